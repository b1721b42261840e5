"""A mounted unit whose temperature follows a thermal chamber: the IMU twin's source with a
temperature channel.

`HeatedUnit(mounted, temperature, effect)` is a `times -> counts (k, m + 1)` source for the serial
IMU twin (`drivers.twins.serial.SerialTwin`): the m sensor columns are those of
`station.sim.live.MountedUnit`, computed with the unit's a and b moved to its temperature by the
`temperature` effect (`station.sim.thermal.unit_at`), block by block at the block's mean
temperature (the unit's temperature moves by millikelvin within a block of frames); the last column
is the unit's own temperature sensor: the true temperature plus white noise of `noise` K, quantised
to the profile's counts per K. `temperature(t)` is the chamber's unit temperature on the shared
clock (`drivers.twins.thermal.ChamberPhysics.unit_temperature`); heating or cooling (for the
effect's hysteresis) is the sign of the change since the previous block.
"""

import numpy as np

from station.model.effects.temperature import Temperature
from station.sim.thermal import ROOM, unit_at

SENSOR_NOISE = 0.02
"""K: white noise of the unit's temperature sensor (1-sigma per sample)."""


class HeatedUnit:
    """`times -> counts (k, m + 1)`: the mounted unit at its temperature, then its temperature.

    mounted     : a `station.sim.live.MountedUnit` (its `unit` is the unit at `effect.t_ref`)
    temperature : callable(clock time) -> the unit's temperature, K
    effect      : the unit's tempcos (`station.model.effects.temperature.Temperature`)
    counts_per_kelvin : the temperature channel's scale (the device profile's)
    noise, seed : the temperature sensor's white noise (K, 1-sigma) and its generator's seed
    """

    def __init__(self, mounted, temperature, effect: Temperature, counts_per_kelvin: float,
                 noise: float = SENSOR_NOISE, seed: int = 0):
        self.mounted, self.temperature, self.effect = mounted, temperature, effect
        self.base = mounted.unit
        self.scale, self.noise = float(counts_per_kelvin), float(noise)
        self._rng = np.random.default_rng([seed, 15])
        self._before = ROOM

    def __call__(self, times) -> np.ndarray:
        times = np.atleast_1d(np.asarray(times, float))
        ends = (self.temperature(float(times[0])), self.temperature(float(times[-1])))
        true = np.interp(times, [times[0], times[-1] + 1e-12], ends)
        middle = float(np.mean(ends))
        self.mounted.unit = unit_at(self.base, middle, middle >= self._before, self.effect)
        self._before = middle
        counts = self.mounted(times)
        sensed = true + self.noise * self._rng.standard_normal(len(times))
        return np.column_stack([counts, np.round(sensed * self.scale).astype(np.int64)])
