"""Static-interval detection in a continuous recording, in the style of PX4's still detector.

The dispersion statistic is the moving variance of every channel over a centred window, divided by
that channel's noise variance and averaged over the channels of a group; with several groups (the
accelerometers, the gyros) the largest group's, so each group can veto stillness:

    s(t) = max_g (1/c_g) sum_{k in g} var_w(x_k)(t) / sigma_k^2     (about 1 at rest, >> 1 moving)

so every threshold is a multiple of the measured noise, never a value in counts. The noise
variance comes from a declared rest period, or robustly from the recording (`noise_level`: the
median over its still stretches, so one pose quieter than the rest does not set it). Hysteresis:
the unit becomes still when s drops below `enter` and stays still until s exceeds `leave` >
`enter`; a pose's settling (s above `enter`) is cut from its start. Still intervals shorter than
`min_still` are dropped, and motions longer than `timeout` (the operator took too long to put the
unit down) are reported; every candidate that is no still interval is reported with the reason.
See docs/stillness.md.
"""

from dataclasses import dataclass, field

import numpy as np

from station.errors import CalibrationInputError

QUANTILE = 0.1
"""The quantile of the rest-length stretches, by quietness, that gives the provisional noise
level."""


@dataclass(frozen=True)
class StillIntervals:
    """Still intervals of a recording of K samples and c channels, with their averaged readings.

    intervals : (P, 2) [start, stop) sample indices, in time order.
    mean, stderr : (P, c) mean of each channel over each interval and its standard error
                   sd / sqrt(N) (white-noise assumption: an underestimate when the noise is
                   coloured).
    rest : (2,) [start, stop) of the rest period given, or of the stretch that gave the
           provisional noise level.
    noise : (c,) noise standard deviation of each channel (window-scale): on the rest period given,
            else the median over the still stretches (docs/stillness.md).
    dispersion : (K,) the normalised statistic s(t); inf where the window does not fit.
    overdue : (Q, 2) [start, stop) motions (before or between still intervals) longer than timeout.
    settling : (P,) samples between the end of the motion (s <= leave) and the interval's start
               (s < enter): the settling cut from the start of each pose.
    rejected : ((start, stop, reason), ...) the candidates (stretches of at least a window where
               some channel group shows no motion) that hold no still interval, with the reason.
    """

    intervals: np.ndarray
    mean: np.ndarray
    stderr: np.ndarray
    rest: np.ndarray
    noise: np.ndarray
    dispersion: np.ndarray
    overdue: np.ndarray
    settling: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    rejected: tuple = ()

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
    groups: dict | None = None,
    floor=0.0,
) -> StillIntervals:
    """Still intervals of `samples` (K, c) sampled at `fs` Hz (any units, e.g. raw counts).

    rest       (start, stop) sample indices of a known rest period (e.g. the first seconds), or None
               for the robust noise level over stretches of `rest_length` seconds (`noise_level`).
    window     length of the moving-variance window, seconds.
    enter, leave  hysteresis thresholds on s(t), in multiples of the rest noise variance.
    min_still  shortest still interval kept, seconds.
    timeout    longest acceptable motion before or between still intervals, seconds (reported).
    groups     {name: column indices} of the channels that decide: s(t) is the largest of the
               groups' statistics, so each group can veto stillness (e.g. {"acc": [0, 1, 2],
               "gyro": [3, 4, 5]}); columns in no group are averaged but do not decide. None: one
               group of every column.
    floor      scalar or (c,): the least moving variance of a channel, e.g. its quantisation
               step^2 / 12 (a channel quieter than its step reads one value at rest).
    """
    x = _as_samples(samples)
    k = x.shape[0]
    w = _window_samples(window, fs, k)
    _check_thresholds(enter, leave, min_still, timeout)
    groups = _groups(groups, x.shape[1])
    mv = np.maximum(moving_variance(x - np.median(x, axis=0), w), floor)
    if rest is None:
        rest, noise_var = noise_level(mv, groups, round(rest_length * fs), w, enter, rest_length)
    else:
        rest = _rest_window(mv, rest, w)
        noise_var = mv[rest[0] + w // 2 : rest[1] - w // 2].mean(axis=0)  # windows inside the rest
    deciding = np.concatenate(list(groups.values()))
    if np.any(~(noise_var[deciding] > 0)):
        flat = deciding[~(noise_var[deciding] > 0)]
        raise CalibrationInputError(
            f"channels {flat.tolist()} do not vary at all on the rest period [{rest[0]}, "
            f"{rest[1]}).",
            "Drop constant channels, or give a rest period where the sensor noise is visible.",
        )
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = mv / noise_var
    s = _statistic(ratio, groups)
    runs = _runs(hysteresis(s, enter, leave))
    keep = runs[:, 1] - runs[:, 0] >= round(min_still * fs)
    intervals = runs[keep]
    mean, stderr = _interval_stats(x, intervals)
    settling, rejected = _candidates(s, ratio, groups, intervals, runs[~keep], w, fs,
                                     (enter, leave, min_still))
    return StillIntervals(
        intervals=intervals,
        mean=mean,
        stderr=stderr,
        rest=rest,
        noise=np.sqrt(noise_var),
        dispersion=s,
        overdue=_overdue(intervals, round(timeout * fs)),
        settling=settling,
        rejected=rejected,
    )


def noise_level(mv: np.ndarray, groups: dict, n: int, w: int, enter: float,
                rest_length: float = 2.0) -> tuple:
    """((2,) the stretch of the provisional level, (c,) noise variances) from the moving variances
    mv (K, c) without a declared rest, robust to a pose quieter than the others.

    The recording is cut into stretches of n samples; each stretch's mean window variance per
    channel is scored by sum_k log (invariant to the channels' units). The stretch at the
    `QUANTILE` of the scores gives a provisional level (the quietest stretch alone, the former
    reference, is biased low and follows one unusually quiet pose); the noise variance is then the
    median, per channel, over every stretch whose statistic on the provisional level is below
    `enter` (the still stretches). With fewer than 1 / QUANTILE stretches the provisional level is
    the quietest stretch's."""
    k = mv.shape[0]
    h = w // 2
    if n < w or n > k:
        raise CalibrationInputError(
            f"rest_length {rest_length} s ({n} samples) must span at least one window ({w}) "
            f"and fit in the recording ({k} samples).",
            "Adjust rest_length or window, or give the rest period explicitly.",
        )
    centres = n - 2 * h  # windows inside one stretch
    count = max((k - 2 * h) // centres, 1)
    means = mv[h : h + count * centres].reshape(count, centres, -1).mean(axis=1)
    deciding = np.concatenate(list(groups.values()))
    with np.errstate(divide="ignore"):
        score = np.log(means[:, deciding]).sum(axis=1)
    pick = int(np.argsort(score, kind="stable")[int(QUANTILE * (count - 1))])
    provisional = means[pick]
    with np.errstate(divide="ignore", invalid="ignore"):
        still = _statistic(means / provisional, groups) < enter
    noise = np.median(means[still], axis=0) if still.any() else provisional
    return np.array([pick * centres, pick * centres + n]), noise


def _statistic(ratio: np.ndarray, groups: dict) -> np.ndarray:
    """The largest over the groups of the mean over the group's columns of `ratio` (rows)."""
    return np.max([ratio[:, cols].mean(axis=1) for cols in groups.values()], axis=0)


def _groups(groups, c: int) -> dict:
    """The deciding channel groups {name: int array}, checked; None: every column."""
    if groups is None:
        return {"all channels": np.arange(c)}
    out = {str(name): np.asarray(cols, dtype=np.int64).ravel() for name, cols in groups.items()}
    if not out or any(not len(v) or v.min() < 0 or v.max() >= c for v in out.values()):
        raise CalibrationInputError(
            f"detection channel groups {groups!r} do not name columns of {c} channels.",
            "Give {name: [column indices]} with at least one column each.",
        )
    return out


def _candidates(s, ratio, groups, intervals, short, w, fs, limits) -> tuple:
    """((P,) settling samples of the intervals, the rejected candidates with their reasons).

    A candidate is a run of at least a window where some group's statistic is <= leave (no motion
    on it); it holds a still interval (its start trimmed by the settling: the samples from the
    last s > leave), or a still run shorter than min_still (too short), or none: a group never got
    below enter (still settling) or never below leave (moving), and vetoed the pose."""
    enter, leave, min_still = limits
    calm = _runs(s <= leave)
    settling = np.array([a - calm[np.searchsorted(calm[:, 0], a, side="right") - 1, 0]
                         for a, _ in intervals], dtype=np.int64)
    stats = {name: ratio[:, cols].mean(axis=1) for name, cols in groups.items()}
    some = _runs(np.min(list(stats.values()), axis=0) <= leave)
    rejected = []
    for a, b in some[some[:, 1] - some[:, 0] >= w]:
        if np.any((intervals[:, 0] < b) & (intervals[:, 1] > a)):
            continue
        brief = short[(short[:, 0] < b) & (short[:, 1] > a)]
        if len(brief):
            longest = int((brief[:, 1] - brief[:, 0]).max())
            reason = (f"too short: still {longest / fs:.2f} s (after {(brief[0, 0] - a) / fs:.2f} "
                      f"s settling), less than min_still {min_still:g} s")
        else:
            lowest = {name: float(stat[a:b].min()) for name, stat in stats.items()}
            reason = "; ".join(
                f"{'moving' if low > leave else 'settling not finished'}: {name} at least "
                f"{low:.1f} x the noise (threshold {enter:g})"
                for name, low in lowest.items() if low >= enter)
        rejected.append((int(a), int(b), reason))
    return settling, tuple(rejected)


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


def _rest_window(mv: np.ndarray, rest, w: int) -> np.ndarray:
    """The given rest period [start, stop) of sample indices, checked."""
    k = mv.shape[0]
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
            f"the still detector's window of {window} s is {w} samples at {fs:g} Hz, for a "
            f"recording of {k} samples; it needs 3 samples or more, within the recording.",
            "Record (or import) the sensor at a higher rate: a flight log's fastest IMU data "
            "(`station import ulog --topic sensor_combined`; the import's notes list the "
            "topics' rates), or a longer recording." if w < 3 else
            "Record a longer recording (several still poses of a few seconds each).",
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


STILL_CHANNELS = ("acc", "acc+gyro")
"""What `StillOptions.channels` may say: the accelerometers decide, or the gyros can veto too."""


@dataclass(frozen=True)
class StillOptions:
    """The detector settings a user gives (`--rest`, `--threshold`, `--still-channels`,
    `--min-still` of solve, replay and diagnose); None: the default.

    rest      : (start, end) seconds from the recording's first sample, a declared rest period
    threshold : enter threshold in multiples of the noise variance; leave = 2 x threshold
    channels  : "acc" (the accelerometers decide) or "acc+gyro" (the gyros can veto: each group's
                statistic must be low); None: the caller's default
    min_still : shortest still interval kept, seconds
    """

    rest: tuple | None = None
    threshold: float | None = None
    channels: str | None = None
    min_still: float | None = None

    def __post_init__(self):
        if self.rest is not None:
            rest = tuple(float(t) for t in self.rest)
            if len(rest) != 2 or not all(np.isfinite(rest)) or not 0 <= rest[0] < rest[1]:
                raise CalibrationInputError(f"rest period {self.rest!r} is not START:END seconds.",
                                            "Give e.g. --rest 0:50 (seconds from the first "
                                            "sample, START < END).")
            object.__setattr__(self, "rest", rest)
        if self.threshold is not None and not (np.isfinite(self.threshold) and self.threshold > 1):
            raise CalibrationInputError(f"threshold {self.threshold!r} is not above 1.",
                                        "It is a multiple of the noise variance (1 = at rest): "
                                        "e.g. --threshold 4 (leave = 2 x threshold).")
        if self.channels is not None and self.channels not in STILL_CHANNELS:
            raise CalibrationInputError(f"still channels {self.channels!r} are unknown.",
                                        f"Choose one of {', '.join(STILL_CHANNELS)}.")
        if self.min_still is not None and not (np.isfinite(self.min_still) and self.min_still > 0):
            raise CalibrationInputError(f"min_still {self.min_still!r} is not a duration.",
                                        "Give the shortest still pose in seconds, e.g. 1.5.")

    def detector(self, fs: float, acc, gyro=(), default: str | None = None) -> dict:
        """`detect_still` options for samples at fs Hz whose columns `acc` are accelerometers and
        `gyro` gyros; channels None: `default` (None: every column decides, one group)."""
        options = {}
        if self.rest is not None:
            options["rest"] = (round(self.rest[0] * fs), round(self.rest[1] * fs))
        if self.threshold is not None:
            options.update(enter=self.threshold, leave=2 * self.threshold)
        if self.min_still is not None:
            options["min_still"] = self.min_still
        channels = self.channels or default
        if channels is not None:
            if len(acc) == 0:
                raise CalibrationInputError("the stream has no accelerometer channel (m/s^2) to "
                                            "detect still poses on.",
                                            "Import the accelerometer with a unit in m/s^2.")
            options["groups"] = {"acc": list(acc)}
        if channels == "acc+gyro":
            if len(gyro) == 0:
                raise CalibrationInputError("--still-channels acc+gyro, but the recording has no "
                                            "gyro channels (rad/s).",
                                            "Use --still-channels acc, or import the gyro too.")
            options["groups"]["gyro"] = list(gyro)
        return options
