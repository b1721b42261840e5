"""Spikes: readings far outside their noise's Gaussian law (a flipped bit, a corrupted frame, a
glitching sensor), told from the noise by a robust scale that they cannot inflate.

`beyond(dev, floor)`: deviations dev (K, c) from a reference the spikes do not move (a window's
median, the median of a sample's neighbours) beyond `SPIKE` robust standard deviations (1.4826
times the median absolute deviation, per channel, at least `floor`: the quantisation step, which
a channel quieter than its step shows as scatter 0). Gaussian noise puts one sample in about
8e14 there (`NULL_CHANCE`); a glitch puts many.
"""

import math

import numpy as np

SPIKE = 8.0
"""Robust standard deviations beyond which a reading is a spike."""
NULL_CHANCE = math.erfc(SPIKE / math.sqrt(2.0))
"""Chance that a Gaussian deviation lies beyond SPIKE standard deviations (1.2e-15)."""


def column_medians(x: np.ndarray) -> np.ndarray:
    """(c,) the median of each column of x (K, c), K >= 1, as `np.median(x, axis=0)` gives it
    (float; NaN for a column holding a NaN): one partition of the columns laid out as rows, about
    twice as fast on a replay's windows, which make thousands of calls."""
    rows = np.array(np.asarray(x).T, dtype=float)  # (c, K), contiguous: partitioned in place
    k = rows.shape[1]
    half = k // 2
    rows.partition([half - 1, half] if k % 2 == 0 else half, axis=1)
    mid = rows[:, half] if k % 2 else (rows[:, half - 1] + rows[:, half]) / 2
    return np.where(np.isnan(rows).any(axis=1), np.nan, mid)


def robust_sigma(dev: np.ndarray) -> np.ndarray:
    """(c,) 1.4826 x the median absolute deviation of dev (K, c) (centred by the caller): the
    standard deviation of Gaussian noise, whatever a few spikes add."""
    return 1.4826 * column_medians(np.abs(dev))


def beyond(dev: np.ndarray, floor=0.0) -> np.ndarray:
    """(K, c) whether each deviation lies beyond SPIKE x max(robust_sigma, floor)."""
    return np.abs(dev) > SPIKE * np.maximum(robust_sigma(dev), floor)
