"""Statistical process control: a Shewhart X chart and the Western Electric / Nelson run rules.

The chart's centre and sigma come from a baseline period (the first `baseline` points: the
process when it was known good); each later point is z = (x - centre) / sigma. The run rules,
each named for what it catches:

    beyond_3_sigma   1 point beyond 3 sigma                    (a shift or an outlier)
    2_of_3_beyond_2  2 of 3 points in a row beyond 2 sigma, same side   (a shift starting)
    8_on_one_side    8 points in a row on one side of the centre        (a sustained shift)
    6_trending       6 points in a row, each above (or below) the last  (a drift)

A rule fires at the point that completes its pattern. Under a stable normal process the false
alarm rate per point is about 0.27 % (rule 1), 0.2 % (rule 2), 0.78 % (rule 3) and 0.28 % (rule
4).
"""

from dataclasses import dataclass

import numpy as np

RULES = ("beyond_3_sigma", "2_of_3_beyond_2", "8_on_one_side", "6_trending")
BASELINE = 20
"""Points of the baseline period by default (fewer than this: no chart): 20-25 is the usual
Shewhart baseline; its sigma is then known to about 16 %."""


@dataclass(frozen=True)
class Chart:
    """An X chart: centre and sigma of the baseline, the points' z, and the rule violations
    [(point index, rule), ...] in order of the points (the baseline's points are judged too)."""

    centre: float
    sigma: float
    baseline: int
    z: np.ndarray
    violations: tuple

    @property
    def first(self) -> int | None:
        """Index of the first point a rule flags, None if none does."""
        return self.violations[0][0] if self.violations else None


def chart(x, baseline: int = BASELINE) -> Chart | None:
    """The X chart of the series `x` (in time order) with the first `baseline` points as its
    baseline; None when there are not more points than that, or the baseline does not vary."""
    x = np.asarray(x, dtype=float)
    if baseline < 2 or len(x) <= baseline:
        return None
    centre, sigma = float(np.mean(x[:baseline])), float(np.std(x[:baseline], ddof=1))
    if not sigma > 0:
        return None
    z = (x - centre) / sigma
    return Chart(centre, sigma, baseline, z, run_rules(z))


def run_rules(z) -> tuple:
    """Every (index, rule) where a run rule fires on the standardised series `z`, by index
    (several rules at one point: in the order of RULES)."""
    z = np.asarray(z, dtype=float)
    points, rules = np.nonzero(np.stack([_fires(z, rule) for rule in RULES], axis=1))
    return tuple(zip(points.tolist(), [RULES[k] for k in rules.tolist()], strict=True))


def _fires(z: np.ndarray, rule: str) -> np.ndarray:
    """Boolean (n,): where `rule` completes its pattern."""
    if rule == "beyond_3_sigma":
        return np.abs(z) > 3
    if rule == "2_of_3_beyond_2":
        high, low = z > 2, z < -2
        return (high & (_window_count(high, 3) >= 2)) | (low & (_window_count(low, 3) >= 2))
    if rule == "8_on_one_side":
        return (_window_count(z > 0, 8) == 8) | (_window_count(z < 0, 8) == 8)
    step = np.diff(z, prepend=np.nan)
    return (_window_count(step > 0, 5) == 5) | (_window_count(step < 0, 5) == 5)


def _window_count(flags: np.ndarray, k: int) -> np.ndarray:
    """(n,): how many of the last k flags (this one included) are set; 0 before k points."""
    total = np.cumsum(np.concatenate(([0], flags.astype(np.int64))))
    count = np.zeros(len(flags), dtype=np.int64)
    count[k - 1:] = total[k:] - total[:-k]
    return count
