"""The commands `solve`, `apply`, `export`, `devices`, `twin`, `record`: help with examples, JSON
output, and `solve` -> `apply` on a session recorded in-process from the twin (CAN link)."""

import io
import json

import numpy as np
import pytest
from serial.tools import list_ports

import station
from station import cli
from station.acquire.bench import BenchProfile, record
from station.acquire.operator import ConsoleOperator
from station.calfiles.calfile import load
from station.model.frames import align_to
from station.session import Session, SessionWriter, StreamSpec
from station.twin.served import BenchTwin

COMMANDS = ("solve", "apply", "export", "devices", "twin", "record")
POSITIONS = 7


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """(session path, truth) of a short session over the twin's virtual CAN link."""
    tmp = tmp_path_factory.mktemp("cli")
    with BenchTwin("can", seed=4, positions=POSITIONS) as twin:
        (tmp / "bench.toml").write_text(twin.profile_text("SN-CLI"))
        operator = ConsoleOperator(stdin=io.StringIO("\n" * POSITIONS), stdout=io.StringIO())
        record(BenchProfile.load(tmp / "bench.toml"), tmp / "s.h5", operator)
        truth = twin.bench.truth()
    return tmp / "s.h5", truth


@pytest.mark.parametrize("name", COMMANDS)
def test_every_command_has_help_with_examples(name, capsys):
    with pytest.raises(SystemExit) as done:
        cli.main([name, "--help"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    assert "examples:" in text and f"station {name}" in text and "--json" in text


def test_solve_writes_a_calibration_file_matching_the_truth(recorded, tmp_path, capsys):
    session, truth = recorded
    nominal = tmp_path / "nominal.csv"
    np.savetxt(nominal, truth.a_nominal, delimiter=",")
    out = tmp_path / "SN-CLI.cal.json"
    assert cli.main(["solve", str(session), "--out", str(out), "--nominal", str(nominal),
                     "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    cal = load(out, unit_serial="SN-CLI")
    assert summary["positions"] == POSITIONS and summary["frame"] == cal.frame == "nominal"
    assert cal.session["path"] == str(session.resolve())
    assert cal.fit["method"] == summary["method"]
    assert summary["start"] == cal.fit["start"] == "closed form"
    # both figures: the total 1-sigma holds the white-noise one (the per-pose term is >= 0)
    assert summary["pose_sigma"] == cal.pose_sigma >= 0
    assert summary["scale_factors_sigma_white"] == cal.white["scale_factors_sigma"].tolist()
    assert np.all(np.array(summary["scale_factors_sigma"])
                  >= np.array(summary["scale_factors_sigma_white"]) * (1 - 1e-9))
    assert cal.counts_per_unit.tolist() == [1000.0] * 12  # the CAN profile's scale
    # the nominal frame: the truth rotated as close as possible to the nominal layout
    # (orthogonal Procrustes, docs/conventions.md) is a itself, within the frame's 1-sigma
    aligned = align_to(truth.a, truth.a_nominal) @ truth.a
    assert np.all(np.abs(cal.a - aligned) < 5 * cal.a_sigma)
    assert np.all(np.abs(cal.scale_factors - np.linalg.norm(truth.a, axis=0))
                  < 5 * cal.scale_factors_sigma)
    # and the same eps as the canonical frame of Eq. (19): the frame changes nothing intrinsic
    assert cli.main(["solve", str(session), "--out", str(tmp_path / "c.json")]) == 0
    canonical = load(tmp_path / "c.json")
    assert canonical.frame == "canonical"
    assert station.eps(truth.a, canonical.a) == pytest.approx(station.eps(truth.a, cal.a),
                                                              rel=1e-6)
    # never overwrites
    capsys.readouterr()
    assert cli.main(["solve", str(session), "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err


def test_apply_to_the_recorded_session_gives_the_table_rate(recorded, tmp_path, capsys):
    session, _ = recorded
    cal_path = tmp_path / "cal.json"
    assert cli.main(["solve", str(session), "--out", str(cal_path)]) == 0
    out = tmp_path / "v.csv"
    assert cli.main(["apply", str(cal_path), str(session), "--out", str(out)]) == 0
    v = np.loadtxt(out, delimiter=",", skiprows=1)[:, 1:]
    norm = np.linalg.norm(v, axis=1)
    spinning = norm > 0.9  # at 1 rad/s; at rest |v| ~ noise (0.0025 rad/s per sample)
    # the fused rate while spinning is the table rate, 1 rad/s (per-sample noise ~0.0013 rad/s)
    assert np.median(norm[spinning]) == pytest.approx(1.0, abs=2e-3)
    assert np.median(norm[norm < 0.1]) < 0.01  # at rest: the biases were removed


def test_solve_refuses_what_it_cannot_solve(tmp_path, capsys):
    path = tmp_path / "imported.h5"
    spec = StreamSpec(("a1", "a2", "a3"), "m/s^2", 1000.0, 100.0)
    with SessionWriter.create(path, {"protocol": "import", "unit_serial": "X"}, {"imu": spec}):
        pass
    assert cli.main(["solve", str(path)]) == 2
    err = capsys.readouterr().err
    assert "stream 'imu' holds 0 samples" in err and "import the recording again" in err
    other = tmp_path / "other.h5"
    with SessionWriter.create(other, {"protocol": "other", "unit_serial": "X"}, {"imu": spec}):
        pass
    assert cli.main(["solve", str(other)]) == 2
    err = capsys.readouterr().err
    assert "records a 'other' session" in err and "station import" in err
    iron = tmp_path / "iron.h5"  # a still-pose session without its gravity
    with SessionWriter.create(iron, {"protocol": "iron", "unit_serial": "X"}, {"imu": spec}):
        pass
    assert cli.main(["solve", str(iron)]) == 2
    assert "no usable gravity (None). Give the stimulus magnitude with --magnitude" \
        in capsys.readouterr().err
    (tmp_path / "junk.h5").write_bytes(b"not hdf5")
    assert cli.main(["solve", str(tmp_path / "junk.h5")]) == 2
    assert "station solve:" in capsys.readouterr().err


def test_devices_lists_serial_ports_and_can_channels(capsys):
    assert cli.main(["devices", "--can-interfaces", "virtual", "--json"]) == 0
    found = json.loads(capsys.readouterr().out)
    assert [p["device"] for p in found["serial"]] == sorted(p.device for p in
                                                           list_ports.comports())
    assert found["can"] and all(c["interface"] == "virtual" for c in found["can"])
    with pytest.raises(SystemExit):
        cli.main(["devices", "--can-interfaces", "nonsense"])
    assert "unknown CAN interfaces ['nonsense']" in capsys.readouterr().err


def test_the_twins_bench_profile_points_at_its_devices(tmp_path):
    with BenchTwin(seed=2, speed=10, positions=12) as twin:
        twin.bench.table_reply = 2.5  # station twin --table-reply 2.5
        (tmp_path / "b.toml").write_text(twin.profile_text("SN9"))
        bench = BenchProfile.load(tmp_path / "b.toml")
        assert bench.imu_address == twin.bench.imu_twin.port
        assert (bench.table_host, bench.table_port) == ("127.0.0.1", twin.bench.table_twin.port)
        assert bench.table_reply == 2.5
        assert (bench.unit_serial, bench.positions, bench.clock_speed) == ("SN9", 12, 10.0)
        assert bench.imu.imu.rate_hz == 200.0


def test_a_session_records_the_bench_profile(recorded):
    session, _ = recorded
    with Session.open(session) as s:
        assert s.metadata["bench"]["tables"]["imu"]["link"] == "can"
        assert s.metadata["profiles"]["imu"]["imu"]["name"] == "imu12-can"
        assert s.metadata["settings"]["rate"] == 1.0
