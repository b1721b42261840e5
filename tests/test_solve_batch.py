"""`station solve A.h5 B.h5 ...` and `--from-list FILE`: many sessions in one process, one line and
one calibration file each, failures per session, the exit code the largest of the sessions', and
the structure checks of the whole batch in one child process (the damage verdicts unchanged)."""

import json
import os
import shutil
import signal
from pathlib import Path

import pytest
from test_session_damage import write_session, zero_chunk

from station.calfiles.calfile import load
from station.cli import main
from station.session import check

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "sessions" / "rotary-12gyro.h5"
CRASH_ON_BAD = (
    "import os, signal, sys\n"
    "from station.session import check\n"
    "survey = check.survey\n"
    "check.survey = lambda p: os.kill(os.getpid(), signal.SIGSEGV) if p.endswith('bad.h5') "
    "else survey(p)\n"
    "check._each(sys.argv[1:])\n")
"""The real check, but the HDF5 library "crashes" on any file named bad.h5 (a new interpreter's
child; a forked one inherits the same `check.survey` from the test)."""


@pytest.fixture
def copies(tmp_path):
    """Three copies of the example rotary session (each a file of its own)."""
    return [Path(shutil.copy(EXAMPLE, tmp_path / f"s{i}.h5")) for i in range(3)]


@pytest.fixture
def children(monkeypatch):
    """The path lists the check's children were started with, in order, with a cache of its
    own."""
    started = []
    launch = check._child

    def counted(paths, cpu_limit):
        started.append(list(paths))
        return launch(paths, cpu_limit)

    monkeypatch.setattr(check, "_child", counted)
    monkeypatch.setattr(check, "_SURVEYS", {})
    return started


def test_a_batch_writes_one_file_and_one_line_per_session_and_reports_failures_per_session(
        copies, tmp_path, children, capsys):
    damaged = write_session(tmp_path / "damaged.h5")  # written with checksums
    zero_chunk(damaged, "streams/imu/counts", 1)
    listed = tmp_path / "more.txt"
    listed.write_text(f"# the rest of the lot\n\n{copies[2].name}\nmissing.h5\n")
    argv = ["solve", str(copies[0]), str(damaged), str(copies[1]), "--from-list", str(listed),
            "--no-db"]
    assert main(argv) == 2  # bad input: the largest of the sessions' exit codes
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 5
    for line, path in zip(lines, [copies[0], damaged, copies[1], copies[2],
                                  tmp_path / "missing.h5"], strict=True):
        assert line.startswith(f"{path}: ")
    for i in (0, 2, 3):
        assert "written to" in lines[i] and "12 sensors" in lines[i]
    assert "failed (exit 2)" in lines[1] and "is damaged" in lines[1]
    assert "failed (exit 2)" in lines[4] and "is not a file" in lines[4]
    for path in copies:
        assert load(path.with_suffix(".cal.json")).sensors
    assert not damaged.with_suffix(".cal.json").exists()
    assert children == [[str(copies[0]), str(damaged), str(copies[1]), str(copies[2])]]


def test_json_lines_and_the_exit_code_of_a_clean_batch(copies, capsys):
    assert main(["solve", *map(str, copies), "--json", "--no-db"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["session"] for r in rows] == list(map(str, copies))
    for r, path in zip(rows, copies, strict=True):
        assert r["exit"] == 0 and r["calibrations"][0]["calibration"] == str(
            path.with_suffix(".cal.json"))


@pytest.mark.parametrize("launch", ["spawn", "fork"])
def test_a_crash_on_one_file_is_its_damage_and_the_batch_goes_on(copies, tmp_path, children,
                                                                 monkeypatch, capsys, launch):
    """With either child (a new interpreter, a fork of this process: station.session.forked)."""
    bad = Path(shutil.copy(EXAMPLE, tmp_path / "bad.h5"))
    monkeypatch.setattr(check, "forkable", lambda: launch == "fork")
    monkeypatch.setattr(check, "CHILD", ("-c", CRASH_ON_BAD))
    survey = check.survey
    monkeypatch.setattr(check, "survey", lambda p: os.kill(os.getpid(), signal.SIGSEGV)
                        if p.endswith("bad.h5") else survey(p))
    assert main(["solve", str(copies[0]), str(bad), str(copies[1]), "--no-db"]) == 2
    lines = capsys.readouterr().out.splitlines()
    assert "written to" in lines[0] and "written to" in lines[2]
    assert "failed (exit 2)" in lines[1] and "is damaged" in lines[1] and "SIGSEGV" in lines[1]
    # the batch's child stops at bad.h5, a new one goes on after it; bad.h5 is checked alone
    assert children == [[str(copies[0]), str(bad), str(copies[1])], [str(copies[1])], [str(bad)]]


def test_out_and_an_empty_batch_are_refused(copies, tmp_path, capsys):
    assert main(["solve", *map(str, copies[:2]), "--out", str(tmp_path / "x.cal.json")]) == 2
    assert "--out" in capsys.readouterr().err
    empty = tmp_path / "empty.txt"
    empty.write_text("# nothing yet\n")
    assert main(["solve", "--from-list", str(empty)]) == 2
    assert "no session given" in capsys.readouterr().err
