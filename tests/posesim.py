"""Still poses of an MPU-6050-class accelerometer triad, with the errors real poses carry, for the
interval-honesty and leave-one-out checks (tests/test_honesty.py, bench/honesty.py).

Noise density 400 ug/sqrt(Hz) at fs = 100 Hz: white sample noise 400e-6 g sqrt(fs / 2) =
0.0277 m/s^2, so a 3 s pose mean has a standard error of 1.6e-3 m/s^2. Real poses add a per-pose
offset (re-seating, settling; `pose_sd` per axis) and coloured noise (an AR(1) process of standard
deviation `ar_sd` and correlation time `ar_tau`): the sd / sqrt(N) of the samples misses both.
"""

import numpy as np
from scipy.signal import lfilter

G = 9.80665
FS = 100.0
WHITE = 400e-6 * G * np.sqrt(FS / 2)  # m/s^2 per sample


def random_directions(rng: np.random.Generator, n: int) -> np.ndarray:
    """(3, n) unit vectors uniform on the sphere."""
    v = rng.standard_normal((3, n))
    return v / np.linalg.norm(v, axis=0)


def mpu6050_triad(rng: np.random.Generator):
    """(a (3, 3), b (3,)): scale errors ~3 %, misalignments ~1 deg, biases ~0.5 m/s^2."""
    a = np.diag(1 + 0.03 * rng.standard_normal(3)) + np.radians(1.0) * rng.standard_normal((3, 3)) \
        * (1 - np.eye(3))
    return a, 0.5 * rng.standard_normal(3)


def pose_means(rng, a, b, v, *, duration: float = 3.0, pose_sd: float = 0.0, ar_sd: float = 0.0,
               ar_tau: float = 0.5):
    """(M (m, n), stderr (m, n)): the sample means of n still poses (gravity G along the unit
    vectors v) and their white-noise standard errors sd / sqrt(N), as a reduction computes them."""
    (m, n), k = (a.shape[1], v.shape[1]), int(round(duration * FS))
    truth = a.T @ (G * v) + b[:, None] + pose_sd * rng.standard_normal((m, n))
    samples = WHITE * rng.standard_normal((m, n, k))
    if ar_sd > 0:
        phi = np.exp(-1 / (FS * ar_tau))
        drive = ar_sd * np.sqrt(1 - phi**2) * rng.standard_normal((m, n, k))
        drive[..., 0] = ar_sd * rng.standard_normal((m, n))  # start in the stationary state
        samples += lfilter([1.0], [1.0, -phi], drive, axis=-1)
    return truth + samples.mean(axis=-1), samples.std(axis=-1, ddof=1) / np.sqrt(k)


def covered(result, a, b) -> dict:
    """Per parameter class, whether each 95 % interval (+-1.96 total sigma) holds the truth."""
    i, k = np.triu_indices(3, 1)
    u = a / np.linalg.norm(a, axis=0)
    angles = np.arccos(np.clip(u.T @ u, -1, 1))[i, k]
    return {
        "scale_factors": np.abs(result.scale_factors - np.linalg.norm(a, axis=0))
        < 1.96 * result.scale_factors_sigma,
        "misalignments": np.abs(result.axis_angles[i, k] - angles)
        < 1.96 * result.axis_angles_sigma[i, k],
        "biases": np.abs(result.bias - b) < 1.96 * result.bias_sigma,
    }


CLASSES = ("scale_factors", "misalignments", "biases")


def coverage(seed: int, reps: int, poses: int = 20, **errors) -> dict:
    """Coverage of the total-figure 95 % intervals over `reps` simulated recordings (a new triad
    and new random poses each), per parameter class, with the same for the white-noise figure:
    {"total" | "white": {class: (fraction, standard error)}, "pose_sigma_median": ...}. The
    standard error is that of the mean of the per-recording fractions (the intervals of one
    recording are not independent). errors: `pose_means` options (pose_sd, ar_sd, ...)."""
    import dataclasses

    import station

    rng = np.random.default_rng(seed)
    hits = {"total": {c: [] for c in CLASSES}, "white": {c: [] for c in CLASSES}}
    pose = []
    for _ in range(reps):
        a, b = mpu6050_triad(rng)
        readings, stderr = pose_means(rng, a, b, random_directions(rng, poses), **errors)
        result = station.calibrate(readings, G, bias="estimate", sigma=stderr)
        white = dataclasses.replace(result, scale_factors_sigma=result.scale_factors_sigma_white,
                                    axis_angles_sigma=result.axis_angles_sigma_white,
                                    bias_sigma=result.bias_sigma_white)
        for figure, res in (("total", result), ("white", white)):
            for name, inside in covered(res, a, b).items():
                hits[figure][name].append(inside.mean())
        pose.append(result.pose_sigma)
    out = {figure: {name: (float(np.mean(x)), float(np.std(x, ddof=1) / np.sqrt(reps)))
                    for name, x in per.items()} for figure, per in hits.items()}
    out["pose_sigma_median"] = float(np.median(pose))
    out["pose_sigma_zero_fraction"] = float(np.mean(np.array(pose) == 0))
    return out
