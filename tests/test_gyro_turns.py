"""Gyro calibration from turns of known angle (station/solve/gyro_turns.py, Hwangbo & Kanade Eq. 31)
on simulated turns with a known truth: recovery within the noise of the integrals, turn senses,
handedness, and the gravity-carry check."""

import numpy as np
import pytest

from station.errors import CalibrationInputError
from station.solve.gyro_turns import (
    angle_deg,
    calibrate_turns,
    carry_gravity,
    gravity_carry_errors,
    integrate,
    mirrored,
    turn_senses,
)

FS = 200.0
TURN_S = 4.0  # duration of one turn
STILL_S = 2.0  # still before each turn: its mean is the bias
NOISE = 2.0  # counts per sample
A_TRUE = np.array(  # gyro i = column i: axis (near e_i) times scale [counts per rad/s]
    [[950.0, 4.0, -10.0], [-3.0, 930.0, 30.0], [12.0, -35.0, 935.0]]
)
B_TRUE = np.array([2.0, -4.5, -3.6])


def unit(face: str) -> np.ndarray:
    return {"x": np.eye(3)[0], "y": np.eye(3)[1], "z": np.eye(3)[2]}[face[1]] * (
        1.0 if face[0] == "+" else -1.0
    )


def turn_rates(axis, angle=2 * np.pi, seconds=TURN_S) -> np.ndarray:
    """(N, 3) rates of a raised-cosine turn whose samples sum to angle * FS exactly."""
    n = round(seconds * FS)
    profile = 1 - np.cos(2 * np.pi * np.arange(n) / n)
    return np.outer(profile * angle / seconds, axis)


def readings(rates, rng) -> np.ndarray:
    return rates @ A_TRUE + B_TRUE + rng.normal(0, NOISE, rates.shape)


def simulate(senses, rng):
    """Integrals (3, n) of the turns, each with the mean of a still stretch before it as bias."""
    cols = []
    for s in senses:
        still = readings(np.zeros((round(STILL_S * FS), 3)), rng)
        cols.append(integrate(readings(turn_rates(unit(s)), rng), FS, still.mean(axis=0)))
    return np.array(cols).T


# sd of one integral: the turn's noise plus its bias estimate's noise times the turn duration
SIGMA_INT = NOISE * np.sqrt(TURN_S * FS) / FS * np.sqrt(1 + TURN_S / STILL_S)


@pytest.mark.parametrize("senses", [("-x", "-y", "-z"), ("+x", "-y", "+z"), ("+y", "+z", "-x")])
def test_turns_recover_the_gyro_in_the_iron_frame(senses):
    rng = np.random.default_rng(7)
    w = simulate(senses, rng)
    assert turn_senses(w, [f"+{s[1]}" for s in senses]) == senses
    cal = calibrate_turns(w, senses, bias=B_TRUE, sigma=SIGMA_INT)
    # three turns determine a exactly: a^T = W Theta^-1, each entry's error is sd SIGMA_INT / 2 pi
    entry_sd = SIGMA_INT / (2 * np.pi)
    np.testing.assert_allclose(cal.a, A_TRUE, atol=5 * entry_sd)
    np.testing.assert_allclose(
        cal.fit.scale_factors, np.linalg.norm(A_TRUE, axis=0), atol=5 * entry_sd
    )
    cos = (A_TRUE.T @ A_TRUE) / np.outer(*2 * [np.linalg.norm(A_TRUE, axis=0)])
    angles = np.arccos(np.clip(cos, -1, 1))
    np.testing.assert_allclose(cal.fit.axis_angles, angles, atol=5 * np.sqrt(2) * entry_sd / 930)
    assert not mirrored(A_TRUE, cal.a)


def test_apply_gives_rates_in_rad_per_second():
    rng = np.random.default_rng(3)
    senses = ("-x", "-y", "-z")
    cal = calibrate_turns(simulate(senses, rng), senses, bias=B_TRUE, sigma=SIGMA_INT)
    omega = np.array([[0.5, -1.0, 2.0]])
    np.testing.assert_allclose(cal.apply((omega @ A_TRUE + B_TRUE).T), omega.T, atol=1e-3)


def test_wrong_turn_senses_mirror_the_gyro():
    rng = np.random.default_rng(11)
    senses = ("-x", "-y", "-z")
    w = simulate(senses, rng)
    flipped = tuple(("+" if s[0] == "-" else "-") + s[1] for s in senses)  # imucal's sign trap
    cal = calibrate_turns(w, flipped, bias=B_TRUE, sigma=SIGMA_INT)
    assert mirrored(A_TRUE, cal.a)
    np.testing.assert_allclose(cal.a, -A_TRUE, atol=5 * SIGMA_INT / (2 * np.pi))


def test_carry_gravity_follows_a_quarter_turn():
    # body turned +90 deg about its y axis: a world-fixed vector along body z ends along body -x
    carried = carry_gravity(turn_rates(np.eye(3)[1], np.pi / 2, 1.0), FS, [0, 0, 9.81])
    np.testing.assert_allclose(carried, [-9.81, 0, 0], atol=1e-9)
    # a full turn about z leaves gravity along z where it was
    carried = carry_gravity(turn_rates(np.eye(3)[2]), FS, [0, 0, 9.81])
    np.testing.assert_allclose(carried, [0, 0, 9.81], atol=1e-9)


def test_gravity_carry_errors_expose_a_mirrored_gyro():
    """Still, a quarter turn about y, still, a half turn about z, still: accelerometer = gravity."""
    still = np.zeros((200, 3))
    rates = np.vstack(
        [
            still,
            turn_rates(np.eye(3)[1], np.pi / 2, 1.0),
            still,
            turn_rates(np.eye(3)[2], np.pi, 1.0),
            still,
        ]
    )
    f = np.empty_like(rates)
    f[0] = [0, 0, 9.81]
    for k in range(1, len(rates)):
        f[k] = carry_gravity(rates[k - 1 : k], FS, f[k - 1])
    intervals = np.array([[0, 200], [400, 600], [800, 1000]])
    errors = gravity_carry_errors(f, rates, FS, intervals)
    np.testing.assert_allclose(errors[:, 1], [90, 180], atol=1e-6)
    np.testing.assert_allclose(errors[:, 2], 0, atol=1e-6)
    # the mirrored gyro turns the other way: 180 deg off after the quarter turn
    assert gravity_carry_errors(f, -rates, FS, intervals)[0, 2] == pytest.approx(180, abs=1e-6)


def test_angle_deg():
    assert angle_deg([1, 0, 0], [0, 2, 0]) == pytest.approx(90)
    assert angle_deg([1, 1, 0], [1, 1, 0]) == pytest.approx(0, abs=1e-12)


@pytest.mark.parametrize(
    "w, senses, sigma, words",
    [
        (np.ones((3, 2)), ("+x", "+y", "+z"), 1.0, "shape"),
        (np.eye(3) * 6000, ("+x", "+y", "+y"), 1.0, "span"),
        (np.eye(3) * 6000, ("+x", "+y", "+z"), None, "sigma"),
    ],
)
def test_bad_turn_input_is_refused_with_advice(w, senses, sigma, words):
    with pytest.raises(CalibrationInputError, match=words):
        calibrate_turns(w, senses, sigma=sigma)


def test_bad_triads_and_faces_are_refused():
    with pytest.raises(CalibrationInputError, match="3 x 3"):
        mirrored(np.eye(3), np.eye(2))
    with pytest.raises(CalibrationInputError, match="face"):
        turn_senses(np.eye(3), ["+x", "+q", "+z"])
    with pytest.raises(CalibrationInputError, match="samples"):
        integrate(np.ones(5), FS, 0.0)
