"""Effect `axis_wobble`: the table axis cones, so the rate vector is not fixed in the unit frame.

Parameters
----------
angle_deg : float
    Half-angle beta of the cone, degrees.
freq : float or None, Hz
    Coning frequency; None ties the coning to the table angle (once per revolution).
phase_deg : float
    Phase of the coning, degrees.

Kinematic model: omega = rate (cos beta u + sin beta (cos phi p + sin phi q)) with u the table
axis and p, q the table's x, y axes in the unit frame, phi = table angle + phase (or
2 pi freq t + phase). |omega| = |rate|; over whole coning periods the mean is rate cos beta u,
a second-order change; each sensor shows a tone at the coning frequency of amplitude
rate sin beta |(a_i . p, a_i . q)|.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class AxisWobble:
    """Coning of the table axis; see the module docstring."""

    angle_deg: float = 0.0
    freq: float | None = None
    phase_deg: float = 0.0


def apply(
    rate: np.ndarray, angle: np.ndarray, t: np.ndarray, orientation: np.ndarray, p: AxisWobble
) -> np.ndarray:
    """Angular rate (n, k, 3) in the unit frame for the table rate and angle (n, k), times t (k,).

    orientation (n, 3, 3) maps table-frame vectors to the unit frame (columns p, q, u).
    """
    beta = np.radians(p.angle_deg)
    phase = np.radians(p.phase_deg)
    phi = (
        angle if p.freq is None else 2 * np.pi * p.freq * np.broadcast_to(t, angle.shape)
    ) + phase
    coef = (
        np.stack(
            [
                np.sin(beta) * np.cos(phi),
                np.sin(beta) * np.sin(phi),
                np.full_like(phi, np.cos(beta)),
            ],
            axis=-1,
        )
        * rate[..., None]
    )
    return np.einsum("nij,nkj->nki", orientation, coef)
