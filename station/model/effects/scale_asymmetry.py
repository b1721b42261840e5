"""Effect `scale_asymmetry`: a sensor's scale differs for positive and negative signals.

Parameters
----------
k : scalar or (m,), dimensionless
    Sensor i outputs s_i + k_i |s_i| where s_i = a_i . v is its linear response: the scale is
    |a_i| (1 + k_i) for positive signals and |a_i| (1 - k_i) for negative ones (a datasheet's
    "scale-factor asymmetry" is 2 k_i).

Signature: the averaged reading of a position moves by k_i |a_i . v_j|; the static window (v = 0
for a gyro at rest) does not move. With one rate magnitude for every position it is nearly
scale_nonlinearity's (k2_i (a_i . v_j)^2: both even in the signal; for signals spread evenly over
+-1 the two correlate by 0.97), which a second table rate tells apart (|s| doubles with the rate,
s^2 quadruples).
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ScaleAsymmetry:
    """Scale-factor asymmetry k per sensor."""

    k: float | tuple = 0.0


def apply(s: np.ndarray, p: ScaleAsymmetry) -> np.ndarray:
    """Sensed signals s (..., m) with the asymmetry added: s + k |s|, made in one new array."""
    out = np.abs(s)
    out *= np.asarray(p.k, float)
    out += s
    return out
