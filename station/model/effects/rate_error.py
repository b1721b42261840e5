"""Effect `rate_error`: the table's true rate differs from the commanded rate.

Parameters
----------
scale : float
    Overall relative error of the table's rate: true = commanded * (1 + scale + delta_j).
spread : float
    Standard deviation of the per-position (per run) relative error delta_j.
encoder : bool
    What the table's angle (and rate) registers report. False (default): the command, so nothing
    but the IMU's readings shows the error (a controller that echoes its set point). True: an
    encoder on the shaft reads the true motion, so the recorded angle shows each position's rate
    (`encoder=1` on the command line).

The distortion multiplies the angular-rate truth by the factor of each position, so |v_j| changes
while its direction does not.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RateError:
    """Relative error of the table's true rate: overall `scale` and per-position `spread` (sd)."""

    scale: float = 0.0
    spread: float = 0.0
    encoder: bool = False

    def __post_init__(self):
        object.__setattr__(self, "encoder", bool(self.encoder))

    def factors(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n,) true/commanded rate ratios 1 + scale + delta_j, delta_j ~ N(0, spread^2)."""
        delta = self.spread * rng.standard_normal(n) if self.spread else np.zeros(n)
        return 1.0 + self.scale + delta


def apply(omega: np.ndarray, factors: np.ndarray) -> np.ndarray:
    """Angular-rate truth (n, k, d) with position j's rate scaled by factors[j]."""
    return omega * np.asarray(factors, float)[:, None, None]
