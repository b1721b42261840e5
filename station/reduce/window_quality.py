"""How well a window was captured, for the confirmation a technician reads as each position or pose
is captured (`station.protocols`): samples found against samples due, the noise of the window
against a reference noise, and a warning when either is out of line.

No threshold is new here:
- the sample count and the samples themselves go through the offline reduction's own checks
  (`station.reduce.rotary.check_window_count`: a lossy link or overlapping times;
  `check_samples`: spikes, a stuck channel), so the warning says live what a replay would refuse;
- the noise is compared as the stillness detector compares it (`station.reduce.stillness`): the
  mean over the channels of var(window) / var(reference), about 1 for a still unit, and out of
  line above the detector's `enter` threshold, where a stretch stops counting as still.
"""

from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError
from station.reduce.rotary import check_samples, check_window_count


@dataclass(frozen=True)
class WindowQuality:
    """One captured window.

    seconds : its length (clock s); found, due : samples in it and samples its length holds
    noise   : (c,) sample standard deviation of each channel (SI)
    ratio   : mean over the channels of noise^2 / reference^2, None without a reference
    limit   : the ratio above which the window is not still (the detector's `enter`)
    problem : why the offline reduction would refuse the window, None if it would not
    """

    seconds: float
    found: int
    due: float
    noise: np.ndarray
    ratio: float | None
    limit: float | None
    problem: str | None

    @property
    def rms_noise(self) -> float:
        """The channels' noise as one figure: sqrt(mean over channels of noise^2)."""
        return float(np.sqrt(np.mean(self.noise**2))) if self.noise.size else float("nan")

    @property
    def noisy(self) -> bool:
        return self.ratio is not None and self.ratio > self.limit

    @property
    def ok(self) -> bool:
        return self.problem is None and not self.noisy


def window_quality(t, z, window, rate_hz: float, lsb, reference=None, limit: float = 4.0,
                   name: str = "still", position: int = 0) -> WindowQuality:
    """The quality of the samples (times `t` (K,) clock s, readings `z` (K, c) SI) whose times lie
    in `window` = (t0, t1), sampled at `rate_hz` with `lsb` SI units per count (scalar or (c,));
    `reference` (c,): the noise standard deviation a still window should have; `limit`: the
    largest accepted variance ratio (the stillness detector's `enter`)."""
    t0, t1 = window
    x = np.asarray(z, float)[(t >= t0) & (t <= t1)]
    due = (t1 - t0) * rate_hz
    noise = x.std(axis=0, ddof=1) if len(x) > 1 else np.full(x.shape[1], np.nan)
    ratio = None
    if reference is not None and len(x) > 1:
        ratio = float(np.mean(noise**2 / np.asarray(reference, float) ** 2))
    try:
        check_window_count(position, name, len(x), due)
        check_samples(position, name, np.round(x / lsb))
        problem = None
    except CalibrationInputError as exc:
        problem = exc.problem.removeprefix(f"position {position + 1}: ")
    return WindowQuality(float(t1 - t0), len(x), due, noise, ratio, limit, problem)


def describe(q: WindowQuality, unit: str, against: str = "the reference") -> str:
    """`q` in words: "4.9 s, 980/980 samples, noise 0.011 m/s^2 (1.1x the rest noise, as
    expected)", with a WARNING when out of line."""
    words = f"{q.seconds:.1f} s, {q.found}/{q.due:.0f} samples, noise {q.rms_noise:.3g} {unit}"
    if q.ratio is not None:
        scale = np.sqrt(q.ratio)
        words += (f" (WARNING: {scale:.1f}x {against}, not still: more than "
                  f"{np.sqrt(q.limit):.0f}x)" if q.noisy else
                  f" ({scale:.1f}x {against}, as expected)")
    if q.problem is not None:
        words += f"; WARNING: {q.problem}"
    return words
