"""A simulated hand-held free-static recording (issue 14): a rest, then poses placed by hand, one
of them quieter than the rest; the hand's letting go wobbles the accelerometer for 0.5-1.5 s and
the gyro longer. Used by the detector's tests and the command-line chain's."""

import numpy as np

FS = 100.0
G = 9.80665
A_TRUE = np.array([[1.02, 0.01, 0.0], [0.0, 0.98, -0.02], [0.01, 0.0, 1.01]])  # rows a_i^T
B_TRUE = np.array([0.05, -0.03, 0.02])
ACC_NOISE, GYRO_NOISE = 0.02, 0.004  # m/s^2, rad/s (white, per sample)
REST, POSE, MOVE = 10.0, 4.0, 1.5  # seconds
QUIET = 5  # this pose is 3x quieter than the rest period and the other poses


def hand_session(seed: int = 0, poses: int = 14, pose_s: float = POSE, gyro_settle: float = 2.0,
                 endless_gyro: int | None = None, ups=None):
    """(samples (K, 6): accelerometer m/s^2 then gyro rad/s, true [start, stop) of the rest and
    each pose): a rest, then poses held `pose_s` seconds by hand. At the start of pose j the hand
    lets go: the accelerometer wobbles (3 Hz, 0.3 m/s^2, dying out over settle_j, uniform in
    0.5-1.5 s) and the gyro for `gyro_settle` x settle_j (4 Hz, 0.05 rad/s); pose `endless_gyro`
    (if any) wobbles on the gyro all the time. Between poses a 1.5 s turn, seen by the gyro.
    ups: (poses + 1, 3) up directions of the rest and each pose in the unit frame, consecutive
    ones neither equal nor opposite (default: random)."""
    rng = np.random.default_rng(seed)
    up = rng.normal(size=(poses + 1, 3)) if ups is None else np.array(ups, float)
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    acc, gyro, truth = [], [], []
    k = 0

    def still(j, seconds, settle):
        nonlocal k
        n = round(seconds * FS)
        t = np.arange(n) / FS
        scale = 1 / 3 if j == QUIET else 1.0
        a = (A_TRUE @ (G * up[j]) + B_TRUE) + scale * ACC_NOISE * rng.standard_normal((n, 3))
        w = scale * GYRO_NOISE * rng.standard_normal((n, 3))
        if settle:
            fade = np.clip(1 - t / settle, 0, None)[:, None] ** 2
            a += 0.3 * fade * np.sin(2 * np.pi * 3 * t)[:, None] * [1.0, -0.7, 0.5]
            tail = settle * gyro_settle if j != endless_gyro else np.inf
            gfade = np.clip(1 - t / tail, 0, None)[:, None] ** 2
            w += 0.05 * gfade * np.sin(2 * np.pi * 4 * t)[:, None] * [0.6, 1.0, -0.8]
        acc.append(a)
        gyro.append(w)
        truth.append((k, k + n))
        k += n

    def turn(j):
        nonlocal k
        n = round(MOVE * FS)
        s = (1 - np.cos(np.pi * np.arange(n) / n)) / 2  # smooth 0 -> 1
        v = (1 - s)[:, None] * up[j] + s[:, None] * up[j + 1]
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        acc.append(G * v @ A_TRUE.T + B_TRUE + ACC_NOISE * rng.standard_normal((n, 3)))
        angle = np.arccos(np.clip(up[j] @ up[j + 1], -1, 1))
        axis = np.cross(up[j], up[j + 1]) / np.sin(angle)
        rate = angle * np.pi / 2 * np.sin(np.pi * np.arange(n) / n) / MOVE
        gyro.append(rate[:, None] * axis + GYRO_NOISE * rng.standard_normal((n, 3)))
        k += n

    still(0, REST, 0.0)
    for j in range(1, poses + 1):
        turn(j - 1)
        still(j, pose_s, rng.uniform(0.5, 1.5))
    turn(poses - 1)  # the unit is picked up at the end
    return np.hstack([np.concatenate(acc), np.concatenate(gyro)]), np.array(truth)
