"""Simulated rotary-table session (Rupniewski Section IV): n positions of the unit on the table.

Per position j the unit sits on the table in orientation C_j (table frame -> unit frame, so the
table axis in the unit frame is u_j = C_j e_z). The table follows the commanded trapezoid of
`RotaryTiming`; the angular-rate truth in the unit frame is rate(t) u_j, distorted by the named
effects in this order: rate_error, axis_wobble, earth_rate, g_sensitivity (kinematics),
projection a^T omega, scale_nonlinearity, latency (sensed signal), biases + bias_drift + walk +
noise, saturation, quantisation.
"""

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from station.model.earth import normal_gravity
from station.model.effects import axis_wobble, earth_rate, g_sensitivity, to_json
from station.model.effects.earth_rate import EarthRate
from station.model.sensing import sense
from station.model.unit import SensorUnit
from station.sim.layouts import A_MODEL, gyro_array
from station.sim.profile import RotaryTiming

BLOCK_POSITIONS = 16
"""Positions simulated at a time when nothing but the noise's random stream carries from one
position to the next (`separable`): the memory of a simulation is then that of a block."""


@dataclass
class Simulation:
    """A simulated recording: `arrays` (the data file's keys) and `truth` (JSON-ready dict).

    An array may be `Blocks` (the positions computed a block at a time as they are written,
    `station.imports.npz.write`)."""

    arrays: dict
    truth: dict


@dataclass(frozen=True)
class Blocks:
    """An array (n, ...) computed a block of positions at a time: `shape`, `dtype`, and `make`,
    a callable returning the iterator of the blocks in order. The blocks may draw from the
    simulation's random stream: iterate them once."""

    shape: tuple
    dtype: np.dtype
    make: object

    def __iter__(self):
        return iter(self.make())


def random_orientations(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3, 3) uniformly distributed rotation matrices."""
    return Rotation.random(n, random_state=rng).as_matrix().reshape(n, 3, 3)


def table_motion(timing: RotaryTiming, fs: float, factors: np.ndarray):
    """Times and commanded rate (k,), commanded angle (k,), and each position's starting angle
    (n,): the true motion of position j is the commanded one times its rate factor, its true
    angle `start[j] + factors[j] * angle_cmd` (the table is not reset between positions);
    `true_motion` gives them for a block of positions."""
    profile = timing.profile()
    t = np.arange(timing.samples(fs)) / fs
    per_position = factors * profile.angle(timing.static + timing.moving)
    start = np.concatenate([[0.0], np.cumsum(per_position)[:-1]])
    return t, profile.rate(t), profile.angle(t), start


def true_motion(rate_cmd, angle_cmd, factors, start) -> tuple:
    """True rate and cumulative true angle (n, k) of positions with rate `factors` (n,) and
    starting angles `start` (n,) (`table_motion`)."""
    return factors[:, None] * rate_cmd, start[:, None] + factors[:, None] * angle_cmd


def separable(unit: SensorUnit, effects: dict) -> bool:
    """True when positions simulated a block at a time give the numbers of the whole session at
    once: no bias random walk and no heating (whose states carry from one position to the
    next); the white noise is drawn block after block from the same stream."""
    drift = effects.get("bias_drift")
    return not np.any(unit.bias_walk) and not (drift is not None and np.any(drift.heating))


def angular_rate(rate, angle, t, orientation, effects: dict) -> np.ndarray:
    """(n, k, 3) angular rate in the unit frame: table rate along u_j, wobble, Earth rate."""
    if "axis_wobble" in effects:
        omega = axis_wobble.apply(rate, angle, t, orientation, effects["axis_wobble"])
    else:
        omega = rate[..., None] * orientation[:, None, :, 2]
    if "earth_rate" in effects:
        omega = earth_rate.apply(omega, orientation, angle, effects["earth_rate"])
    if "g_sensitivity" in effects:
        g = normal_gravity(effects.get("earth_rate", EarthRate()).latitude_deg)
        f = g * orientation[:, None, :, 2]  # specific force: the table axis is up
        omega = g_sensitivity.apply(omega, f, effects["g_sensitivity"])
    return omega


def simulate_rotary(
    unit: SensorUnit,
    orientations,
    timing: RotaryTiming | None = None,
    effects: dict | None = None,
    gap: float = 30.0,
    a_nominal=None,
    lazy: bool = False,
) -> Simulation:
    """Simulate the rotary protocol for `orientations` ((n, 3, 3) or a count of random ones).

    unit : the gyro unit (its rng drives everything, so a seeded unit makes the session
        deterministic).
    timing : durations and commanded rate of a position (default `RotaryTiming()`).
    gap : seconds between the end of one position and the start of the next (re-mounting).
    effects : {name: parameters} from `station.model.effects.parse_all`; empty = ideal.
    lazy : the counts `y` and the `angle` as `Blocks`, computed as they are written (a block of
        `BLOCK_POSITIONS` positions at a time when `separable`), the same numbers.
    """
    effects = effects or {}
    timing = timing or RotaryTiming()
    rng = unit.rng
    if np.ndim(orientations) == 0:
        orientations = random_orientations(int(orientations), rng)
    orientation = np.asarray(orientations, float)
    n, fs = orientation.shape[0], unit.fs
    factors = effects["rate_error"].factors(n, rng) if "rate_error" in effects else np.ones(n)
    encoder = "rate_error" in effects and effects["rate_error"].encoder
    t, rate_cmd, angle_cmd, start = table_motion(timing, fs, factors)
    k = t.size
    t0 = np.arange(n) * (k / fs + gap)
    size = BLOCK_POSITIONS if separable(unit, effects) else n
    parts = [slice(i, i + size) for i in range(0, n, size)]

    def counts():
        """The counts, a block of positions at a time."""
        for b in parts:
            rate, angle = true_motion(rate_cmd, angle_cmd, factors[b], start[b])
            yield _counts(unit, orientation[b], rate, angle, t, t0[b], effects)

    def angles():
        """The table's reported angle within each position: its encoder's, or the command's."""
        for b in parts:
            yield (factors[b, None] * angle_cmd if encoder
                   else np.broadcast_to(angle_cmd, (len(factors[b]), k)).copy())

    y = Blocks((n, k, unit.m), np.dtype(np.int32), counts)
    angle = Blocks((n, k), np.dtype(float), angles)
    segments = timing.segments(fs)
    arrays = {
        "y": y if lazy else _whole(y),
        "lsb": unit.lsb,
        "fs": np.float64(fs),
        "t0": t0,
        "rate_cmd": rate_cmd,
        "c_cmd": np.float64(timing.rate),
        "angle": angle if lazy else _whole(angle),
        **{f"seg_{name}": np.array(seg) for name, seg in segments.items()},
    }
    if a_nominal is not None:
        arrays["a_nominal"] = np.asarray(a_nominal, float)
    axis = orientation[:, :, 2]
    truth = {
        "protocol": "rotary",
        "units": {"v": "rad/s", "a": "output rad/s per rad/s", "bias": "rad/s", "time": "s"},
        "a": unit.a,
        "bias": unit.bias,
        "noise_density": unit.noise_density,
        "bias_walk": unit.bias_walk,
        "output_range": unit.output_range,
        "orientations": orientation,
        "axis": axis,
        "rate_factors": factors,
        "v": (timing.rate * factors[:, None] * axis).T,
        "timing": {
            "rate": timing.rate,
            "max_accel": timing.max_accel,
            "static": timing.static,
            "moving": timing.moving,
            "settle": timing.settle,
            "gap": gap,
        },
        "effects": to_json(effects),
    }
    return Simulation(arrays, truth)


def _counts(unit, orientation, rate, angle, t, t0, effects) -> np.ndarray:
    """Counts (n, k, m) of the positions `orientation` (n, 3, 3) with the true table `rate` and
    `angle` (n, k), recordings starting at session times t0 (n,)."""
    if {"axis_wobble", "earth_rate", "g_sensitivity"} & effects.keys():
        s = unit.project(angular_rate(rate, angle, t, orientation, effects))
    else:  # fast path: omega = rate u_j, so a^T omega = rate (a^T u_j)
        s = rate[..., None] * unit.project(orientation[:, :, 2])[:, None, :]
    return sense(unit, s, t, t0, rate, effects)


def _whole(blocks: Blocks) -> np.ndarray:
    """The array of `blocks`, filled block by block."""
    out = np.empty(blocks.shape, blocks.dtype)
    first = 0
    for block in blocks:
        out[first:first + len(block)] = block
        first += len(block)
    return out


def simulated_session(rng: np.random.Generator, effects: dict, options) -> Simulation:
    """`station simulate --protocol rotary` (`station.protocols.KINDS`): a 12-gyro array at
    `options.fs` on `options.positions` (default 20) random positions at `options.rate` rad/s,
    its counts and angles computed as they are written (`Blocks`)."""
    unit = gyro_array(rng, fs=options.fs)
    return simulate_rotary(unit, options.positions or 20, RotaryTiming(rate=options.rate),
                           effects=effects, a_nominal=A_MODEL, lazy=True)
