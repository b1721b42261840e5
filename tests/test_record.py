"""`station record` with a bench profile pointing at `station twin`'s devices (issue 6): the same
rotary session as the demo, each prompt answered by a scripted operator (lines on stdin), and the
result checked against the twin's truth with bounds from theory."""

import io
import json
import os
import subprocess
import tomllib

import numpy as np
import pytest
from scipy import stats
from technicians import QuitsAt
from twinproc import STATION, TwinProcess

import station
from station.acquire.bench import BenchProfile, record, resume
from station.acquire.operator import ConsoleOperator, OperatorAbort
from station.calfiles.calfile import load
from station.commands.record import solve
from station.reduce.rotary import rotary_readings
from station.session import Session
from station.solve.uncertainty import eps_tail_probability
from station.twin.served import BenchTwin

POSITIONS = 8


def check_against_truth(session_path, cal_path, truth: dict, rate: float = 1.0) -> None:
    """eps (Eq. 19) against the Cramer-Rao bound, chi2, scale factors and biases."""
    cal = load(cal_path)
    a = np.array(truth["a"])
    with Session.open(session_path) as s:
        sigma = rotary_readings(s).sigma
    v = rate * np.array(truth["orientations"])[:POSITIONS, :, 2].T
    # as tests/test_demo.py: eps consistent with the Cramer-Rao bound at a 1e-4 false-alarm level
    assert eps_tail_probability(station.eps(a, cal.a), station.crlb(a, v, sigma)) > 1e-4
    dof = cal.fit["dof"]
    assert abs(cal.fit["chi2"] / dof - 1) < 5 * np.sqrt(2 / dof)
    assert np.all(np.abs(cal.scale_factors - np.linalg.norm(a, axis=0))
                  < 5 * cal.scale_factors_sigma)
    # biases: mean of n static means, sigma from their scatter -> Student t with n - 1 dof;
    # a false failure over 12 sensors has probability 1e-3
    limit = stats.t.ppf(1 - 1e-3 / 24, POSITIONS - 1)
    assert np.all(np.abs(cal.bias - np.array(truth["bias"])) < limit * cal.bias_sigma)


def test_record_with_a_profile_pointing_at_the_twin_process(tmp_path):
    profile, session = tmp_path / "twin.toml", tmp_path / "session.h5"
    with TwinProcess("--positions", str(POSITIONS), "--seed", "3",
                     "--profile-out", str(profile), "--lifetime", "300") as twin:
        started = twin.started  # lockstep time, the twin's default: the same session on any host
        assert started["profile"] == str(profile) and "lockstep" in started
        protocol = tomllib.loads(profile.read_text())["protocol"]
        assert os.path.exists(started["imu"]["port"])
        # the technician: one Enter per mounting prompt
        rec = subprocess.run([*STATION, "record", "--profile", str(profile), "--out", str(session),
                              "--solve", "--json"], check=False, input="\n" * POSITIONS, text=True,
                             capture_output=True, timeout=600)
        assert rec.returncode == 0, rec.stderr
        summary = json.loads(rec.stdout)
        assert summary["positions_done"] == POSITIONS and summary["unit_serial"] == "SIM-3"
        assert rec.stderr.count("(the fixture mounts it)") == POSITIONS  # no key press needed
        assert [f"position {j}/{POSITIONS} captured" in rec.stderr
                for j in range(1, POSITIONS + 1)] == [True] * POSITIONS
    truth = twin.truth
    assert truth["mounted"] == list(range(1, POSITIONS + 1))  # each position once, in order
    with Session.open(session) as s:
        kinds = [e.kind for e in s.events()]
        assert kinds.count("position_done") == POSITIONS and "abort" not in kinds
        # the twin's profile, its positions and waits, recorded with the session and used
        assert protocol["positions"] == POSITIONS
        assert s.unit_serial == "SIM-3" and s.metadata["bench"]["tables"]["protocol"] == protocol
        assert s.metadata["settings"]["steady"] == protocol["steady"]
    check_against_truth(session, summary["calibration"]["calibration"], truth)


def test_end_of_input_aborts_and_stops_the_table(tmp_path):
    with BenchTwin(seed=5, positions=POSITIONS) as twin:
        (tmp_path / "b.toml").write_text(twin.profile_text())
        bench = BenchProfile.load(tmp_path / "b.toml")
        # a table without the fixture: the technician mounts the unit and presses Enter; the
        # input ends after the first position
        (tmp_path / "b.toml").write_text(twin.profile_text().replace(
            'profile = "table_fixture"', 'profile = "table_modbus"'))
        bench = BenchProfile.load(tmp_path / "b.toml")
        operator = ConsoleOperator(stdin=io.StringIO("\n"), stdout=io.StringIO())
        with pytest.raises(OperatorAbort):
            record(bench, tmp_path / "s.h5", operator)
        assert not twin.bench.table.state().running
    with Session.open(tmp_path / "s.h5") as s:
        events = s.events()
        assert [e.kind for e in events if e.kind == "position_done"] == ["position_done"]
        aborts = [e for e in events if e.kind == "abort"]
        assert len(aborts) == 1 and "OperatorAbort" in aborts[0].detail["error"]
        # after the abort, the link counters are still recorded for the report
        assert events[-1].kind == "note" and events[-1].detail["link"]["samples"] > 0


def test_an_aborted_session_resumes_with_the_devices_of_its_bench_profile(tmp_path, capsys):
    """Three positions, then the technician's input ends (abort); a killed station may also leave
    the table turning. `station resume` with the bench profile stops the table, refuses a
    profile for another unit, and completes the session with the real drivers."""
    from station.cli import main

    path, profile = tmp_path / "s.h5", tmp_path / "b.toml"
    with BenchTwin(seed=6, positions=POSITIONS) as twin:
        profile.write_text(twin.profile_text())
        bench = BenchProfile.load(profile)
        with pytest.raises(OperatorAbort):  # the technician walks away at the 4th position
            record(bench, path, QuitsAt(f"position 4/{POSITIONS}"))
        other = tmp_path / "other.toml"
        other.write_text(twin.profile_text(unit_serial="SIM-99"))
        assert main(["resume", str(path), "--profile", str(other)]) == 2
        assert "recorded unit 'SIM-6', the profile is for 'SIM-99'" in capsys.readouterr().err
        table = twin.bench.table  # the table's physics: left turning by a station that died
        table.set_rate(1.0)
        table.start()
        operator = ConsoleOperator(stdin=io.StringIO("\n" * POSITIONS), stdout=io.StringIO())
        assert resume(bench, path, operator) == 3
        assert not table.state().running
        truth = twin.truth()
    with Session.open(path) as s:
        events = s.events()
        done = sorted({e.position for e in events if e.kind == "position_done"})
        assert done == list(range(POSITIONS)) and s.closed_cleanly
        resumed = [e for e in events if e.kind == "session_resumed"]
        assert len(resumed) == 1 and resumed[0].time > max(
            e.time for e in events if e.kind == "abort")  # the clock went on
    cal = load(solve(path)["calibration"])
    dof = cal.fit["dof"]
    assert abs(cal.fit["chi2"] / dof - 1) < 5 * np.sqrt(2 / dof)
    assert np.all(np.abs(cal.scale_factors - np.linalg.norm(truth["a"], axis=0))
                  < 5 * cal.scale_factors_sigma)


def test_station_resume_stops_a_turning_table_before_anything_else(tmp_path):
    """A station died with the table turning, and the IMU is unplugged too: the `station resume`
    process cannot go on, but the first thing it did was command the stop (the twin's register
    log), before it tried the IMU or the session."""
    import time

    path, profile, log = tmp_path / "s.h5", tmp_path / "b.toml", tmp_path / "writes.log"
    with BenchTwin(seed=7, positions=POSITIONS) as twin:
        profile.write_text(twin.profile_text())
        with pytest.raises(OperatorAbort):
            record(BenchProfile.load(profile), path, QuitsAt(f"position 2/{POSITIONS}"))
        table = twin.bench.table
        table.set_rate(1.0)
        table.start()
        twin.bench.imu_twin.unplug()
        twin.bench.table_twin.write_log = log
        launched = time.monotonic()
        done = subprocess.run([*STATION, "resume", str(path)], stdin=subprocess.DEVNULL,
                              capture_output=True, text=True, timeout=600)
        assert done.returncode == 3 and "cannot open serial port" in done.stderr
        assert not table.state().running
    first = log.read_text().splitlines()[0].split()
    command = BenchProfile.load(profile).table_map.registers["command"]
    assert (int(first[1]), int(first[2])) == (command, 0)  # a stop, nothing before it
    assert launched < float(first[0]) < launched + 10  # bench/faults.py measures: under 1 s


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("[protocol]", "[protocol]\nstatic = -1.0"), "must be positive"),
    (lambda t: t.replace("[protocol]", "[protocol]\nstatik = 5.0"), "unknown keys"),
    (lambda t: t.replace('link = "serial"', 'link = "usb"'), "link: must be one of"),
    (lambda t: t + "\n[extra]\n", "unknown sections"),
    (lambda t: t.replace("[table]", "[tabel]"), "unknown sections"),
    (lambda t: t.replace("port = 5020", "port = 5020\nreply_timeout = 0.0"),
     "reply_timeout: 0.0: give 0 < seconds <= 600"),
    (lambda t: t.replace('unit_serial = "SIM-1"', ""), "unit_serial: missing"),
    (lambda t: t.replace('"SIM-1"', '"../../x"'), "it names the session file"),
    (lambda t: t.replace('port = "/dev/null"', 'port = "/dev/null"\nrate_hz = 0.0'),
     "give the IMU's output rate in Hz"),
])
def test_bad_bench_profiles_are_refused_with_the_fix(tmp_path, capsys, edit, message):
    from station import cli

    text = ('[bench]\nunit_serial = "SIM-1"\n\n[imu]\nlink = "serial"\nprofile = "imu12_serial"\n'
            'port = "/dev/null"\n\n[table]\nhost = "127.0.0.1"\nport = 5020\n\n'
            "[protocol]\npositions = 8\n")
    path = tmp_path / "bench.toml"
    path.write_text(edit(text))
    assert cli.main(["record", "--profile", str(path), "--out", str(tmp_path / "s.h5")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "s.h5").exists()


def test_the_example_bench_profiles_load():
    serial, can = BenchProfile.load("bench_serial"), BenchProfile.load("bench_can")
    assert serial.imu_address == "/dev/ttyUSB0" and serial.positions == 20
    assert can.link == "can" and can.imu_address["interface"] == "socketcan"
    assert serial.imu.imu.channels == can.imu.imu.channels
    static, iron = BenchProfile.load("bench_static"), BenchProfile.load("bench_iron")
    assert (static.protocol, static.positions, static.table_host) == ("static", 18, None)
    np.testing.assert_array_equal(static.layout, np.eye(3))
    assert (iron.protocol, iron.positions) == ("iron", 12)  # 2 mountings x 6 faces
    np.testing.assert_allclose(np.linalg.norm(iron.layout, axis=0), 1.0, atol=1e-5)
