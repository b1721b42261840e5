"""Still-interval detector: moving variance, hysteresis, noise-relative thresholds,
minimum still time, timeout report, and bad input."""

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from station.errors import CalibrationInputError
from station.model.unit import SensorUnit
from station.reduce.stillness import detect_still, hysteresis, moving_variance
from station.sim.static import simulate_static

FS = 100.0
COUNTS = 400.0  # counts per m/s^2, about an Xsens MTi
A_TRUE = np.array([[1.01, 0.004, -0.01], [0.0, 0.99, 0.006], [0.0, 0.0, 1.0]])


def simulated(seed: int, poses: int = 15):
    """A free-static accelerometer recording (counts) with its true still intervals and readings."""
    unit = SensorUnit(
        A_TRUE, bias=[0.2, -0.1, 0.3], noise_density=0.0008, fs=FS, counts_per_unit=COUNTS, rng=seed
    )
    sim = simulate_static(unit, poses=poses, still=4.0, move=2.0, latitude_deg=45.4)
    y = sim.arrays["y"][0].astype(float)
    true_mean = (unit.project(sim.truth["v"].T) + unit.bias) * COUNTS  # (P, 3) noise-free counts
    return y, np.asarray(sim.truth["still"]), true_mean, unit


def segments(parts, channels: int = 3, seed: int = 0) -> np.ndarray:
    """A recording from (seconds, kind) parts: "still" = unit white noise, "move" = a swing of 50
    noise sd plus the noise, "bump" = white noise of variance 6 (a disturbance below 'moving')."""
    rng = np.random.default_rng(seed)
    out = []
    for seconds, kind in parts:
        k = round(seconds * FS)
        x = rng.standard_normal((k, channels))
        if kind == "move":
            x += 50 * np.sin(np.pi * np.arange(k) / k)[:, None] * np.linspace(1, -1, channels)
        elif kind == "bump":
            x *= np.sqrt(6.0)
        out.append(x)
    return np.concatenate(out)


def test_moving_variance_equals_windowed_variance():
    x = np.random.default_rng(1).normal(size=(300, 2)) * [1.0, 5.0] + [1e3, -7.0]
    w = 11
    expected = np.var(sliding_window_view(x, w, axis=0), axis=-1)  # (K - w + 1, c)
    mv = moving_variance(x - np.median(x, axis=0), w)
    np.testing.assert_allclose(mv[5:-5], expected, rtol=1e-9)
    assert np.all(np.isinf(mv[:5])) and np.all(np.isinf(mv[-5:]))


def test_hysteresis_by_hand():
    s = np.array([9, 3, 5, 7, 9, 5, 3, 9, 5])
    expected = [False, True, True, True, False, False, True, False, False]
    assert hysteresis(s, enter=4, leave=8).tolist() == expected


def test_finds_every_simulated_pose_inside_its_true_interval():
    y, truth, _, _ = simulated(seed=3)
    found = detect_still(y, FS)
    w = 101
    assert len(found.intervals) == len(truth)
    for (a, b), (ta, tb) in zip(found.intervals, truth, strict=True):
        overlap = min(b, tb) - max(a, ta)
        assert overlap >= 0.95 * (
            b - a
        )  # inside the truth (a few samples of a gentle onset at most)
        assert b - a >= (tb - ta) - 2 * w  # loses at most a window at each end
    assert found.overdue.shape == (0, 2)


def test_interval_means_unbiased_and_standard_errors_honest():
    """z = (mean - truth) / stderr is N(0, 1) for unbiased means and honest standard errors:
    over 6 x 15 x 3 = 270 values, sd(z) has a standard error of 1/sqrt(540) = 0.043, mean(z)
    0.061."""
    z = []
    for seed in range(6):
        y, _, true_mean, _ = simulated(seed)
        found = detect_still(y, FS)
        assert found.mean.shape == true_mean.shape
        z.append(((found.mean - true_mean) / found.stderr).ravel())
    z = np.concatenate(z)
    assert abs(z.std() - 1) < 0.15
    assert abs(z.mean()) < 0.25


def test_thresholds_are_relative_to_the_noise():
    """Same intervals in counts, in SI units with an offset, and with noise and motion 10x
    larger."""
    y, _, _, _ = simulated(seed=4, poses=10)
    base = detect_still(y, FS).intervals
    np.testing.assert_array_equal(detect_still(y / COUNTS + 5.0, FS).intervals, base)
    parts = [(10, "still"), (3, "move"), (6, "still"), (3, "move"), (6, "still")]
    x = segments(parts)
    np.testing.assert_array_equal(detect_still(10 * x, FS).intervals, detect_still(x, FS).intervals)
    assert len(detect_still(x, FS).intervals) == 3


def test_mixed_units_channels_stack():
    """Channels of very different scales (accelerometer counts, gyro rad/s) share one statistic."""
    x = segments([(10, "still"), (3, "move"), (6, "still")], channels=6)
    x[:, 3:] *= 1e-3
    found = detect_still(x, FS)
    assert len(found.intervals) == 2
    np.testing.assert_allclose(found.noise[3:] / found.noise[:3], 1e-3, rtol=0.3)


def test_explicit_rest_measures_the_noise():
    y, truth, _, unit = simulated(seed=5)
    ta, tb = truth[7]
    found = detect_still(y, FS, rest=(int(ta), int(tb)))
    expected = np.sqrt((unit.sigma * COUNTS) ** 2 + 1 / 12)  # white noise + quantisation, counts
    # mean of ~300 window variances of 101 samples, strongly overlapping: ~10 % is generous
    np.testing.assert_allclose(found.noise, expected, rtol=0.1)
    quietest = detect_still(y, FS)  # the quietest 2 s: the minimum of many estimates, biased low
    assert np.all((0.75 * expected < quietest.noise) & (quietest.noise < 1.05 * expected))
    assert quietest.intervals.shape == found.intervals.shape
    assert np.abs(quietest.intervals - found.intervals).max() < 101  # within one window


def test_min_still_drops_short_rests():
    x = segments([(8, "still"), (3, "move"), (2.5, "still"), (3, "move"), (6, "still")])
    # cores are shorter than the rests by one window (0.5 s here)
    assert len(detect_still(x, FS, window=0.5, min_still=1.0).intervals) == 3
    assert len(detect_still(x, FS, window=0.5, min_still=3.0).intervals) == 2


def test_hysteresis_bridges_a_small_disturbance():
    x = segments([(8, "still"), (3, "move"), (4, "still"), (2, "bump"), (4, "still")], channels=6)
    assert len(detect_still(x, FS, enter=3, leave=10).intervals) == 2  # bump s ~ 6 < leave
    assert len(detect_still(x, FS, enter=3, leave=4.5).intervals) == 3  # bump splits the rest


def test_timeout_reports_a_long_motion():
    x = segments([(8, "still")] + [(3, "move")] * 25 + [(6, "still")])  # 75 s of motion
    found = detect_still(x, FS, timeout=60.0)
    assert len(found.intervals) == 2
    ((a, b),) = found.overdue
    assert a == found.intervals[0, 1] and b == found.intervals[1, 0]
    assert 75 * FS <= b - a <= 77 * FS  # the motion plus up to one window at each side
    assert detect_still(x, FS, timeout=100.0).overdue.shape == (0, 2)


NOISE = np.random.default_rng(0).normal(size=(1000, 3))


@pytest.mark.parametrize(
    "samples, kwargs, words",
    [
        (np.full((1000, 3), np.nan), {}, "NaN"),
        (np.c_[NOISE[:, :2], np.ones(1000)], {}, "do not vary"),
        (NOISE, {"enter": 8}, "enter"),
        (NOISE, {"rest": (0, 40)}, "rest period"),
        (NOISE, {"rest": (0.0, 4.5)}, "sample indices"),
        (NOISE, {"window": 20.0}, "window"),
        (NOISE, {"rest_length": 60.0}, "rest_length"),
        (NOISE, {"timeout": 0}, "timeout"),
    ],
)
def test_bad_input_is_refused_with_advice(samples, kwargs, words):
    with pytest.raises(CalibrationInputError, match=words) as err:
        detect_still(samples, FS, **kwargs)
    assert err.value.advice
