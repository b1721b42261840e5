"""Static-interval detection in a continuous recording, in the style of PX4's still detector.

The dispersion statistic is the moving variance of every channel over a centred window, divided by
that channel's noise variance measured on a rest period and averaged over the channels:

    s(t) = (1/c) sum_k var_w(x_k)(t) / sigma_k^2        (about 1 at rest, >> 1 in motion)

so every threshold is a multiple of the measured noise, never a value in counts. Hysteresis: the
unit becomes still when s drops below `enter` and stays still until s exceeds `leave` > `enter`.
Still intervals shorter than `min_still` are dropped, and motions longer than `timeout` (the
operator took too long to put the unit down) are reported. See docs/stillness.md.
"""

from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError


@dataclass(frozen=True)
class StillIntervals:
    """Still intervals of a recording of K samples and c channels, with their averaged readings.

    intervals : (P, 2) [start, stop) sample indices, in time order.
    mean, stderr : (P, c) mean of each channel over each interval and its standard error
                   sd / sqrt(N) (white-noise assumption: an underestimate when the noise is
                   coloured).
    rest : (2,) [start, stop) of the rest period the noise was measured on.
    noise : (c,) noise standard deviation of each channel on the rest period (window-scale).
    dispersion : (K,) the normalised statistic s(t); inf where the window does not fit.
    overdue : (Q, 2) [start, stop) motions (before or between still intervals) longer than timeout.
    """

    intervals: np.ndarray
    mean: np.ndarray
    stderr: np.ndarray
    rest: np.ndarray
    noise: np.ndarray
    dispersion: np.ndarray
    overdue: np.ndarray

    @property
    def lengths(self) -> np.ndarray:
        """(P,) samples in each interval."""
        return self.intervals[:, 1] - self.intervals[:, 0]


def detect_still(
    samples,
    fs: float,
    *,
    rest=None,
    rest_length: float = 2.0,
    window: float = 1.0,
    enter: float = 4.0,
    leave: float = 8.0,
    min_still: float = 1.5,
    timeout: float = 60.0,
) -> StillIntervals:
    """Still intervals of `samples` (K, c) sampled at `fs` Hz (any units, e.g. raw counts).

    rest       (start, stop) sample indices of a known rest period (e.g. the first seconds), or None
               to use the quietest `rest_length` seconds of the recording.
    window     length of the moving-variance window, seconds.
    enter, leave  hysteresis thresholds on s(t), in multiples of the rest noise variance.
    min_still  shortest still interval kept, seconds.
    timeout    longest acceptable motion before or between still intervals, seconds (reported).
    """
    x = _as_samples(samples)
    k = x.shape[0]
    w = _window_samples(window, fs, k)
    _check_thresholds(enter, leave, min_still, timeout)
    mv = moving_variance(x - np.median(x, axis=0), w)
    rest = _rest_window(mv, rest, rest_length, fs, w)
    noise_var = mv[rest[0] + w // 2 : rest[1] - w // 2].mean(axis=0)  # windows inside the rest
    if np.any(~(noise_var > 0)):
        raise CalibrationInputError(
            f"channels {np.flatnonzero(~(noise_var > 0)).tolist()} do not vary at all on the rest "
            f"period [{rest[0]}, {rest[1]}).",
            "Drop constant channels, or give a rest period where the sensor noise is visible.",
        )
    s = (mv / noise_var).mean(axis=1)
    intervals = _runs(hysteresis(s, enter, leave))
    intervals = intervals[intervals[:, 1] - intervals[:, 0] >= round(min_still * fs)]
    mean, stderr = _interval_stats(x, intervals)
    return StillIntervals(
        intervals=intervals,
        mean=mean,
        stderr=stderr,
        rest=rest,
        noise=np.sqrt(noise_var),
        dispersion=s,
        overdue=_overdue(intervals, round(timeout * fs)),
    )


def moving_variance(x: np.ndarray, w: int) -> np.ndarray:
    """(K, c) population variance of x over the centred window of w samples (w odd); inf at the
    ends.

    Computed from running sums; x should be roughly centred (e.g. minus its median) for accuracy.
    """
    k, c = x.shape
    h = w // 2
    zero = np.zeros((1, c))
    s1 = np.concatenate([zero, np.cumsum(x, axis=0)])
    s2 = np.concatenate([zero, np.cumsum(x * x, axis=0)])
    mean = (s1[w:] - s1[:-w]) / w
    var = np.maximum((s2[w:] - s2[:-w]) / w - mean * mean, 0.0)
    out = np.full((k, c), np.inf)
    out[h : k - h] = var
    return out


def hysteresis(s: np.ndarray, enter: float, leave: float) -> np.ndarray:
    """Boolean still state: True from a sample with s < enter until the next sample with s > leave.

    Vectorised: the state at t is set by whichever of the two events happened last at or before t.
    """
    idx = np.arange(s.size)
    last_enter = np.maximum.accumulate(np.where(s < enter, idx, -1))
    last_leave = np.maximum.accumulate(np.where(s > leave, idx, -1))
    return last_enter > last_leave


def _runs(mask: np.ndarray) -> np.ndarray:
    """(P, 2) [start, stop) of the runs of True in a boolean array."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return np.stack([np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)], axis=1)


def _rest_window(mv: np.ndarray, rest, rest_length: float, fs: float, w: int) -> np.ndarray:
    """The given rest period [start, stop), checked, or the quietest stretch of rest_length seconds.

    Quietest = smallest sum over channels of log(mean moving variance) over the windows that lie
    inside the stretch: invariant to the channels' units.
    """
    k = mv.shape[0]
    h = w // 2
    if rest is not None:
        r = np.asarray(rest)
        if r.shape != (2,) or not np.issubdtype(r.dtype, np.integer):
            raise CalibrationInputError(
                f"rest period {rest!r} is not a pair of sample indices.",
                "Give (start, stop) integers.",
            )
        r = np.clip(r, 0, k)
        if r[1] - r[0] < w:
            raise CalibrationInputError(
                f"rest period {rest!r} holds fewer than one window ({w} samples) of the recording "
                f"({k} samples).",
                "Give a longer rest period, or a shorter window.",
            )
        return r
    n = round(rest_length * fs)
    if n < w or n > k:
        raise CalibrationInputError(
            f"rest_length {rest_length} s ({n} samples) must span at least one window ({w}) "
            f"and fit in the recording ({k} samples).",
            "Adjust rest_length or window, or give the rest period explicitly.",
        )
    centres = n - 2 * h  # windows inside one stretch
    inner = mv[h : k - h]
    run = np.concatenate([np.zeros((1, inner.shape[1])), np.cumsum(inner, axis=0)])
    with np.errstate(divide="ignore"):
        score = np.log((run[centres:] - run[:-centres]) / centres).sum(axis=1)
    start = int(np.argmin(score))  # first window centre h + start, so the stretch starts at start
    return np.array([start, start + n])


def _interval_stats(x: np.ndarray, intervals: np.ndarray):
    """(P, c) means and standard errors sd / sqrt(N) over each interval."""
    mean = np.array([x[a:b].mean(axis=0) for a, b in intervals]).reshape(-1, x.shape[1])
    sd = np.array([x[a:b].std(axis=0, ddof=1) for a, b in intervals]).reshape(-1, x.shape[1])
    return mean, sd / np.sqrt(intervals[:, 1:] - intervals[:, :1])


def _overdue(intervals: np.ndarray, limit: int) -> np.ndarray:
    """(Q, 2) motions before the first or between two still intervals longer than limit samples."""
    starts = np.concatenate([[0], intervals[:, 1]])[: len(intervals)]
    gaps = np.stack([starts, intervals[:, 0]], axis=1).reshape(-1, 2)
    return gaps[gaps[:, 1] - gaps[:, 0] > limit]


def _as_samples(samples) -> np.ndarray:
    x = np.asarray(samples, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2 or x.shape[0] < 3:
        raise CalibrationInputError(
            f"samples have shape {np.shape(samples)}.", "Give a (samples, channels) array."
        )
    if not np.all(np.isfinite(x)):
        raise CalibrationInputError(
            "samples contain NaN or infinite values.", "Remove or interpolate the invalid samples."
        )
    return x


def _window_samples(window: float, fs: float, k: int) -> int:
    """Odd number of samples in the moving window, checked against the recording length."""
    if not (np.isfinite(fs) and fs > 0):
        raise CalibrationInputError(f"sample rate {fs!r} is not positive.", "Give fs in Hz.")
    w = 2 * round(window * fs / 2) + 1
    if w < 3 or w > k:
        raise CalibrationInputError(
            f"window {window} s is {w} samples for a recording of {k} samples.",
            "Use a window of at least 3 samples and shorter than the recording.",
        )
    return w


def _check_thresholds(enter: float, leave: float, min_still: float, timeout: float) -> None:
    if not 1 < enter < leave:
        raise CalibrationInputError(
            f"thresholds enter={enter}, leave={leave} are not 1 < enter < leave.",
            "They are multiples of the rest noise variance (1 = at rest): e.g. enter=4, leave=8.",
        )
    if not (min_still > 0 and timeout > 0):
        raise CalibrationInputError(
            f"min_still={min_still} s and timeout={timeout} s must be positive.",
            "Give both in seconds.",
        )
