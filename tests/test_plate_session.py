"""Several units on one rotary table (issue 16, item 5): `station twin --units 3` serves three
simulated units on one plate (each its own truth, mounting and pty), `station record` records
them into one session through one driver each, `station solve` writes one calibration file per
unit; a unit lost for good stops the table and is named; profiles and session metadata that do
not describe units are refused with the fix."""

import io
import json
import threading

import numpy as np
import pytest
from scipy import stats
from technicians import QuitsAt
from twinproc import TwinProcess, station_run

import station
import station.commands.solve
from drivers.profile import ProfileError
from station.acquire.bench import BenchProfile, record, resume
from station.acquire.operator import ConsoleOperator, OperatorAbort
from station.calfiles.calfile import load
from station.commands.record import solve_plate
from station.errors import InputError, ProtocolError, SessionFormatError
from station.reduce.rotary import rotary_readings
from station.reduce.timeline import sample_times, segment_breaks
from station.session import Session
from station.session.units import recorded_units
from station.solve.uncertainty import eps_tail_probability
from station.twin.served import BenchTwin

POSITIONS = 8
UNITS = 3
FALSE_ALARM = 1e-3
"""False-alarm probability of each family of checks over the whole session (Bonferroni over the
units and their sensors)."""


def check_unit(session_path, cal_path, stream: str, truth: dict, rate: float = 1.0) -> None:
    """One unit's calibration against its own truth: chi2 within chi2(dof)'s two-sided bounds,
    scale factors within 4 sigma, biases within Student t bounds, eps against the Cramer-Rao bound
    of the stimuli in the unit's own frame."""
    cal = load(cal_path)
    a = np.array(truth["a"])
    dof, chi2 = cal.fit["dof"], cal.fit["chi2"]
    low, high = stats.chi2.ppf([FALSE_ALARM / (2 * UNITS), 1 - FALSE_ALARM / (2 * UNITS)], dof)
    assert low < chi2 < high, (stream, chi2, dof)
    # |z| < 4: a false failure of one of the 36 scale factors has probability 36 * 6.3e-5 = 2e-3
    z = (cal.scale_factors - np.linalg.norm(a, axis=0)) / cal.scale_factors_sigma
    assert np.all(np.abs(z) < 4), (stream, z)
    # biases: the mean of n static means, sigma from their scatter: Student t with n - 1 dof
    limit = stats.t.ppf(1 - FALSE_ALARM / (2 * UNITS * a.shape[1]), POSITIONS - 1)
    assert np.all(np.abs(cal.bias - np.array(truth["bias"])) < limit * cal.bias_sigma), stream
    with Session.open(session_path) as s:
        sigma = rotary_readings(s, stream).sigma
    # the unit felt the table axis in its own frame: its mounting times the plate's orientation
    v = rate * np.array(truth["orientations"])[:POSITIONS, :, 2].T
    assert eps_tail_probability(station.eps(a, cal.a), station.crlb(a, v, sigma)) \
        > FALSE_ALARM / UNITS


def instant_lags(session) -> np.ndarray:
    """(units, segments) median of each unit's sample instants (`sample_times`) minus its frames'
    device times, per segment of the stream (before and after each `session_resumed`)."""
    breaks = segment_breaks(session.events())
    lags = []
    for name in sorted(session.specs):
        d = session.stream(name, columns=("seq", "host_time", "device_time"))
        t = sample_times(d.seq, d.host_time, session.specs[name].rate_hz, breaks)
        segment = np.searchsorted(breaks, d.host_time, side="right")
        lags.append([np.nanmedian((t - d.device_time)[segment == k])
                     for k in range(len(breaks) + 1)])
    return np.array(lags)


def test_three_units_on_one_table_recorded_and_solved_each_against_its_truth(tmp_path):
    profile, session = tmp_path / "plate.toml", tmp_path / "plate.h5"
    with TwinProcess("--positions", str(POSITIONS), "--seed", "11", "--units",
                     str(UNITS), "--rate-hz", "100", "--profile-out", str(profile),
                     "--lifetime", "300") as twin:
        assert len({u["port"] for u in twin.started["units"]}) == UNITS  # a pty per unit
        rec = station_run("record", "--profile", profile, "--out", session, "--solve", "--json",
                          timeout=600)
        assert rec.returncode == 0, rec.stderr
    truth = twin.truth
    summary = json.loads(rec.stdout)
    serials = [f"SIM-11-U{k}" for k in range(1, UNITS + 1)]
    streams = ["imu", "imu2", "imu3"]
    assert summary["positions_done"] == POSITIONS
    assert [(u["unit_serial"], u["stream"]) for u in summary["units"]] == list(
        zip(serials, streams, strict=True))
    # each unit's samples: about a sample per 1/100 s of the session, the same for every unit
    counts = [u["samples"] for u in summary["units"]]
    assert max(counts) - min(counts) < 0.05 * max(counts)
    with Session.open(session) as s:
        assert sorted(s.specs) == streams and s.unit_serial == "SIM-11"
        assert [u.unit_serial for u in recorded_units(s.metadata, s.specs, session)] == serials
        kinds = [e.kind for e in s.events()]
        assert kinds.count("position_done") == POSITIONS and "abort" not in kinds
        links = [e.detail for e in s.events() if e.kind == "note" and "link" in e.detail]
        assert sorted(d["stream"] for d in links) == streams
    files = [c["calibration"] for c in summary["calibrations"]]
    assert files == [str(tmp_path / f"plate.{serial}.cal.json") for serial in serials]
    for unit, file, serial in zip(truth["units"], files, serials, strict=True):
        assert load(file).unit_serial == serial
        check_unit(session, file, unit["stream"], unit)
    # distinct truths: the units differ by far more than their calibrations' sigmas
    scales = [np.linalg.norm(np.array(u["a"]), axis=0) for u in truth["units"]]
    assert min(np.max(np.abs(scales[i] - scales[j])) for i, j in ((0, 1), (0, 2), (1, 2))) \
        > 10 * max(load(f).scale_factors_sigma.max() for f in files)
    # `station solve` on the session: the same files, refused while they exist, then a line each
    again = station_run("solve", str(session), timeout=600)
    assert again.returncode == 2 and "exists" in again.stderr and files[0] in again.stderr
    again = station_run("solve", str(session), "--out", str(tmp_path / "b"), timeout=600)
    assert again.returncode == 0, again.stderr
    lines = again.stdout.splitlines()
    assert len(lines) == UNITS and all(f"unit {s} (stream {st})" in line and "quality gate "
                                       "passed" in line for s, st, line in
                                       zip(serials, streams, lines, strict=True))
    assert np.allclose(load(tmp_path / "b.SIM-11-U2.cal.json").scale_factors,
                       load(files[1]).scale_factors)
    # `station replay` re-reduces every unit's stream as the solve did: the same scale factors
    replayed = station_run("replay", str(session), "--json", timeout=600)
    assert replayed.returncode == 0, replayed.stderr
    units = json.loads(replayed.stdout)["units"]
    assert [(u["unit_serial"], u["stream"]) for u in units] == list(
        zip(serials, streams, strict=True))
    for unit, file in zip(units, files, strict=True):
        assert np.allclose(unit["scale_factors"], load(file).scale_factors, rtol=1e-9)
    # `station diagnose` takes one unit at a time: refused without --stream, naming the streams
    diagnosed = station_run("diagnose", str(session), timeout=600)
    assert diagnosed.returncode == 2 and "--stream imu" in diagnosed.stderr
    assert all(st in diagnosed.stderr for st in streams)
    wrong = station_run("diagnose", str(session), "--stream", "imu4", timeout=600)
    assert wrong.returncode == 2 and "no unit on stream 'imu4'" in wrong.stderr
    second = station_run("diagnose", str(session), "--stream", "imu2", "--json", timeout=300)
    assert second.returncode == 0, second.stderr
    before = json.loads(second.stdout)["calibration_before"]
    # its nominal fit is unit 2's: within 4 sigma of unit 2's file, far from unit 1's
    gap = [np.max(np.abs(np.subtract(before["scale_factors"], load(f).scale_factors))
                  / np.array(before["scale_factors_sigma"])) for f in files[:2]]
    assert gap[1] < 4 < 10 < gap[0], gap
    # `station report`: one report per unit, each of its unit's stream and calibration
    reported = station_run("report", str(session), "--json", timeout=300)
    assert reported.returncode == 0, reported.stderr
    reports = json.loads(reported.stdout)["units"]
    assert [(r["unit_serial"], r["stream"]) for r in reports] == list(
        zip(serials, streams, strict=True))
    for r, file, count, serial in zip(reports, files, counts, serials, strict=True):
        assert r["files"][0] == str(tmp_path / f"plate.{serial}.html")
        assert r["samples"] == count and r["sensors"] == 12
        assert r["chi2_per_dof"] == pytest.approx(load(file).fit["chi2"] / load(file).fit["dof"])
    one = station_run("report", session, "--stream", "imu3", "--out", tmp_path / "u3.html",
                      "--json")
    assert one.returncode == 0, one.stderr
    assert json.loads(one.stdout)["unit_serial"] == serials[2]
    wrong = station_run("report", str(session), "--stream", "imu4", timeout=600)
    assert wrong.returncode == 2 and "no stream 'imu4'" in wrong.stderr


def test_three_can_units_on_one_bus_recorded_and_solved_each_against_its_truth(tmp_path):
    """Three units of one model on ONE CAN bus, each configured to its own node (id_offset 0,
    0x10, 0x20 in its [[imu]] table), one driver each, recorded into one session: each stream
    holds its own unit's samples (solved within its bounds against its own truth), none the
    others' frames."""
    path = tmp_path / "s.h5"
    # python-can's virtual bus hands every frame to every driver in this process: 3 units x 3
    # frames x 3 drivers per sample, so a lower rate than the serial plate's (lockstep time)
    with BenchTwin("can", seed=12, positions=POSITIONS, rate_hz=50, units=UNITS) as twin:
        (tmp_path / "b.toml").write_text(twin.profile_text())
        bench = BenchProfile.load(tmp_path / "b.toml")
        assert [u.imu.can.id_offset for u in bench.units] == [0, 0x10, 0x20]
        assert len({(u.address["interface"], u.address["channel"]) for u in bench.units}) == 1
        said = io.StringIO()
        record(bench, path, ConsoleOperator(stdin=io.StringIO(), stdout=said))
        truth = twin.truth()
    # every captured position confirmed for every unit, each with its own windows' samples
    for u in bench.units:
        lines = [line for line in said.getvalue().splitlines()
                 if line.startswith(f"  unit {u.unit_serial} (stream {u.stream}): static ")]
        assert len(lines) == POSITIONS and all("rotating" in line for line in lines), lines
    for k, unit in enumerate(truth["units"]):
        cal = station.commands.solve.solve_session(path, unit["stream"])
        cal.save(tmp_path / f"u{k}.cal.json")
        check_unit(path, tmp_path / f"u{k}.cal.json", unit["stream"], unit)
    with Session.open(path) as s:
        assert [e.kind for e in s.events()].count("position_done") == POSITIONS


def test_can_units_sharing_a_bus_at_the_same_ids_are_refused(tmp_path):
    """Two [[imu]] units on one CAN bus without their own id_offset would each decode the
    other's frames: refused, naming both units and the ids, with the fix."""
    with BenchTwin("can", seed=12, positions=POSITIONS, rate_hz=100, units=2) as twin:
        text = twin.profile_text().replace("id_offset = 16", "id_offset = 0")
    (tmp_path / "b.toml").write_text(text)
    with pytest.raises(ProfileError, match=r"units SIM-12-U1 and SIM-12-U2 share the CAN bus .* "
                                           r"0x180, 0x181, 0x182; configure each unit"):
        BenchProfile.load(tmp_path / "b.toml")


def test_a_unit_lost_for_good_stops_the_table_and_is_named(tmp_path):
    with BenchTwin(seed=7, positions=POSITIONS, rate_hz=100, units=UNITS) as twin:
        (tmp_path / "b.toml").write_text(twin.profile_text())
        bench = BenchProfile.load(tmp_path / "b.toml")
        assert bench.plate and [u.stream for u in bench.units] == ["imu", "imu2", "imu3"]

        def unplug():  # unit 2's cable pulled once position 2 is mounted, never put back
            while len(twin.mounted) < 2:
                threading.Event().wait(0.01)
            twin.toggle("imu2")

        threading.Thread(target=unplug, daemon=True).start()
        console = io.StringIO()  # the technician confirms every reconnection, in vain
        operator = ConsoleOperator(stdin=io.StringIO("\n" * 20), stdout=console)
        with pytest.raises(ProtocolError) as caught:
            record(bench, tmp_path / "s.h5", operator)
        assert "unit SIM-7-U2 (stream imu2)" in str(caught.value)
        assert not twin.bench.table.state().running
        assert "the IMU of unit SIM-7-U2 (stream imu2) was lost" in console.getvalue()
    with Session.open(tmp_path / "s.h5") as s:
        events = s.events()
        faults = [e for e in events if e.kind == "fault"]
        assert faults and {e.detail["unit"] for e in faults} == {"unit SIM-7-U2 (stream imu2)"}
        aborts = [e for e in events if e.kind == "abort"]
        assert len(aborts) == 1 and aborts[0].detail["table_stopped"]
        assert any("SIM-7-U2" in d for d in aborts[0].detail["devices"])
        done = [e.position for e in events if e.kind == "position_done"]
        assert done == [0]  # position 1 complete, position 2 lost with the unit


def test_an_aborted_plate_session_resumes_with_every_unit(tmp_path):
    """The technician walks away at the 4th position (abort, table stopped); `station resume`
    with the plate's profile refuses a profile that lists other units, then completes the session
    with all three units, each solved against its own truth, and each unit's samples timed alike
    in both segments (a CI run once found the first unit's resumed instants seconds late: its
    rotating window of position 4 held the spin-up; `tests/test_recorder_backlog.py`)."""
    path, profile = tmp_path / "s.h5", tmp_path / "b.toml"
    with BenchTwin(seed=6, positions=POSITIONS, rate_hz=100, units=UNITS) as twin:
        profile.write_text(twin.profile_text())
        bench = BenchProfile.load(profile)
        with pytest.raises(OperatorAbort):
            record(bench, path, QuitsAt(f"position 4/{POSITIONS}"))
        assert not twin.bench.table.state().running
        two = tmp_path / "two.toml"  # the third unit's [[imu]] table left out
        two.write_text(profile.read_text().rsplit("[[imu]]", 1)[0] + "[table]"
                       + profile.read_text().split("[table]", 1)[1])
        with pytest.raises(InputError, match="resume with the bench profile the session was "):
            resume(BenchProfile.load(two), path, ConsoleOperator(io.StringIO(""),
                                                                 io.StringIO()))
        assert resume(bench, path, ConsoleOperator(io.StringIO(""), io.StringIO())) == 3
        truth = twin.truth()
        guard = bench.settings.guard  # the bench's margins (`VirtualBench.with_margins`): 1 s
    with Session.open(path) as s:
        done = sorted({e.position for e in s.events() if e.kind == "position_done"})
        assert done == list(range(POSITIONS)) and s.closed_cleanly
        lag = instant_lags(s)
    # the twin's device time is each frame's true instant on the twin's clock, which differs from
    # the session's by one constant per segment, the same for every unit: the units' lags agree
    # to well within the protocol's guard, which a window's samples would otherwise cross
    assert lag.shape == (UNITS, 2) and np.ptp(lag, axis=0).max() < 0.25 * guard, lag
    summaries = solve_plate(path)
    assert [c["stream"] for c in summaries] == ["imu", "imu2", "imu3"]
    for unit, summary in zip(truth["units"], summaries, strict=True):
        check_unit(path, summary["calibration"], unit["stream"], unit)


PLATE = """[bench]
unit_serial = "PLATE1"

[[imu]]
link = "serial"
profile = "imu12_serial"
port = "/dev/ttyUSB0"
unit_serial = "SN1"

[[imu]]
link = "can"
profile = "imu12_can"
interface = "socketcan"
channel = "can0"
unit_serial = "SN2"
mounting = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]

[table]
host = "192.168.0.50"
port = 502

[protocol]
positions = 8
"""


def test_a_plate_profile_lists_each_unit_with_its_link_serial_and_mounting(tmp_path):
    (tmp_path / "p.toml").write_text(PLATE)
    bench = BenchProfile.load(tmp_path / "p.toml")
    assert [(u.unit_serial, u.link, u.stream) for u in bench.units] == [
        ("SN1", "serial", "imu"), ("SN2", "can", "imu2")]
    assert bench.units[0].mounting is None
    assert np.array_equal(bench.units[1].mounting @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    assert bench.units[1].address == {"interface": "socketcan", "channel": "can0"}
    assert (bench.link, bench.imu_address, bench.unit_serial) == ("serial", "/dev/ttyUSB0",
                                                                  "PLATE1")


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace('"SN2"', '"SN1"'), "repeat a unit_serial"),
    (lambda t: t.replace('channel = "can0"', 'channel = "can0"\n').replace(
        'link = "can"\nprofile = "imu12_can"\ninterface = "socketcan"\nchannel = "can0"',
        'link = "serial"\nprofile = "imu12_serial"\nport = "/dev/ttyUSB0"'),
     "repeat a address"),
    (lambda t: t.replace('unit_serial = "SN2"\n', ""), "[imu #2] unit_serial: missing"),
    (lambda t: t.replace('"SN2"', '"../x"'), "names the unit's calibration file"),
    (lambda t: t.replace("[0.0, 0.0, 1.0]]", "[0.0, 0.0, 2.0]]"), "must be a rotation"),
    (lambda t: t.replace("[protocol]", '[protocol]\nkind = "static"').replace(
        "[table]\nhost = \"192.168.0.50\"\nport = 502\n", ""), "records one unit"),
])
def test_bad_plate_profiles_are_refused_with_the_fix(tmp_path, edit, message):
    from drivers.profile import ProfileError

    (tmp_path / "p.toml").write_text(edit(PLATE))
    with pytest.raises(ProfileError) as caught:
        BenchProfile.load(tmp_path / "p.toml")
    assert message in str(caught.value)


@pytest.mark.parametrize("units, message", [
    ([], "non-empty list"),
    ([{"stream": "imu9", "unit_serial": "A"}], "names stream 'imu9'"),
    ([{"stream": "imu", "unit_serial": "a/b"}], "must be 1-64 letters"),
    ([{"stream": "imu", "unit_serial": "A"}, {"stream": "imu2", "unit_serial": "A"}],
     "repeats a unit_serial"),
    ([{"stream": "imu", "unit_serial": "A", "mounting": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}],
     "not a 3 x 3 rotation"),
    ([{"stream": "imu", "unit_serial": "A", "mounting": "eye"}], "not a 3 x 3 rotation"),
    (["imu"], "not a unit"),
])
def test_session_units_that_are_not_units_of_the_file_are_refused(units, message):
    with pytest.raises(SessionFormatError) as caught:
        recorded_units({"units": units}, {"imu": None, "imu2": None}, "s.h5")
    assert message in str(caught.value)


def test_a_one_unit_session_has_no_units_entry():
    assert recorded_units({"unit_serial": "SN1"}, {"imu": None}, "s.h5") == []


def test_one_imu_section_is_one_unit_on_stream_imu_as_before():
    bench = BenchProfile.load("drivers/profiles/bench_serial.toml")
    assert not bench.plate and len(bench.units) == 1
    unit = bench.units[0]
    assert (unit.unit_serial, unit.stream, unit.mounting) == ("SN0001", "imu", None)
    assert (unit.link, unit.address) == (bench.link, bench.imu_address) == ("serial",
                                                                           "/dev/ttyUSB0")
