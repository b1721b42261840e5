"""A sensor unit mounted on the live rotary table: the sample source of the serial/CAN twins."""

import numpy as np

from station.model import sensing
from station.model.unit import SensorUnit
from station.sim.table import TablePhysics


class MountedUnit:
    """`times -> counts (k, m)` for `unit` on `table`, for `drivers.twins.can`/serial twins.

    `orientation` (3 x 3, table frame -> unit frame) is what the technician changes between
    positions; the angular rate is the table's true rate along the table axis at each sample's
    own time (`TablePhysics.true_rates`), so a twin that falls behind still sends the right motion.
    `effects` {name: parameters}: named sensor effects (station.model.sensing.LIVE_EFFECTS) in
    the unit's output chain.
    """

    def __init__(self, unit: SensorUnit, table: TablePhysics, orientation=None, effects=None):
        self.unit = unit
        self.table = table
        self.orientation = np.eye(3) if orientation is None else np.asarray(orientation, float)
        self.effects = dict(effects or {})
        sensing.refuse_batch_effects(self.effects)

    def __call__(self, times) -> np.ndarray:
        times = np.atleast_1d(np.asarray(times, float))
        omega = np.outer(self.table.true_rates(times), self.orientation[:, 2])
        return self.unit.sample(omega, times, self.effects)
