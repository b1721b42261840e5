"""A mounted unit whose temperature follows a thermal chamber: the IMU twin's source with a
temperature channel.

`HeatedUnit(mounted, temperature, effect)` is a `times -> counts (k, m + 1)` source for the serial
IMU twin (`drivers.twins.serial.SerialTwin`): the m sensor columns are those of
`station.sim.live.MountedUnit`, computed with the unit's a and b moved to its temperature by the
`temperature` effect (`station.sim.thermal.unit_at`) at the start of each `STEP` of the clock (the
unit's temperature moves by millikelvin in a second); the last column is the unit's own
temperature sensor: the true temperature at each sample's instant plus white noise of `noise` K,
quantised to the profile's counts per K. `temperature(times)` is the chamber's unit temperature on
the shared clock (`drivers.twins.thermal.ChamberPhysics.unit_temperature`); heating or cooling
(for the effect's hysteresis) is the sign of the change over the step before. So a sample's counts
are those of its instant, whatever blocks a busy host cuts the stream into (the sensor's noise
apart: it is drawn in the order of the samples).
"""

import numpy as np

from station.model.effects.temperature import Temperature
from station.sim.thermal import unit_at

SENSOR_NOISE = 0.02
"""K: white noise of the unit's temperature sensor (1-sigma per sample)."""
STEP = 1.0
"""Clock seconds: the unit's a and b take its temperature at the start of each such step (from
clock 0)."""


class HeatedUnit:
    """`times -> counts (k, m + 1)`: the mounted unit at its temperature, then its temperature.

    mounted     : a `station.sim.live.MountedUnit` (its `unit` is the unit at `effect.t_ref`)
    temperature : callable(clock times (k,)) -> the unit's temperatures there, K (or one for all)
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
        self._step = (None, None)  # (step, the unit at its temperature) last used

    def __call__(self, times) -> np.ndarray:
        times = np.atleast_1d(np.asarray(times, float))
        steps = np.floor(times / STEP)
        counts = np.empty((len(times), self.base.m), np.int64)
        for step in np.unique(steps):
            here = steps == step
            self.mounted.unit = self._unit_in(step)
            counts[here] = self.mounted(times[here])
        sensed = self._temperatures(times) + self.noise * self._rng.standard_normal(len(times))
        return np.column_stack([counts, np.round(sensed * self.scale).astype(np.int64)])

    def _unit_in(self, step: float):
        """The unit at its temperature at the start of `step`, heating if warmer than a step
        before (kept while the stream stays in that step)."""
        if self._step[0] != step:
            now, before = self._temperatures(np.array([step, step - 1.0]) * STEP)
            self._step = (step, unit_at(self.base, now, now >= before, self.effect))
        return self._step[1]

    def _temperatures(self, times: np.ndarray) -> np.ndarray:
        """The unit's true temperatures at `times`, K."""
        return np.broadcast_to(np.asarray(self.temperature(times), float), times.shape)
