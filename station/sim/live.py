"""A sensor unit mounted on the live rotary table: the sample source of the serial/CAN twins."""

import numpy as np

from station.sim.table import RotaryTable
from station.sim.unit import SensorUnit


class MountedUnit:
    """`times -> counts (k, m)` for `unit` on `table`, for `drivers.twin_can`/serial twins.

    `orientation` (3 x 3, table frame -> unit frame) is what the technician changes between
    positions; the angular rate is the table's true rate along the table axis, read from the
    table's state at each call (bursts are short compared with the table's dynamics).
    """

    def __init__(self, unit: SensorUnit, table: RotaryTable, orientation=None):
        self.unit = unit
        self.table = table
        self.orientation = np.eye(3) if orientation is None else np.asarray(orientation, float)

    def __call__(self, times) -> np.ndarray:
        times = np.atleast_1d(np.asarray(times, float))
        rate = self.table.state().true_rate
        omega = np.outer(np.full(times.size, rate), self.orientation[:, 2])
        return self.unit.sample(omega, times)
