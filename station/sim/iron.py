"""Right-angle-iron poses (Hwangbo & Kanade): six faces per mounting, several mountings.

The unit is fixed in the iron in orientation B (iron frame -> unit frame) for one mounting; the iron
rests on face f, whose outward normal n_f (+-x, +-y, +-z of the iron) points down, so "up" is -n_f.
Each pose has a small placement error (a random rotation of `placement_deg` standard deviation per
axis). Stimulus of an accelerometer: specific force g * B E (-n_f). Optionally (`turn_deg`) a gyro
sees a known-angle turn of the iron about the vertical on each face, with a raised-cosine rate.
"""

import numpy as np
from scipy.spatial.transform import Rotation

from station.model.earth import normal_gravity
from station.model.effects import to_json
from station.model.sensing import refuse_motion_effects, sense
from station.model.unit import SensorUnit
from station.sim.layouts import TRIAD, accelerometer_triad, gyro_array
from station.sim.rotary import Simulation, random_orientations

FACE_NORMALS = np.array(
    [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float
)
"""Outward normals of the iron's faces, in the iron frame; face 2i and 2i+1 are opposite."""


def pose_up(mountings: np.ndarray, placement_deg: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) up direction in the unit frame and (P,) face index for 6 faces per mounting."""
    p = 6 * len(mountings)
    err = Rotation.from_rotvec(np.radians(placement_deg) * rng.standard_normal((p, 3))).as_matrix()
    face = np.tile(np.arange(6), len(mountings))
    b = np.repeat(mountings, 6, axis=0)
    up = np.einsum("pij,pjk,pk->pi", b, err, -FACE_NORMALS[face])
    return up, face


def turn_rate(t: np.ndarray, start: float, duration: float, angle: float) -> np.ndarray:
    """Raised-cosine rate of a turn by `angle` rad over [start, start + duration]."""
    x = np.clip((t - start) / duration, 0.0, 1.0)
    inside = (t > start) & (t < start + duration)
    return np.where(inside, angle / duration * (1 - np.cos(2 * np.pi * x)), 0.0)


def simulate_iron(
    unit: SensorUnit,
    mountings=3,
    still: float = 5.0,
    gap: float = 10.0,
    placement_deg: float = 0.1,
    latitude_deg: float = 52.2,
    turn_deg=None,
    turn_time: float = 4.0,
    effects: dict | None = None,
    a_nominal=None,
) -> Simulation:
    """Simulate 6 faces x mountings poses of an accelerometer unit (or, with turn_deg, a gyro unit).

    mountings : count of random mountings or (K, 3, 3) iron -> unit rotations.
    still : seconds of each static recording; with turn_deg, still / turn / still.
    """
    effects = effects or {}
    refuse_motion_effects(effects, "iron")
    rng = unit.rng
    b = (
        random_orientations(int(mountings), rng)
        if np.ndim(mountings) == 0
        else np.asarray(mountings, float)
    )
    up, face = pose_up(b, placement_deg, rng)
    fs, p = unit.fs, up.shape[0]
    g = normal_gravity(latitude_deg)
    duration = still if turn_deg is None else 2 * still + turn_time
    k = round(duration * fs)
    t = np.arange(k) / fs
    t0 = np.arange(p) * (duration + gap)
    if turn_deg is None:
        profile, magnitude = np.zeros(k), g
        v = np.broadcast_to(g * up[:, None, :], (p, k, 3))
    else:
        profile, magnitude = (
            turn_rate(t, still, turn_time, np.radians(turn_deg)),
            np.radians(turn_deg),
        )
        v = profile[None, :, None] * up[:, None, :]
    y = sense(unit, unit.project(v), t, t0, np.zeros((p, k)), effects)
    arrays = {
        "y": y,
        "lsb": unit.lsb,
        "fs": np.float64(fs),
        "t0": t0,
        "c_cmd": np.float64(magnitude),
        "mounting": np.repeat(np.arange(len(b)), 6),
    }
    if turn_deg is None:
        arrays["seg_still"] = np.array([0, k])
    else:
        edges = np.ceil(np.round(np.array([0, still, still + turn_time, duration]) * fs, 9)).astype(
            int
        )
        arrays.update(seg_static=edges[:2], seg_turn=edges[1:3], seg_static_after=edges[2:])
    if a_nominal is not None:
        arrays["a_nominal"] = np.asarray(a_nominal, float)
    truth = {
        "protocol": "iron",
        "stimulus": "rate" if turn_deg else "specific force",
        "units": {"v": "m/s^2" if turn_deg is None else "rad (turn angle)", "time": "s"},
        "a": unit.a,
        "bias": unit.bias,
        "noise_density": unit.noise_density,
        "mountings": b,
        "face": face,
        "up": up,
        "gravity": g,
        "v": (g * up).T if turn_deg is None else (np.radians(turn_deg) * up).T,
        "effects": to_json(effects),
    }
    return Simulation(arrays, truth)


def simulated_session(rng: np.random.Generator, effects: dict, options) -> Simulation:
    """`station simulate --protocol iron` (`station.protocols.KINDS`): an accelerometer triad at
    `options.fs` in `options.positions` (default 3) mountings, or with `options.turn_deg` a gyro
    triad turned by that angle on each face."""
    unit = (gyro_array(rng, TRIAD, fs=options.fs) if options.turn_deg
            else accelerometer_triad(rng, fs=options.fs))
    return simulate_iron(unit, options.positions or 3, turn_deg=options.turn_deg, effects=effects,
                         a_nominal=TRIAD)
