"""Gyro calibration from hand turns between still poses (station.solve.gyro_carry): on simulated
recordings whose gyro sees the turns, the sensitivity is recovered within its stated sigma and the
carried gravity lands where the accelerometer measures it."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from station.errors import CalibrationInputError
from station.sim.static import attitude_path
from station.solve.gyro_carry import calibrate_carry

FS = 100.0
G = 9.81


def hand_recording(seed: int, a_true, poses: int = 24, acc_noise: float = 0.01,
                   gyro_noise: float = 0.003, bias=(0.02, -0.01, 0.015), axis=None):
    """(gyro (K, 3), acc (K, 3), still intervals): poses held 3 s, turns of 2 s between them.
    The attitude maps world vectors into the unit frame; the body rate of step k is
    rotvec(R_k R_{k+1}^-1) fs, so that `carry_gravity`'s C_{k+1} = C_k exp([w/fs]x) holds."""
    rng = np.random.default_rng(seed)
    if axis is None:
        rot = Rotation.random(poses, random_state=rng)
    else:  # every pose a turn about one body axis: the gyro is not determined
        rot = Rotation.from_rotvec(np.outer(rng.uniform(-np.pi, np.pi, poses), axis))
    _, att, still = attitude_path(rot, 3.0, 2.0, FS)
    omega = (att[:-1] * att[1:].inv()).as_rotvec() * FS
    omega = np.vstack([omega, omega[-1:]])
    acc = G * att.apply([0.0, 0.0, 1.0]) + acc_noise * rng.standard_normal((len(att), 3))
    gyro = omega @ np.asarray(a_true) + np.asarray(bias) \
        + gyro_noise * rng.standard_normal((len(att), 3))  # rows: z^T = w^T a + b^T
    return gyro, acc, still


def true_sensitivity(seed: int) -> np.ndarray:
    """A gyro triad 3 % off in scale, about 1 deg misaligned."""
    rng = np.random.default_rng(1000 + seed)
    return np.diag(1 + 0.03 * rng.standard_normal(3)) + 0.02 * rng.standard_normal((3, 3))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_sensitivity_is_recovered_within_its_sigma(seed):
    a_true = true_sensitivity(seed)
    gyro, acc, still = hand_recording(seed, a_true)
    cal = calibrate_carry(gyro, FS, acc, still)
    z = (cal.a - a_true) / cal.a_sigma
    assert np.max(np.abs(z)) < 4.5, z  # 9 entries: |z| < 4.5 fails with p ~ 6e-5
    assert np.sqrt(np.mean(z ** 2)) < 2.0  # the stated sigma is not tiny
    k = np.linalg.norm(a_true, axis=0)
    assert np.all(np.abs(cal.scale_factors - k) < 4.5 * cal.scale_factors_sigma)
    assert np.median(cal.errors_after_deg) < 0.25 * np.median(cal.errors_before_deg)


def test_the_bias_is_the_still_mean():
    a_true = true_sensitivity(4)
    gyro, acc, still = hand_recording(4, a_true, gyro_noise=0.0)
    cal = calibrate_carry(gyro, FS, acc, still)
    np.testing.assert_allclose(cal.bias, [0.02, -0.01, 0.015], atol=1e-12)


def test_turns_about_one_axis_are_refused_by_name():
    gyro, acc, still = hand_recording(5, np.eye(3), axis=[1.0, 0.0, 0.0])
    with pytest.raises(CalibrationInputError, match="turns|axis"):
        calibrate_carry(gyro, FS, acc, still)


def test_too_few_turns_are_refused():
    gyro, acc, still = hand_recording(6, np.eye(3), poses=4)
    with pytest.raises(CalibrationInputError, match="at least five"):
        calibrate_carry(gyro, FS, acc, still)
