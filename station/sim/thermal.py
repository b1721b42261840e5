"""A unit soaked at a list of temperatures (the `temperature` effect): one simulated session each.

Each soak is a session of the unit with its a and b moved to the soak's temperature by
`station.model.effects.temperature` (`unit_at`): any session simulation (`soak_recordings`, e.g.
`station.sim.rotary.simulate_rotary`), or a free-static one (`simulate_soaks`:
`station.sim.static.simulate_static`, random poses, smooth turns, the unit's noise and
quantisation) whose still intervals of the truth are averaged (mean and standard error per pose),
as the reduction of a recorded soak would give them.
"""

from functools import partial

import numpy as np

from station.model.effects import temperature as effect
from station.model.temperature import Soak
from station.model.unit import SensorUnit
from station.sim.static import simulate_static

ROOM = 296.15
"""K: where the unit starts before the first soak (for the hysteresis' direction)."""


def unit_at(unit: SensorUnit, temperature: float, heating: bool, p: effect.Temperature):
    """A copy of `unit` (same noise, quantisation and random stream) at `temperature` K."""
    ratio, offset = effect.apply(temperature, heating, p)
    return SensorUnit(unit.a * ratio, unit.bias + offset, unit.noise_density, unit.fs,
                      unit.counts_per_unit, unit.output_range, unit.bias_walk, rng=unit.rng)


def soak_recordings(unit: SensorUnit, temperatures, p: effect.Temperature, simulate, *,
                    start: float = ROOM) -> list:
    """[Simulation] `simulate(unit at T)` of `unit` at each temperature T (K) in the order given
    (e.g. a free-static session, or `station.sim.rotary.simulate_rotary` for a gyro unit); the
    unit starts at `start` K: each soak is reached by heating when warmer than the one before."""
    sims, before = [], start
    for temp in temperatures:
        sims.append(simulate(unit_at(unit, temp, temp > before, p)))
        before = temp
    return sims


def simulate_soaks(unit: SensorUnit, temperatures, p: effect.Temperature, *, poses: int = 20,
                   still: float = 2.0, move: float = 1.0, start: float = ROOM) -> list:
    """[Soak] of `unit` at each temperature (K): free-static sessions of `poses` still poses of
    `still` seconds (`soak_recordings`), the still intervals of the truth averaged."""
    sims = soak_recordings(unit, temperatures, p,
                           partial(simulate_static, poses=poses, still=still, move=move),
                           start=start)
    return [Soak(float(temp), *_still_means(sim))
            for temp, sim in zip(temperatures, sims, strict=True)]


def _still_means(sim) -> tuple:
    """((m, P) means, (m, P) standard errors) of a simulation's still intervals, SI units."""
    y = sim.arrays["y"][0] * sim.arrays["lsb"]
    intervals = sim.truth["still"]
    means = np.array([y[a:z].mean(axis=0) for a, z in intervals]).T
    sigma = np.array([y[a:z].std(axis=0, ddof=1) / np.sqrt(z - a) for a, z in intervals]).T
    return means, sigma

