"""Issue 19's acceptance for the MAVLink link: the MAVLink twin (a flight controller streaming
SCALED_IMU, pymavlink on both sides) serves the hand bench's accelerometer triad over a real pty or
UDP on 127.0.0.1; `station record` runs a free-static session against it through the bench profile
`station twin` writes, and `station solve` calibrates it within its chi2 bounds, the recovered
sensitivities and biases within their sigmas of the twin's truth."""

import io
import json
import subprocess

import numpy as np
import pytest
from scipy import stats
from twinproc import STATION, TwinProcess

from station import cli
from station.acquire.bench import BenchProfile, record
from station.acquire.operator import ConsoleOperator
from station.calfiles.calfile import load
from station.session import Session
from station.twin.served import HandTwin

FALSE_ALARM = 1e-3
"""Two-sided false-alarm probability of each check (Bonferroni over the values it checks)."""




@pytest.fixture(scope="module", params=["pty", "udp"])
def solved(request, tmp_path_factory):
    """A free-static session of 12 poses recorded from the MAVLink twin, solved by `station
    solve --json` (at 25x, not the serial tests' 40x: pymavlink packs and parses each message in
    Python, 8 s of CPU for the session where the serial link's numpy takes 6.5; a loaded host
    must still keep up with the technician's metronome): (link, truth, session path,
    calibration, bench profile text). pty: the twin and `station record`'s code in this
    process; udp: `station twin --link mavlink --udp` and
    `station record` as separate processes talking over 127.0.0.1."""
    tmp = tmp_path_factory.mktemp(request.param)
    record_ = _record_in_process if request.param == "pty" else _record_by_the_commands
    truth = record_(tmp)
    assert cli.main(["solve", str(tmp / "s.h5"), "--json"]) == 0
    serial = "SN-FC" if request.param == "pty" else "SIM-12"  # `station twin` names it by seed
    return (request.param, truth, tmp / "s.h5", load(tmp / "s.cal.json", unit_serial=serial),
            (tmp / "b.toml").read_text())


def _record_in_process(tmp) -> dict:
    """`station.acquire.bench.record` against a `HandTwin` on a pty; the twin's truth."""
    with HandTwin("static", seed=11, poses=12, link="mavlink") as twin:
        (tmp / "b.toml").write_text(twin.profile_text("SN-FC"))
        profile = BenchProfile.load(tmp / "b.toml")
        summary = record(profile, tmp / "s.h5", ConsoleOperator(io.StringIO("\n" * 50),
                                                                  io.StringIO()))
        truth = twin.truth()
    assert twin.error is None
    assert summary["positions_done"] == profile.positions == 12
    return truth


def _record_by_the_commands(tmp) -> dict:
    """`station twin ... --udp` in one process, `station record` in another; the twin's truth
    (printed when it stops)."""
    with TwinProcess("--protocol", "static", "--link", "mavlink", "--udp",
                     "--positions", "12", "--seed", "12", "--profile-out", str(tmp / "b.toml"),
                     "--lifetime", "1500") as twin:  # lockstep time: a hang guard only
        started = twin.started
        assert started["imu"]["link"] == "mavlink"
        assert started["imu"]["port"].startswith("udpin:127.0.0.1:")
        rec = subprocess.run([*STATION, "record", "--profile", str(tmp / "b.toml"), "--out",
                              str(tmp / "s.h5"), "--json"], check=False, input="\n" * 12,
                             text=True, capture_output=True, timeout=1200)
        assert rec.returncode == 0, rec.stderr
        assert json.loads(rec.stdout)["positions_done"] == 12
    truth = twin.truth
    assert truth["turns"] == 12
    return truth


def test_the_bench_profile_names_the_mavlink_link(solved):
    link, _, _, _, text = solved
    assert 'link = "mavlink"' in text and 'profile = "imu6_scaled_mavlink"' in text
    assert ('port = "udpin:127.0.0.1:' in text) == (link == "udp")


@pytest.mark.parametrize("args, message", [
    (["--protocol", "rotary", "--link", "mavlink"], "serial link only"),
    (["--protocol", "iron", "--link", "mavlink"], "4 accelerometers"),
    (["--protocol", "static", "--udp"], "--udp serves the MAVLink link"),
])
def test_station_twin_refuses_what_mavlink_cannot_serve(tmp_path, capsys, args, message):
    assert cli.main(["twin", *args, "--profile-out", str(tmp_path / "x.toml")]) == 2
    assert message in capsys.readouterr().err


def test_the_chi2_is_within_its_bounds(solved):
    _, _, _, cal, _ = solved
    chi2, dof = cal.fit["chi2"], cal.fit["dof"]
    low, high = stats.chi2.ppf(FALSE_ALARM / 2, dof), stats.chi2.isf(FALSE_ALARM / 2, dof)
    assert dof > 0 and low <= chi2 <= high, (chi2, dof, low, high)


def test_the_calibration_matches_the_truth(solved):
    _, truth, _, cal, _ = solved
    a = np.array(truth["a"])
    z = np.concatenate([(cal.bias - truth["bias"]) / cal.bias_sigma,
                        (cal.scale_factors - np.linalg.norm(a, axis=0)) / cal.scale_factors_sigma])
    assert np.all(np.abs(z) < stats.norm.isf(FALSE_ALARM / 2 / z.size)), z
    assert cal.units == ("m/s^2",) * 3


def test_the_session_holds_the_mavlink_stream(solved):
    """The stream's counts are mG and mrad/s (SCALED_IMU's fixed scales), every sample numbered in
    turn; at rest the gyros read their biases. Rest: every gyro within 8 mrad/s of its median
    (turns reach ~1 rad/s; the few turn samples slower than that, at a turn's ends, move the mean
    by < 1e-5 rad/s). There the per-sample noise is at most 2.5 mrad/s (0.01 deg/s/sqrt(Hz) at
    200 Hz) and dithers the 1 mrad/s count (no bias); over >= 4e4 samples the mean's standard
    error is <= 1.3e-5 rad/s, and 1e-4 rad/s is 7.7 of them."""
    _, truth, path, _, _ = solved
    with Session.open(path) as session:
        spec, stream = session.specs["imu"], session.stream("imu")
        assert session.metadata["profiles"]["imu"]["mavlink"]["message"] == "SCALED_IMU"
        seq, counts = np.asarray(stream.seq), np.asarray(stream.counts)
    np.testing.assert_allclose(spec.counts_per_unit, [1000 / 9.80665] * 3 + [1000.0] * 3,
                               rtol=1e-12)
    assert spec.units == ("m/s^2",) * 3 + ("rad/s",) * 3
    assert np.all(np.diff(seq) == 1)
    gyro = counts[:, 3:] / 1000.0
    rest = np.all(np.abs(gyro - np.median(gyro, axis=0)) < 8e-3, axis=1)
    assert np.count_nonzero(rest) >= 4e4 and np.count_nonzero(~rest) > 0
    np.testing.assert_allclose(gyro[rest].mean(axis=0), truth["gyro"]["bias"], rtol=0, atol=1e-4)


def test_the_hand_rig_turns_at_the_rate_its_gyros_sense():
    """HandRig.rates against the attitude it turns through: -C' C^T = [w x] by central
    differences (error ~ h^2 |C'''| ~ 1e-9), and |w| integrates to the turn's angle."""
    from scipy.spatial.transform import Rotation

    from drivers.clock import ScaledClock
    from station.twin.hand_bench import HandRig

    clock = ScaledClock(1.0, start=10.0)
    rig = HandRig(None, clock, 9.8, turn_time=2.0)
    rig.next_turn = 10.5
    rig.orientation = Rotation.from_rotvec([0.9, -1.4, 0.6]).as_matrix()
    t, h = np.linspace(10.0, 13.0, 3001), 1e-5
    c_dot = (rig.attitude(t + h) - rig.attitude(t - h)) / (2 * h)
    omega = -c_dot @ np.transpose(rig.attitude(t), (0, 2, 1))
    w = np.stack([omega[:, 2, 1], omega[:, 0, 2], omega[:, 1, 0]], axis=1)
    smooth = (np.abs(t - 10.5) > 2 * h) & (np.abs(t - 12.5) > 2 * h)  # s'' jumps at the ends
    np.testing.assert_allclose(rig.rates(t)[smooth], w[smooth], rtol=0, atol=1e-7)
    assert np.all(rig.rates(t[(t <= 10.5) | (t >= 12.5)]) == 0)
    angle = np.trapezoid(np.linalg.norm(rig.rates(t), axis=1), t)
    assert angle == pytest.approx(np.linalg.norm([0.9, -1.4, 0.6]), rel=1e-5)
