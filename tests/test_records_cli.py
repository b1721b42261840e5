"""The record store through the command line: every solve recorded (default store beside the
calibration file, --db, STATION_DB, --no-db), a store that cannot be written never costs the
calibration file, `station history`, `station fleet` (--json, --csv, --html), `station db`,
`station combine --from-db`, `station solve --repeatability-from-db`, `station demo`."""

import json
import shutil
from pathlib import Path

import pytest

from station import cli
from station.calfiles.calfile import load
from station.records.sources import file_sha256
from station.records.store import open_store

EXAMPLE = Path(__file__).parents[1] / "sessions" / "rotary-12gyro.h5"


@pytest.fixture
def session(tmp_path):
    """A copy of the example rotary session."""
    return Path(shutil.copy(EXAMPLE, tmp_path / "SN.h5"))


def serial_of(path) -> str:
    return load(path).unit_serial


def test_a_solve_is_recorded_beside_its_calibration_file(session, monkeypatch, capsys):
    monkeypatch.delenv("STATION_DB")
    assert cli.main(["solve", str(session), "--json"]) == 0
    out, err = capsys.readouterr()
    cal = Path(json.loads(out)["calibration"])
    store = session.parent / "station.db"
    assert f"recorded in sqlite:///{store}" in err
    with open_store(f"sqlite:///{store}", create=False) as s:
        (record,) = s.history(serial_of(cal))
    assert record.calibration_sha256 == file_sha256(cal)
    assert record.session_sha256 == file_sha256(session)
    assert record.session_path == str(session.resolve())
    assert record.kind == "session" and record.chi2 > 0 and record.positions > 0
    names = {(p.name, p.sensor) for p in record.parameters}
    sensors = load(cal).sensors
    assert {("bias", s) for s in sensors} | {("scale_factor", s) for s in sensors} <= names
    assert all(p.sigma > 0 for p in record.parameters if p.name in ("bias", "scale_factor"))


def test_no_db_records_nothing(session, monkeypatch):
    monkeypatch.delenv("STATION_DB")
    assert cli.main(["solve", str(session), "--no-db"]) == 0
    assert not (session.parent / "station.db").exists()
    assert session.with_suffix(".cal.json").is_file()


def test_a_store_that_cannot_be_written_never_costs_the_calibration(session, tmp_path, capsys,
                                                                     monkeypatch):
    blocked = tmp_path / "blocked"
    blocked.mkdir()  # a directory where the store's file should be: sqlite cannot open it
    assert cli.main(["solve", str(session), "--db", f"sqlite:///{blocked}"]) == 1
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if "not recorded" in x)
    assert "--no-db" in line and "station db import" in line
    assert session.with_suffix(".cal.json").is_file()
    session.with_suffix(".cal.json").unlink()
    monkeypatch.setenv("STATION_DB", f"sqlite:///{blocked}")  # the line's store: no failure
    assert cli.main(["solve", str(session)]) == 0
    assert "not recorded" in capsys.readouterr().err
    assert session.with_suffix(".cal.json").is_file()


def test_history_fleet_import_and_combine_from_the_store(session, tmp_path, capsys,
                                                         record_store):
    tolerances = tmp_path / "tol.toml"
    tolerances.write_text("[tolerances]\nscale_factor = 0.05\nbias = 0.03\n")
    assert cli.main(["solve", str(session), "--out", str(tmp_path / "a.cal.json")]) == 0
    assert cli.main(["solve", str(session), "--out", str(tmp_path / "b.cal.json"),
                     "--tolerances", str(tolerances)]) == 0
    serial = serial_of(tmp_path / "a.cal.json")
    capsys.readouterr()
    assert cli.main(["history", serial, "--json"]) == 0
    h = json.loads(capsys.readouterr().out)
    assert len(h["calibrations"]) == 2
    assert h["largest_drift"]["sigmas"] == 0  # the same session solved twice: no drift
    assert cli.main(["history", serial, "--last", "1", "--parameter", "bias"]) == 0
    lines = capsys.readouterr().out.splitlines()
    biases = [x for x in lines if " +- " in x]
    assert len(biases) == len(load(tmp_path / "a.cal.json").sensors)
    assert all(x.endswith("drift +0.00 sigma") for x in biases)  # one session solved twice
    assert cli.main(["history", "NO-SUCH-UNIT"]) == 2
    assert "no calibration of unit 'NO-SUCH-UNIT'" in capsys.readouterr().err

    assert cli.main(["combine", "--from-db", f"serial={serial}", "--out",
                     str(tmp_path / "c.cal.json"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["sessions"] == 2
    with open_store(record_store, create=False) as s:
        assert [r.kind for r in s.history(serial)] == ["session", "session", "combined"]

    html = tmp_path / "fleet.html"
    assert cli.main(["fleet", f"serial={serial}", "--json", "--html", str(html)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["records"] == 2 and report["yield"]["judged"] == 1  # kind=session by default
    assert report["selection"] == {"serial": serial, "kind": "session"}
    assert html.read_text().startswith("<!DOCTYPE html>")
    assert cli.main(["fleet", "--csv"]) == 0
    rows = capsys.readouterr().out.splitlines()
    assert rows[0].startswith("model,parameter,sensor") and len(rows) > 1

    fresh = f"sqlite:///{tmp_path / 'imported.db'}"
    assert cli.main(["db", "import", str(tmp_path), "--db", fresh, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["added"] == 3
    assert cli.main(["db", "import", str(tmp_path), "--db", fresh, "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["added"] == 0 and again["present"] == 3
    assert cli.main(["db", "check", "--db", fresh, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["problems"] == []
    assert cli.main(["db", "list", f"serial={serial}", "kind=session", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)["calibrations"]
    assert [r["calibration_path"] for r in listed] == [str(tmp_path / f"{n}.cal.json")
                                                       for n in "ab"]
    assert {r["session_sha256"] for r in listed} == {file_sha256(session)}

    assert cli.main(["solve", str(session), "--out", str(tmp_path / "d.cal.json"), "--json",
                     "--repeatability-from-db", f"serial={serial}"]) == 0
    (source,) = json.loads(capsys.readouterr().out)["repeatability"]["files"]
    assert source["sha256"] == file_sha256(tmp_path / "c.cal.json")


def test_combine_from_the_store_refuses_a_file_changed_since(session, tmp_path, capsys):
    out = tmp_path / "a.cal.json"
    assert cli.main(["solve", str(session), "--out", str(out)]) == 0
    out.write_text(out.read_text() + " ")
    assert cli.main(["combine", "--from-db", f"serial={serial_of(out)}", "--out",
                     str(tmp_path / "c.cal.json")]) == 2
    assert "changed since it was recorded" in capsys.readouterr().err


def test_the_demo_records_into_the_working_directory_and_says_where(tmp_path, monkeypatch,
                                                                    capsys):
    monkeypatch.delenv("STATION_DB")
    monkeypatch.chdir(tmp_path)
    assert cli.main(["demo", "--positions", "8", "--seed", "5", "--json"]) == 0
    err = capsys.readouterr().err
    assert f"recorded in sqlite:///{Path.cwd() / 'station.db'}" in err
    with open_store(f"sqlite:///{tmp_path / 'station.db'}", create=False) as s:
        assert s.count() == 1
