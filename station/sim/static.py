"""Free static poses for multi-position accelerometer calibration (as in Tedaldi et al.).

One continuous recording: the unit rests in a random orientation for `still` seconds, then turns
smoothly (spherical interpolation with a raised-cosine timing) to the next one in `move` seconds.
The specific force is gravity, g R(t) up, rotated into the unit frame; the still intervals are not
in the data file (the station must detect them), only in the truth.
"""

import numpy as np
from scipy.spatial.transform import Rotation

from station.errors import InputError
from station.model.earth import earth_rate_enu, normal_gravity
from station.model.effects import g_sensitivity, to_json
from station.model.sensing import refuse_motion_effects, sense
from station.model.unit import SensorUnit
from station.sim.layouts import TRIAD, accelerometer_triad
from station.sim.rotary import Simulation


def attitude_path(rotations: Rotation, still: float, move: float, fs: float):
    """Sample times (K,), the attitude at each sample and the (P, 2) still intervals in samples."""
    p = len(rotations)
    period = still + move
    k = round((p * period - move) * fs)
    t = np.arange(k) / fs
    j = np.minimum((t // period).astype(int), p - 1)
    frac = np.clip((t - j * period - still) / move, 0.0, 1.0)
    smooth = 0.5 - 0.5 * np.cos(np.pi * frac)
    out = rotations[j]
    moving = frac > 0
    if np.any(moving):
        jm = j[moving]
        rel = (rotations[jm].inv() * rotations[np.minimum(jm + 1, p - 1)]).as_rotvec()
        out_m = rotations[jm] * Rotation.from_rotvec(rel * smooth[moving, None])
        mats = out.as_matrix()
        mats[moving] = out_m.as_matrix()
        out = Rotation.from_matrix(mats)
    starts = np.arange(p) * period
    still_idx = np.ceil(np.round(np.stack([starts, starts + still], 1) * fs, 9)).astype(int)
    return t, out, np.minimum(still_idx, k)


def simulate_static(
    unit: SensorUnit,
    poses: int = 20,
    still: float = 4.0,
    move: float = 2.0,
    latitude_deg: float = 52.2,
    effects: dict | None = None,
    a_nominal=None,
) -> Simulation:
    """Simulate a free-static accelerometer recording of `poses` random orientations."""
    effects = effects or {}
    refuse_motion_effects(effects, "static")
    rot = Rotation.random(int(poses), random_state=unit.rng)  # local -> unit frame
    t, att, still_idx = attitude_path(rot, still, move, unit.fs)
    g = normal_gravity(latitude_deg)
    v = g * att.apply([0.0, 0.0, 1.0])
    y = sense(unit, unit.project(v)[None], t, np.zeros(1), np.zeros((1, t.size)), effects)
    arrays = {
        "y": y,
        "lsb": unit.lsb,
        "fs": np.float64(unit.fs),
        "t0": np.zeros(1),
        "c_cmd": np.float64(g),
    }
    if a_nominal is not None:
        arrays["a_nominal"] = np.asarray(a_nominal, float)
    truth = {
        "protocol": "static",
        "units": {"v": "m/s^2", "time": "s"},
        "a": unit.a,
        "bias": unit.bias,
        "noise_density": unit.noise_density,
        "gravity": g,
        "still": still_idx,
        "orientations": rot.as_matrix(),
        "v": (g * rot.apply([0.0, 0.0, 1.0])).T,
        "effects": to_json(effects),
    }
    return Simulation(arrays, truth)


def static_gyro(truth: dict, samples: int, rng: np.random.Generator, *, bias: float = 0.01,
                sigma: float = 0.002, effects: dict | None = None) -> np.ndarray:
    """(samples, 3) gyro of a free-static session (`simulate_static`'s truth), rad/s: a common
    bias, white noise of `sigma` per sample and, in the still intervals, the gyro effects
    earth_rate (the Earth rate in the unit frame of each pose; the heading is in the random
    orientation) and g_sensitivity (G f_j, f_j = the pose's specific force). The turns between
    poses are not simulated (the stillness detector finds them on the accelerometer)."""
    effects = effects or {}
    extra = sorted(set(effects) - {"earth_rate", "g_sensitivity"})
    if extra:
        raise InputError(f"effect(s) {', '.join(extra)} are not simulated on the static gyro; "
                         "it supports earth_rate and g_sensitivity")
    rot = np.asarray(truth["orientations"])
    omega = np.zeros((len(rot), 3))
    if "earth_rate" in effects:
        p = effects["earth_rate"]
        omega += rot @ earth_rate_enu(p.latitude_deg, p.rate)
    if "g_sensitivity" in effects:
        omega = g_sensitivity.apply(omega, np.asarray(truth["v"]).T, effects["g_sensitivity"])
    out = bias + sigma * rng.standard_normal((samples, 3))
    for j, (a, z) in enumerate(truth["still"]):
        out[a:z] += omega[j]
    return out


def simulated_session(rng: np.random.Generator, effects: dict, options) -> Simulation:
    """`station simulate --protocol static` (`station.protocols.KINDS`): an accelerometer triad at
    `options.fs` in `options.positions` (default 20) poses."""
    unit = accelerometer_triad(rng, fs=options.fs)
    return simulate_static(unit, options.positions or 20, effects=effects, a_nominal=TRIAD)
