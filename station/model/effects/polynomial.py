"""Effect `polynomial`: a sensor's output bends with its signal by a polynomial of any order.

Parameters
----------
c2, c3, c4, c5 : scalar or (m,), (SI unit of the stimulus)^(1 - q)
    Sensor i outputs s_i + sum_q c_q,i s_i^q (q = 2 .. 5) where s_i = a_i . v is its linear
    response: scale_nonlinearity's quadratic term (c2 = k2) and the higher orders a datasheet's
    "nonlinearity" (a best-fit straight line's residual over the range) also holds.

Signature: the averaged reading of a position moves by sum_q c_q,i (a_i . v_j)^q; the static
window (v = 0 for a gyro at rest) does not move. The odd orders are partly a scale factor (the
calibration takes that part); the even ones partly scale_asymmetry's |s|.
"""

from dataclasses import dataclass

import numpy as np

ORDERS = (2, 3, 4, 5)
"""The powers of the signal, in the order of the parameters."""


@dataclass(frozen=True)
class Polynomial:
    """Coefficients of the powers 2 .. 5 of the signal, per sensor."""

    c2: float | tuple = 0.0
    c3: float | tuple = 0.0
    c4: float | tuple = 0.0
    c5: float | tuple = 0.0


def apply(s: np.ndarray, p: Polynomial) -> np.ndarray:
    """Sensed signals s (..., m) with the polynomial added: s + sum_q c_q s^q (Horner's scheme,
    in one new array besides a working one)."""
    out = np.zeros_like(s)
    for q in reversed(ORDERS):
        out += np.asarray(getattr(p, f"c{q}"), float)
        out *= s
    out *= s  # the lowest power is 2
    out += s
    return out
