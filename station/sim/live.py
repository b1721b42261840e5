"""A sensor unit mounted on the live rotary table: the sample source of the serial/CAN twins."""

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
    the unit's output chain.
    """

    def __init__(self, unit: SensorUnit, table: TablePhysics, orientation=None, effects=None):
        self.unit = unit
        self.table = table
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
        self._mounts.append((self.table.clock.now(), np.asarray(value, float)))

    def __call__(self, times) -> np.ndarray:
        times = np.atleast_1d(np.asarray(times, float))
        which = np.searchsorted([t for t, _ in self._mounts], times, side="right") - 1
        axes = np.array([u[:, 2] for _, u in self._mounts])[which]
        omega = self.table.true_rates(times)[:, None] * axes
        return self.unit.sample(omega, times, self.effects)
