"""Effect `earth_rate`: the Earth's rotation adds to the table's rate.

Parameters
----------
latitude_deg : float
    Latitude of the bench, degrees.
heading_deg : float
    Heading of the table's x axis at the start of the session, degrees east of north.
rate : float, rad/s
    Magnitude of the Earth rate (default the sidereal rate; larger values make tests visible).

The unit on the table at angle theta sees C_j (N cos h, N sin h, U) with h = heading - theta
(earth.earth_rate_table). Over whole revolutions the horizontal part averages out and only the
vertical part U u_j survives, while the static window sees the full projection at the static
heading: the difference leaks into m_j. The table rate vector itself (|v_j|) is unchanged.
"""

from dataclasses import dataclass

import numpy as np

from station.model.earth import OMEGA_EARTH, earth_rate_table


@dataclass(frozen=True)
class EarthRate:
    """Earth rotation at a latitude and heading; see the module docstring."""

    latitude_deg: float = 52.2
    heading_deg: float = 0.0
    rate: float = OMEGA_EARTH


def apply(
    omega: np.ndarray, orientation: np.ndarray, angle: np.ndarray, p: EarthRate
) -> np.ndarray:
    """Angular rate (n, k, d) in the unit frame plus the Earth rate.

    orientation (n, 3, 3) maps table-frame vectors to the unit frame per position; angle (n, k) is
    the table's cumulative true angle over the session (rad).
    """
    heading = np.radians(p.heading_deg) - angle
    e_table = earth_rate_table(p.latitude_deg, heading, p.rate)
    return omega + np.einsum("nij,nkj->nki", orientation, e_table)
