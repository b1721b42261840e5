"""A rotary session of a unit whose temperature moves during it, its temperature recorded.

`simulate_warm_rotary` runs `station.sim.rotary.simulate_rotary` (any other effects included),
then moves each sample's biases by the `temperature` effect's bias tempcos at the unit's
temperature T(t) (`station.model.effects.temperature.bias_offsets`), and records T as the
session's `temperature` array (n, k) in K: the true temperature plus the temperature sensor's
white noise, quantised (`KELVIN_LSB`), as a unit's own temperature channel gives it
(`station.sim.heated`). Temperature histories (session time (n, k), true table rate (n, k) ->
K (n, k)):

- `chamber_hump`: a chamber ramp up and back down over the session (not monotone in time);
- `motor_heating`: the table's motor heats the unit while it spins, it cools at rest (the heat
  state of `station.model.effects.bias_drift.heat`);
- `slow_ramp`: a slow monotone drift of the room (with no tempco: a recorded but harmless T).

The offsets (often a fraction of a count) are added to the quantised counts with a uniform
dither, round(offset + u), u ~ U(-1/2, 1/2): the mean is the offset exactly, and the dither adds
white noise of at most 1/4 count^2 (the default MEMS gyro: 0.5 lsb against 1.7 lsb of noise per
sample at 100 Hz, 4 % of its variance), which the diagnosis' noise estimate includes.
"""

import dataclasses

import numpy as np

from station.model.effects.bias_drift import heat
from station.model.effects.temperature import Temperature, bias_offsets
from station.sim.heated import SENSOR_NOISE
from station.sim.rotary import Simulation, simulate_rotary
from station.sim.thermal import ROOM

KELVIN_LSB = 1 / 326.8
"""K per count of the simulated temperature channel (an InvenSense MEMS gyro's 326.8 LSB/degC)."""


def chamber_hump(amplitude: float, start: float = ROOM):
    """T = start + amplitude sin(pi t / t_end): up, then back down by the session's end."""
    def history(t_session, rate):
        return start + amplitude * np.sin(np.pi * t_session / t_session.max())
    return history


def motor_heating(gain: float, tau: float = 60.0, start: float = ROOM):
    """T = start + gain H(t), H the heat state of |rate| with time constant tau (K per rad/s)."""
    def history(t_session, rate):
        return start + gain * heat(t_session, rate, tau)
    return history


def slow_ramp(total: float, start: float = ROOM):
    """T = start + total t / t_end: a room drifting by `total` K over the session."""
    def history(t_session, rate):
        return start + total * t_session / t_session.max()
    return history


def simulate_warm_rotary(unit, orientations, timing, history, tempco: Temperature, *,
                         effects: dict | None = None, a_nominal=None,
                         sensor_noise: float = SENSOR_NOISE) -> Simulation:
    """[Simulation] of the rotary protocol (`simulate_rotary`, its arguments) of a unit whose
    temperature follows `history` (session time, true rate -> K) and whose biases follow
    `tempco` (its bias and bias2; its scale tempcos and hysteresis are refused: not simulated
    here); the arrays gain `temperature` (n, k) K, the truth `temperature` (the tempcos) and
    `temperature_true` (n, k)."""
    if np.any(tempco.scale) or np.any(tempco.scale2) or np.any(tempco.hysteresis):
        raise ValueError("simulate_warm_rotary moves the biases only: give bias (and bias2) "
                         "tempcos, scale, scale2 and hysteresis 0")
    sim = simulate_rotary(unit, orientations, timing, effects=effects, a_nominal=a_nominal)
    arrays, truth = dict(sim.arrays), dict(sim.truth)
    factors = np.asarray(truth["rate_factors"], float)
    t_session = arrays["t0"][:, None] + np.arange(arrays["y"].shape[1]) / arrays["fs"]
    true = history(t_session, factors[:, None] * arrays["rate_cmd"])
    shift = bias_offsets(true - tempco.t_ref, tempco) * unit.counts_per_unit
    dither = unit.rng.uniform(-0.5, 0.5, arrays["y"].shape)
    arrays["y"] = (arrays["y"] + np.round(shift + dither)).astype(arrays["y"].dtype)
    sensed = true + sensor_noise * unit.rng.standard_normal(true.shape)
    arrays["temperature"] = np.round(sensed / KELVIN_LSB) * KELVIN_LSB
    truth["temperature"] = dataclasses.asdict(tempco)
    truth["temperature_true"] = true
    return Simulation(arrays, truth)
