"""Outliers: a spiky, heavy-tailed noise law in a stream of samples (issue 32): detected, their
rate reported, and down-weighted (replaced) before anything else reads the samples.

Each sample is compared with the mean of two medians: of the `NEIGHBOURS` samples before it and
of the `NEIGHBOURS` after it. It is not part of either, so under Gaussian noise the deviation is
its own noise less an independent smooth estimate (close to Gaussian); a steady signal or a
smooth motion (a ramp, a turn) moves both sides alike, and a single spike moves neither median.
Deviations beyond `station.reduce.spikes.SPIKE` robust standard deviations (at least the
quantisation step) are outliers.

Under Gaussian noise the count of outliers in a channel of K samples is Binomial(K, NULL_CHANCE),
about Poisson(K NULL_CHANCE); the p-value of the count seen is its Poisson tail, and outliers are
`detected` when a channel's p-value is below alpha / channels (Bonferroni, as the gap statistics).
Each outlier is replaced by its neighbours' estimate, so that it weighs nothing in the stillness
decision, the noise sigma, the window means or the rails.
"""

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.stats import poisson

from station.reduce.spikes import NULL_CHANCE, SPIKE, beyond

NEIGHBOURS = 3
"""Samples on each side whose median is a sample's reference (a median of 3 ignores one spike)."""


def reference(x: np.ndarray) -> np.ndarray:
    """(K, c) the mean of the medians of the NEIGHBOURS samples before and after each sample of
    x (K, c) (the edges repeat the first and last sample)."""
    n = NEIGHBOURS
    padded = np.pad(x, ((n, n), (0, 0)), mode="edge")
    w = sliding_window_view(padded, 2 * n + 1, axis=0)  # (K, c, 2n + 1)
    return 0.5 * (np.median(w[..., :n], axis=-1) + np.median(w[..., n + 1:], axis=-1))


@dataclass(frozen=True)
class Cleaned:
    """Samples x (K, c) with their outliers (`flags`, (K, c)) replaced by the reference."""

    x: np.ndarray
    flags: np.ndarray


def clean(x: np.ndarray, step) -> Cleaned:
    """The outliers of x (K, c) (floor of the robust scale: `step`, (c,)) replaced."""
    ref = reference(x)
    flags = beyond(x - ref, step)
    return Cleaned(np.where(flags, ref, x), flags)


def test(flags: np.ndarray, alpha: float) -> dict:
    """The count of outliers per channel in flags (K, c) against its Gaussian-noise law
    (`counted`)."""
    return counted(flags.sum(axis=0), flags.shape[0], alpha)


def counted(count: np.ndarray, k: int, alpha: float) -> dict:
    """The counts of outliers per channel (c,) among k samples each against their Gaussian-noise
    law: counts, samples, rate (count / samples), expected count, log10 p of each count (Poisson
    tail: that many or more), the Bonferroni threshold log10(alpha / c) and whether outliers are
    detected."""
    c = len(count)
    expected = k * NULL_CHANCE
    log10_p = np.logaddexp(poisson.logpmf(count, expected),  # P(N = count) + P(N > count)
                           poisson.logsf(count, expected)) / np.log(10)
    threshold = float(np.log10(alpha / c))
    return {"count": count, "samples": k, "rate": count / k, "expected": expected,
            "log10_p": log10_p, "threshold_log10_p": threshold,
            "detected": bool(np.any(log10_p < threshold)), "beyond_sigma": SPIKE}


def message(report: dict, names, replaced_by: str = "its neighbours' median") -> str:
    """One line on the outliers of `test`'s report, channels called `names`, each outlier
    `replaced_by` that."""
    if not report["detected"]:
        return (f"no outliers: {int(report['count'].sum())} sample(s) beyond "
                f"{report['beyond_sigma']:g} robust sigma, as Gaussian noise allows")
    hit = [f"{n} {int(k)} ({r:.2%})" for n, k, r in
           zip(names, report["count"], report["rate"], strict=True) if k]
    return (f"OUTLIERS: samples beyond {report['beyond_sigma']:g} robust sigma (Gaussian noise: "
            f"{report['expected']:.1e} expected per channel) in {', '.join(hit)} of "
            f"{report['samples']} samples (log10 p {report['log10_p'].min():.1f}); "
            f"down-weighted: each replaced by {replaced_by}")
