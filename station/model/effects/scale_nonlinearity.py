"""Effect `scale_nonlinearity`: a quadratic term per sensor.

Parameters
----------
k2 : scalar or (m,), 1 / (SI unit of the stimulus)
    Sensor i outputs s_i + k2_i s_i^2 where s_i = a_i . v is its linear response.

Signature: the averaged reading of a position moves by k2_i (a_i . v_j)^2; the static window
(v = 0 for a gyro at rest) does not move.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ScaleNonlinearity:
    """Quadratic scale-factor term k2 per sensor."""

    k2: float | tuple = 0.0


def apply(s: np.ndarray, p: ScaleNonlinearity) -> np.ndarray:
    """Sensed signals s (..., m) with the quadratic term added: s + k2 s^2, made in one new
    array (the diagnosis' twin is of the session's size)."""
    out = np.square(s)
    out *= np.asarray(p.k2, float)
    out += s
    return out
