"""No verdict from a wall clock (issue 29): the session-file check bounds its child's CPU time, not
the wall; a check that could not finish is "could not be checked" (SessionUncheckedError, exit 1),
never "damaged"; a crash inside the HDF5 library stays damage; `--no-check` skips the check; a
command reads each file once.

The child is slowed or crashed (`child_runs_first`): it spins, sleeps or raises a signal before
running the real check, so nothing here depends on the host's speed. Each test runs with both
children: the new interpreter (`check.CHILD`, the interpreter arguments that run the survey) and
the fork of this process (`station.session.forked`, whose `check.survey` runs the code first)."""

import shutil
from pathlib import Path

import numpy as np
import pytest
from test_session_damage import write_session

from drivers.samples import SampleBlock
from station.cli import main
from station.errors import SessionFormatError, SessionUncheckedError
from station.session import SessionWriter, StreamSpec, check

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "sessions" / "rotary-12gyro.h5"
THEN = "import runpy; runpy.run_module('station.session.check', run_name='__main__')"
"""The real check, after whatever a test puts before it in the child."""
SPIN = "import time\nwhile time.process_time() < 30: pass\n"
"""30 s of CPU time: more than any limit a test gives."""
OLD_WALL_LIMIT = 5.0
"""The former wall-clock limit's base (5 s + size / 50 MB/s), which a slow start ran into."""


@pytest.fixture(params=["spawn", "fork"])
def launch(request, monkeypatch):
    """Which child checks: a new interpreter or a fork of this process."""
    monkeypatch.setattr(check, "forkable", lambda: request.param == "fork")
    return request.param


def child_runs_first(monkeypatch, launch: str, code: str) -> None:
    """The check's child runs `code` (Python source), then the real check."""
    if launch == "spawn":
        monkeypatch.setattr(check, "CHILD", ("-c", code + "\n" + THEN))
        return
    real = check.survey

    def survey(path):
        exec(code, {})  # noqa: S102 - the test's own code, in the forked child
        return real(path)

    monkeypatch.setattr(check, "survey", survey)


@pytest.fixture
def session(tmp_path):
    """A copy of the example rotary session (intact; a file of its own: checked afresh)."""
    return Path(shutil.copy(EXAMPLE, tmp_path / "s.h5"))


@pytest.fixture
def launches(monkeypatch):
    """The paths the check's children were launched for, in order, with a cache of its own."""
    seen = []
    launch = check._survey_in_child

    def counted(path, cpu_limit):
        seen.append(path)
        return launch(path, cpu_limit)

    monkeypatch.setattr(check, "_survey_in_child", counted)
    monkeypatch.setattr(check, "_SURVEYS", {})
    return seen


def test_out_of_cpu_time_is_no_verdict(session, monkeypatch, launch):
    """A child that spends its CPU time without finishing (as HDF5 looping on damaged metadata,
    here a spin before the real check) says so; the file is not called damaged."""
    child_runs_first(monkeypatch, launch, SPIN)
    with pytest.raises(SessionUncheckedError) as err:
        check.checked(session, cpu_limit=1)
    words = str(err.value)
    assert not isinstance(err.value, SessionFormatError)
    assert "could not be checked" in words and "1 s of CPU time" in words
    assert "is damaged" not in words and "--no-check" in words


def test_a_slow_start_does_not_make_an_intact_file_damaged(session, monkeypatch, launch):
    """The child starts later than the former wall-clock limit allowed (a busy host): the intact
    file still passes, since only CPU time counts."""
    child_runs_first(monkeypatch, launch, f"import time; time.sleep({OLD_WALL_LIMIT + 1})")
    check.checked(session)


def test_the_wall_backstop_is_no_verdict(session, monkeypatch, launch):
    """A child that neither finishes nor uses CPU (hung storage) meets the wall-clock backstop:
    no verdict either."""
    child_runs_first(monkeypatch, launch, "import time; time.sleep(600)")
    monkeypatch.setattr(check, "WALL_FACTOR", 0.1)
    with pytest.raises(SessionUncheckedError, match="could not be checked: .* did not finish "
                                                    "within 1 s"):
        check.checked(session, cpu_limit=10)


@pytest.mark.parametrize("signal_name", ["SIGSEGV", "SIGABRT"])
def test_a_crash_in_the_child_is_damage(session, monkeypatch, launch, signal_name):
    """HDF5 crashing on a file is evidence of damage: refused as damaged (exit 2)."""
    child_runs_first(monkeypatch, launch,
                     f"import os, signal; os.kill(os.getpid(), signal.{signal_name})")
    with pytest.raises(SessionFormatError, match=f"is damaged: .*signal {signal_name}"):
        check.checked(session)


def test_a_child_killed_from_outside_is_no_verdict(session, monkeypatch, launch):
    child_runs_first(monkeypatch, launch, "import os, signal; os.kill(os.getpid(), signal.SIGTERM)")
    with pytest.raises(SessionUncheckedError, match="stopped by SIGTERM"):
        check.checked(session)


def test_the_cli_says_could_not_be_checked_with_exit_1_and_no_check_skips(session, tmp_path,
                                                                          monkeypatch, capsys,
                                                                          launch):
    child_runs_first(monkeypatch, launch, SPIN)
    monkeypatch.setattr(check, "CPU_BASE", 1.0)
    monkeypatch.setattr(check, "CPU_PER_BYTE", 0.0)
    out = tmp_path / "s.cal.json"
    assert main(["solve", str(session), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "could not be checked" in err and "is damaged" not in err
    assert not out.exists()
    assert main(["solve", str(session), "--out", str(out), "--no-check"]) == 0
    assert out.exists()


def test_no_check_leaves_the_readers_own_checks(tmp_path, capsys):
    """Changed metadata text (HDF5's global heap, which no HDF5 checksum covers): refused by the
    reader's SHA-256 of it with and without --no-check (exit 2)."""
    session = write_session(tmp_path / "s.h5")
    data = bytearray(session.read_bytes())
    at = data.index(b'"unit_serial": "D1"')
    data[at + len('"unit_serial": "D')] = ord("7")
    session.write_bytes(bytes(data))
    for extra in ([], ["--no-check"]):
        assert main(["noise", str(session), *extra]) == 2
        assert "does not match its checksum" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [
    ["solve", "{s}", "--out", "{tmp}/s.cal.json"],
    ["replay", "{s}"],
    ["noise", "{s}"],
    ["diagnose", "{s}"],
    ["report", "{s}", "--out", "{tmp}/s.html"],
], ids=lambda argv: argv[0])
def test_a_command_reads_the_session_once(argv, session, tmp_path, launches, capsys):
    assert main([a.format(s=session, tmp=tmp_path) for a in argv]) == 0
    assert launches == [str(session)]


def test_apply_reads_the_session_once(session, tmp_path, launches, capsys):
    cal = tmp_path / "s.cal.json"
    assert main(["solve", str(session), "--out", str(cal), "--no-check"]) == 0
    assert main(["apply", str(cal), str(session), "--out", str(tmp_path / "v.csv")]) == 0
    assert launches == [str(session)]


def test_an_unchanged_file_is_surveyed_once_a_changed_one_again(session, launches):
    check.checked(session)
    check.checked(session, positions=[0, 1])
    assert launches == [str(session)]
    with session.open("ab") as fh:  # a writer appended: another file
        fh.write(b"\0")
    check.checked(session)
    assert launches == [str(session)] * 2


def test_a_live_writers_file_is_read_as_live_a_killed_ones_as_closed(tmp_path):
    """Flagged open for write and locked by a live writer: read by HDF5's SWMR reader (inside a
    flush the file may be shorter than its superblock says). Flagged with no lock (a killed
    writer's): read as a closed file (test_session_damage: a truncated one)."""
    spec = StreamSpec(["a", "b", "c"], "m/s^2", 1000.0, 100.0)
    with SessionWriter.create(tmp_path / "live.h5", {"protocol": "check-test", "unit_serial": "L1"},
                              {"imu": spec}) as w:
        seq = np.arange(2000)
        w.append("imu", SampleBlock(np.stack([seq % 7] * 3, 1).astype(np.int32), seq, seq / 100.0,
                                    seq / 100.0))
        w.flush()
        assert check._held(str(tmp_path / "live.h5"))
        check.checked(tmp_path / "live.h5")
    assert not check._held(str(tmp_path / "live.h5"))
