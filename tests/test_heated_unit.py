"""The IMU twin's source inside a thermal chamber (station.sim.heated.HeatedUnit): its
temperature channel is the unit's temperature with the sensor's noise and quantisation, and its
gyros' biases move with that temperature by the true tempco."""

import numpy as np
from scipy.stats import norm

from drivers.clock import ScaledClock
from station.sim.heated import SENSOR_NOISE, HeatedUnit
from station.sim.layouts import gyro_array
from station.sim.live import MountedUnit
from station.sim.table import TablePhysics
from station.twin.thermal import TRUTH

ALPHA = 0.01
"""False-alarm probability of each check, over the values it checks (Bonferroni)."""
N = 20000


def test_the_heated_unit_streams_its_temperature_and_its_biases_follow_it():
    clock = ScaledClock(1.0)
    unit = gyro_array(np.random.default_rng(1), fs=100.0, counts_per_unit=1e6)
    temperature = {"now": 263.15}
    source = HeatedUnit(MountedUnit(unit, TablePhysics(clock)), lambda t: temperature["now"],
                        TRUTH, counts_per_kelvin=100.0, seed=1)
    times = np.arange(N) / 100.0
    cold = source(times)
    temperature["now"] = 333.15
    hot = source(times + N / 100.0)

    sigma = np.hypot(SENSOR_NOISE, 0.01 / np.sqrt(12))  # noise, then rounding to 0.01 K
    for counts, true in ((cold[:, -1], 263.15), (hot[:, -1], 333.15)):
        sensed = counts / 100.0 - true
        assert abs(sensed.mean()) < norm.isf(ALPHA / 8) * sigma / np.sqrt(N)
        assert abs(sensed.std(ddof=1) / sigma - 1) < norm.isf(ALPHA / 8) / np.sqrt(2 * (N - 1))

    moved = (hot[:, :12].mean(axis=0) - cold[:, :12].mean(axis=0)) / 1e6  # at rest: the biases
    se = np.sqrt((hot[:, :12].var(axis=0, ddof=1) + cold[:, :12].var(axis=0, ddof=1)) / N) / 1e6
    assert np.all(np.abs(moved - 70.0 * TRUTH.bias) < norm.isf(ALPHA / 24) * se), moved


class SetClock:
    """A clock the test sets by hand."""

    t = 0.0

    def now(self) -> float:
        return self.t


def test_a_late_block_gets_the_counts_an_on_time_one_got():
    """Inside a heating chamber, the samples of 120 s asked for at once, 5000 s late, are to the
    last count those asked for block by block as they fell due: temperature channel and gyros
    (the unit's a and b follow its temperature step by step of the clock, not block by block)."""
    from drivers.twins.thermal import ChamberPhysics

    times = np.arange(12000) / 100.0

    def bench():
        clock = SetClock()
        physics = ChamberPhysics(clock, tau_air=10.0, heat_rate=30.0, tau_unit=30.0)
        physics.set_setpoint(physics.room + 40.0)
        physics.run()
        unit = gyro_array(np.random.default_rng(1), fs=100.0, counts_per_unit=1e6)
        source = HeatedUnit(MountedUnit(unit, TablePhysics(ScaledClock(1.0))),
                            physics.unit_temperature, TRUTH, counts_per_kelvin=100.0, seed=1)
        return clock, physics, source

    clock, physics, source = bench()
    blocks, sent = [], 0
    for now in np.arange(0.0, 120.0, 0.37):  # the chamber's polls and the twin's blocks
        clock.t = now
        physics.state()
        due = np.searchsorted(times, now, side="right")
        if due > sent:
            blocks.append(source(times[sent:due]))
            sent = due
    clock, physics, late = bench()
    clock.t = 5000.0
    physics.state()
    np.testing.assert_array_equal(late(times[:sent]), np.concatenate(blocks))
