"""A sensor unit mounted on the live rotary table: the sample source of the serial/CAN twins."""

import itertools

import numpy as np

from station.model import sensing
from station.model.unit import SensorUnit
from station.sim.table import TablePhysics


class MountedUnit:
    """`times -> counts (k, m)` for `unit` on `table`, for `drivers.twins.can`/serial twins.

    `orientation` (3 x 3, table frame -> unit frame) is what the technician changes between
    positions; each sample has the orientation set last at or before its own time and the table's
    true rate along the table axis at that time (`TablePhysics.true_rates`), so a twin that falls
    behind (a backlog sent after the station reopened the port) still sends the right motion.
    `effects` {name: parameters}: named sensor effects (station.model.sensing.LIVE_EFFECTS) in
    the unit's output chain. `inner` (source, axis): a second axis the unit turns about, fixed in
    the unit frame (a two-axis table's position axis in rate mode: `source.true_rates(times)`
    rad/s about the unit-frame direction `axis`, `station.sim.table.PositionAxis`); the unit feels
    the sum of both angular rates (the rate axis' along the orientation's third column).
    """

    def __init__(self, unit: SensorUnit, table: TablePhysics, orientation=None, effects=None,
                 inner=None):
        self.unit = unit
        self.table = table
        self.inner = inner
        initial = np.eye(3) if orientation is None else np.asarray(orientation, float)
        self._mounts = [(-np.inf, initial)]  # (clock time set, orientation), in time order
        self.effects = dict(effects or {})
        sensing.refuse_batch_effects(self.effects)

    @property
    def orientation(self) -> np.ndarray:
        """The orientation now."""
        return self._mounts[-1][1]

    @orientation.setter
    def orientation(self, value) -> None:
        self.mount(value, self.table.clock.now())

    def mount(self, orientation, at: float) -> None:
        """Take `orientation` from clock time `at` on (now or later: a two-axis table's position
        axis arriving at its setpoint), never before the mounting set last takes effect."""
        at = max(float(at), self._mounts[-1][0])
        self._mounts.append((at, np.asarray(orientation, float)))

    def placement(self, times) -> np.ndarray:
        """(k,) the placement each of `times` (clock s) has: 0 the initial orientation, one more
        at each `mount` that changes it (a mounting that keeps the orientation, e.g. a fixture
        asked again for the position it holds, or a two-axis table's position axis held where it
        is, is the same placement)."""
        changed = [0] + [int(not np.allclose(a, b, atol=1e-12))
                         for (_, a), (_, b) in itertools.pairwise(self._mounts)]
        return np.cumsum(changed)[self._which(np.atleast_1d(np.asarray(times, float)))]

    def orientation_at(self, time: float) -> np.ndarray:
        """The orientation the samples at clock time `time` have."""
        return self._mounts[self._which(np.atleast_1d(float(time)))[0]][1]

    def _which(self, times: np.ndarray) -> np.ndarray:
        """Index in the mountings of each of `times`."""
        return np.searchsorted([t for t, _ in self._mounts], times, side="right") - 1

    def __call__(self, times) -> np.ndarray:
        times = np.atleast_1d(np.asarray(times, float))
        which = self._which(times)
        axes = np.array([u[:, 2] for _, u in self._mounts])[which]
        omega = self.table.true_rates(times)[:, None] * axes
        if self.inner is not None:
            source, axis = self.inner
            omega = omega + source.true_rates(times)[:, None] * np.asarray(axis, float)
        return self.unit.sample(omega, times, self.effects)


class Plate:
    """Several `MountedUnit`s fixed on one plate on the table: the technician (or fixture) sets
    the plate's orientation (table frame -> plate frame) and unit k takes `mountings[k] @` it,
    `mountings[k]` being its fixed rotation plate frame -> unit frame. The table axis is then one
    physical axis for all, and each unit sees it in its own frame."""

    def __init__(self, units: list, mountings: list):
        if len(units) != len(mountings) or not units:
            raise ValueError("a plate needs one mounting per unit")
        self.units = list(units)
        self.mountings = [np.asarray(r, float) for r in mountings]
        self._orientation = np.eye(3)

    @property
    def orientation(self) -> np.ndarray:
        """The plate's orientation now."""
        return self._orientation

    @orientation.setter
    def orientation(self, value) -> None:
        self.mount(value, self.units[0].table.clock.now())

    def mount(self, orientation, at: float) -> None:
        """The plate takes `orientation` from clock time `at` on (`MountedUnit.mount`), each unit
        its mounting times it."""
        self._orientation = np.asarray(orientation, float)
        for unit, mounting in zip(self.units, self.mountings, strict=True):
            unit.mount(mounting @ self._orientation, at)
