"""The right-angle-iron protocol on the virtual iron bench (4 accelerometers through the real serial
driver): stillness found without key presses, faces recognised from the data, and the solution
within 3 sigma of the truth; face recognition and refusals on their own."""

import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from station.acquire.operator import SimulatedTechnician
from station.acquire.recorder import Recorder
from station.errors import CalibrationInputError
from station.protocols.iron import FACE_UP, IronProtocol, IronSettings
from station.protocols.rotary import ProtocolError
from station.protocols.still import StreamTap
from station.reduce.iron import recognise_faces
from station.reduce.still import pose_windows, up_direction
from station.session import Session, SessionWriter
from station.solve.constraints import FACES, from_faces
from station.twin.hand_bench import ACC4, HandBench, record_iron_session

SEED = 2


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """One two-mounting session (12 poses) recorded on the bench at 40x: (path, truth, readings,
    result)."""
    path = tmp_path_factory.mktemp("iron") / "iron.h5"
    truth, readings, result = record_iron_session(path, seed=SEED, mountings=2)
    return path, truth, readings, result


def _angles(a):
    u = a / np.linalg.norm(a, axis=0)
    return np.arccos(np.clip(u.T @ u, -1, 1))


FAMILY_FALSE_ALARM = 1e-3
"""Chance that an efficient fit fails the z test below in any of its 14 parameters (Bonferroni:
two-sided per parameter at 1e-3 / 14, |z| < 3.97); 3 sigma for each would fail 3.7 % of runs,
and the session's noise changes from run to run with the host's timing."""


def test_recovers_biases_gains_and_angles_within_their_sigma(recorded):
    _, truth, _, result = recorded
    i, k = np.triu_indices(4, 1)
    z = {
        "bias": (result.bias - truth.bias) / result.bias_sigma,
        "gain": (result.scale_factors - np.linalg.norm(truth.a, axis=0))
        / result.scale_factors_sigma,
        "angle": (result.axis_angles[i, k] - _angles(truth.a)[i, k])
        / result.axis_angles_sigma[i, k],
    }
    limit = stats.norm.isf(FAMILY_FALSE_ALARM / 2 / sum(v.size for v in z.values()))
    for name, values in z.items():
        assert np.all(np.abs(values) < limit), (name, values, limit)
    # the uncertainties are those of 5 s means of 100 ug/sqrt(Hz) noise, not vacuous
    assert np.all(result.bias_sigma < 5e-4) and np.all(result.scale_factors_sigma < 1e-4)
    # the model explains the data: chi2 / dof near 1 (sigma = the windows' standard errors)
    assert 0.3 < result.chi2 / result.dof < 2.5, (result.chi2, result.dof)


def test_faces_recognised_match_the_true_geometry(recorded):
    _, truth, readings, _ = recorded
    # turns: mounting 1, six faces, mounting 2, six faces -> the poses are the turns to a face
    up = np.delete(truth.up, [0, 7], axis=0)
    assert len(up) == readings.M.shape[1] == 12
    c = readings.constraints()
    true_h = np.einsum("ij,ij->i", up[c.j], up[c.k])
    # squareness 0.0002 deg = 3.5e-6 rad per axis: a right angle errs by ~5e-6 rad; 5 sigma
    np.testing.assert_allclose(c.h, true_h, atol=2.5e-5)
    assert readings.mountings.tolist() == [0] * 6 + [1] * 6


def test_windows_are_still_and_events_in_order(recorded):
    path, truth, readings, _ = recorded
    with Session.open(path) as s:
        events = s.events()
    kinds = [e.kind for e in events if e.position == 0]
    assert kinds == ["position_start", "static_start", "static_end", "position_done"]
    windows, _ = pose_windows(events)
    np.testing.assert_allclose(np.diff(windows, axis=1), 5.0)  # hold = 5 s
    np.testing.assert_allclose(np.diff(readings.windows, axis=1), 5.0 - 1 / 200)
    # the readings are the truth a^T (g up) + b within 5 sigma of their standard errors
    up = np.delete(truth.up, [0, 7], axis=0)
    expected = truth.a.T @ (truth.gravity * up.T) + truth.bias[:, None]
    assert np.all(np.abs(readings.M - expected) < 5 * readings.sigma + 1e-6)


def test_live_results_read_back(recorded):
    path, _, readings, result = recorded
    with Session.open(path) as s:
        live = s.results("live")
    np.testing.assert_array_equal(live.readings, readings.M)
    np.testing.assert_array_equal(live.calibration.bias, result.bias)


def test_recognise_faces_relative_to_the_first_pose():
    rng = np.random.default_rng(0)
    b = Rotation.random(2, random_state=rng).as_matrix()
    order = ["-y", "+z", "+y", "-x", "-z", "+x"]
    up = np.array([bk @ FACE_UP[f] for bk in b for f in order])
    up += 0.05 * rng.standard_normal(up.shape)  # 3 deg of noise is within the tolerance
    labels = recognise_faces(up / np.linalg.norm(up, axis=1, keepdims=True), [0] * 6 + [1] * 6)
    c = from_faces(labels, [0] * 6 + [1] * 6)
    exact = np.array([bk @ FACE_UP[f] for bk in b for f in order])
    np.testing.assert_allclose(c.h, np.round(np.einsum("ij,ij->i", exact[c.j], exact[c.k])))
    assert labels[0] == labels[6] == "+x"


def test_a_pose_off_the_faces_is_refused():
    up = np.array([[0, 0, 1], [1, 0, 0], [0, np.sqrt(0.5), np.sqrt(0.5)]], float)
    with pytest.raises(CalibrationInputError, match="pose 3.*not on a face"):
        recognise_faces(up, [0, 0, 0])


def test_up_direction_through_the_nominal_layout():
    v = np.array([[0.0, 0.6, 0.8], [1.0, 0.0, 0.0]])
    z = 9.8 * ACC4.T @ v.T + 0.3
    np.testing.assert_allclose(up_direction(z, ACC4, bias_guess=np.full(4, 0.3)), v, atol=1e-12)


def test_settings_are_checked():
    with pytest.raises(ValueError, match="faces"):
        IronSettings(faces=("+x", "up"))
    with pytest.raises(ValueError, match="mountings"):
        IronSettings(mountings=0)


def test_a_technician_who_does_not_move_the_iron_times_out(tmp_path):
    """No key press: a still stream that began before the request is not a new pose."""

    class Idle(SimulatedTechnician):
        def wait(self, instruction):
            self.prompt(instruction.text)

    with HandBench(seed=1) as bench, bench.driver() as imu:
        idle = Idle(bench.rig, bench.clock)
        protocol = IronProtocol(idle, bench.clock, ACC4,
                                IronSettings(gravity=bench.gravity, timeout=8.0))
        tap = StreamTap(imu, bench.stream_spec.rate_hz, bench.stream_spec.counts_per_unit)
        path = tmp_path / "idle.h5"
        writer = SessionWriter.create(path, {**protocol.metadata(), "unit_serial": "T"},
                                      {"imu": bench.stream_spec}, clock=bench.clock)
        with writer, Recorder(writer, tap, clock=bench.clock) as recorder, \
                pytest.raises(ProtocolError, match="no still pose within 8 s after re-mounting 1"):
            protocol.run(recorder, tap)
    with Session.open(path) as s:
        assert s.events()[-1].kind == "abort"
        assert "position_done" not in [e.kind for e in s.events()]


def test_iron_constants():
    for f in FACES:
        assert FACE_UP[f] @ FACE_UP[f] == 1
    assert FACE_UP["+z"] @ np.array([0, 0, -1]) == 1  # standing on +z, -z of the iron points up
