"""Sensor layouts and stimuli shared by the tests (truth generators, not code under test)."""

import numpy as np

# Rupniewski Section IV: four gyro triads (Fig. 1)
A_MODEL = np.array(
    [
        [1, 0, 0, 0, 1, 0, 0, -1, 0, 1, 0, 0],
        [0, 1, 0, -1, 0, 0, 1, 0, 0, 0, 0, -1],
        [0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 1, 0],
    ],
    dtype=float,
)


def random_directions(rng, d: int, n: int, magnitude: float = 1.0) -> np.ndarray:
    """n directions uniform on the sphere of radius `magnitude` in R^d, (d, n)."""
    v = rng.standard_normal((d, n))
    return magnitude * v / np.linalg.norm(v, axis=0)


def section4_gyros(rng, n: int, sigma: float):
    """Truth a (a_model + N(0, 0.01^2)), directions v and noisy readings M, as in Section IV."""
    a = A_MODEL + 0.01 * rng.standard_normal(A_MODEL.shape)
    v = random_directions(rng, 3, n)
    return a, v, a.T @ v + sigma * rng.standard_normal((12, n))
