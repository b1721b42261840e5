"""Geometry of a two-axis rotary table (docs/conventions.md "Two-axis table").

The unit is mounted on the inner POSITION axis (angle phi, set and held by the table), which the
outer RATE axis carries; the position axis makes the angle `alpha` with the rate axis. Frames:

  unit frame U --R_mount--> inner frame P (z = the position axis) --Rz(phi)--> outer frame O

with the rate axis e_rate = (sin alpha, 0, cos alpha) in O at phi = 0. A rotation of the rate axis
at rate w is, in the unit frame, w * R_mount^T Rz(phi)^T e_rate: over phi these directions sweep
a cone of half-angle alpha about c = R_mount^T e_z, the position axis in the unit frame.

A single cone does NOT determine g of Rupniewski's Eq. (7): every v on it satisfies
v^T (c c^T - cos^2 alpha I) v = 0, one linear relation between the six entries of v v^T
(`station.solve.identifiability.check_design` refuses such positions). Spinning the POSITION axis
instead (the rate axis at rest) turns the unit about c itself, off the cone (c^T Q c = sin^2 alpha),
which restores the missing direction: a two-axis session has positions on the cone and at least
one about c (`position_axes`).

The bench geometry: alpha = arccos(1/sqrt 3) = 54.74 deg (the unit on a 54.74 deg wedge) and a
mounting that puts c along the unit's body diagonal (1, 1, 1)/sqrt 3, so the cone passes through
the unit's x, y and z axes.
"""

import numpy as np

from station.errors import InputError

ALPHA = float(np.arccos(1 / np.sqrt(3)))
"""Angle between the position and rate axes of the bench (rad): 54.74 deg."""


def rz(phi: float) -> np.ndarray:
    """Rotation by `phi` rad about z."""
    c, s = np.cos(phi), np.sin(phi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def diagonal_mount() -> np.ndarray:
    """R_mount (unit -> inner frame) that puts the position axis along the unit's body diagonal
    (1, 1, 1)/sqrt 3 (R_mount^T e_z), the inner x axis along the unit's x made perpendicular to
    it."""
    c = np.ones(3) / np.sqrt(3)
    x = np.array([1.0, 0.0, 0.0]) - c / np.sqrt(3)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(c, x), c]).T


def rate_axis(phi, alpha: float = ALPHA, mount: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) unit-frame directions of the rate axis at position angles `phi` (rad):
    R_mount^T Rz(phi)^T e_rate."""
    mount = diagonal_mount() if mount is None else np.asarray(mount, float)
    e_rate = np.array([np.sin(alpha), 0.0, np.cos(alpha)])
    return np.array([mount.T @ rz(p).T @ e_rate for p in np.atleast_1d(phi)])


def position_axis(mount: np.ndarray | None = None) -> np.ndarray:
    """(3,) unit-frame direction of the position axis (the cone's axis c)."""
    mount = diagonal_mount() if mount is None else np.asarray(mount, float)
    return mount.T @ np.array([0.0, 0.0, 1.0])


def position_angles(n: int) -> np.ndarray:
    """`n` position angles (rad) spread evenly over a turn, 0 first."""
    if n < 1:
        raise InputError(f"number of cone positions must be positive, got {n}")
    return 2 * np.pi * np.arange(n) / n


def position_axes(n: int, spins: int = 1, alpha: float = ALPHA,
                  mount: np.ndarray | None = None) -> np.ndarray:
    """(n + spins, 3) unit-frame spin axes of a two-axis session: the rate axis at `n` evenly
    spread position angles, then `spins` spins of the position axis itself (alternating sign),
    without which the positions lie on one cone and g of Eq. (7) is not determined."""
    if spins < 1:
        raise InputError("a two-axis session needs at least one spin of the position axis: "
                         "positions on the rate axis alone lie on one cone (docs/conventions.md)")
    return spin_axes(position_angles(n), spins, alpha, mount)


def spin_signs(spins: int) -> np.ndarray:
    """(spins,) the sign of each spin of the position axis: +1, -1, +1, ... (alternating, so
    that the spins' own errors of sign, e.g. a direction-dependent rate error, show)."""
    return np.where(np.arange(spins) % 2 == 0, 1.0, -1.0)


def spin_axes(phis, spins: int, alpha: float = ALPHA,
              mount: np.ndarray | None = None) -> np.ndarray:
    """(len(phis) + spins, 3) unit-frame spin axes: the rate axis at the position angles `phis`
    (rad), then `spins` spins of the position axis (`spin_signs` times c)."""
    c = position_axis(mount)
    return np.vstack([rate_axis(phis, alpha, mount).reshape(-1, 3),
                      spin_signs(spins)[:, None] * c])


def orientation(phi: float, alpha: float = ALPHA, mount: np.ndarray | None = None) -> np.ndarray:
    """(3, 3) table frame (z = the rate axis) -> unit frame at position angle `phi`, as
    `station.sim.live.MountedUnit.orientation` takes it: R_mount^T Rz(phi)^T Ry(alpha)."""
    mount = diagonal_mount() if mount is None else np.asarray(mount, float)
    c, s = np.cos(alpha), np.sin(alpha)
    tilt = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # e_z -> e_rate
    return mount.T @ rz(phi).T @ tilt
