"""Effect `g_sensitivity`: the gyro bias grows linearly with the specific force (IEEE Std 528's
g-sensitive bias; imucal's K_ga).

Parameters
----------
matrix : 9 values, row-major 3 x 3 G, rad/s per m/s^2
    The angular rate error G f added to the true angular rate, f the specific force in the unit
    frame (at rest: gravity, g up).

Rotary protocol: f = g C_j e_z (the table axis is up), constant over a position, so every
window of the position moves by a^T G f_j and M (rotating minus static means) is unchanged.
Free-static protocol (station.sim.static.static_gyro): f_j = the specific force of pose j.
Gravity: normal gravity at the session's latitude (the earth_rate effect's, else 52.2 deg).
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GSensitivity:
    """g-sensitivity matrix G (row-major, rad/s per m/s^2); see the module docstring."""

    matrix: tuple = (0.0,) * 9

    def __post_init__(self):
        if np.size(self.matrix) != 9:
            raise ValueError(
                f"g_sensitivity matrix has {np.size(self.matrix)} values; give 9 (row-major "
                "3 x 3, rad/s per m/s^2), colon-separated"
            )

    @property
    def g(self) -> np.ndarray:
        return np.reshape(np.asarray(self.matrix, float), (3, 3))


def apply(omega: np.ndarray, f: np.ndarray, p: GSensitivity) -> np.ndarray:
    """Angular rate (..., 3) plus G f for the specific force f (..., 3) in the unit frame."""
    return omega + np.asarray(f, float) @ p.g.T
