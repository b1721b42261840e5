"""Effect `outliers`: sparse single-sample spikes, as a glitching sensor or a corrupted frame
gives them (a heavy-tailed noise law).

Parameters
----------
rate : chance that a sample of a channel is a spike (independent per sample and channel)
size : scalar or (m,), SI output units: the spike added, with a random sign

Signature: a few samples far out of the noise's Gaussian law (tens of sigma for sizes tens of
times the noise); means move by about rate x size x (the signs' imbalance), the sample scatter
by rate x size^2.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Outliers:
    """Spikes of `size` (either sign) on a fraction `rate` of the samples."""

    rate: float = 0.0
    size: float | tuple = 0.0


def apply(z: np.ndarray, p: Outliers, rng: np.random.Generator) -> np.ndarray:
    """Outputs z (..., m) with spikes added (draws from `rng`)."""
    hit = rng.random(z.shape) < p.rate
    sign = np.where(rng.random(z.shape) < 0.5, -1.0, 1.0)
    return z + hit * sign * np.asarray(p.size, float)
