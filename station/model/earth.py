"""Gravity and the Earth's rotation at a latitude, in the local East-North-Up (ENU) frame.

The rotary table's axis is the local up axis. A positive table rotation is counter-clockwise seen
from above (right-handed about up), so a table x axis at heading h0 (rad east of north) points at
heading h0 - angle after the table has turned by `angle`.
"""

import numpy as np

OMEGA_EARTH = 7.2921150e-5
"""Earth's sidereal rotation rate, rad/s (WGS84)."""


def normal_gravity(latitude_deg: float) -> float:
    """Magnitude of gravity on the WGS84 ellipsoid at a latitude (Somigliana's formula), m/s^2."""
    s2 = np.sin(np.radians(latitude_deg)) ** 2
    return float(9.7803253359 * (1 + 0.00193185265241 * s2) / np.sqrt(1 - 0.00669437999013 * s2))


def earth_rate_enu(latitude_deg: float, rate: float = OMEGA_EARTH) -> np.ndarray:
    """Earth rotation vector in ENU: (0, rate cos(lat), rate sin(lat)), rad/s."""
    lat = np.radians(latitude_deg)
    return np.array([0.0, rate * np.cos(lat), rate * np.sin(lat)])


def earth_rate_table(latitude_deg: float, heading: np.ndarray, rate: float = OMEGA_EARTH):
    """Earth rotation in the table frame when the table's x axis points `heading` rad east of north.

    In ENU, x_table = (sin h, cos h, 0), y_table = up x x_table = (-cos h, sin h, 0), z_table = up,
    so the Earth rate in the table frame is (N cos h, N sin h, U) with N, U its north and up parts.
    Returns an array of shape heading.shape + (3,).
    """
    h = np.asarray(heading, float)
    north, up = rate * np.cos(np.radians(latitude_deg)), rate * np.sin(np.radians(latitude_deg))
    out = np.empty(h.shape + (3,))
    out[..., 0] = north * np.cos(h)
    out[..., 1] = north * np.sin(h)
    out[..., 2] = up
    return out
