"""Sensor layouts used by the simulator's defaults (nominal sensitivity matrices, d x m)."""

import numpy as np

A_MODEL = np.array([
    [1, 0, 0, 0, 1, 0, 0, -1, 0, 1, 0, 0],
    [0, 1, 0, -1, 0, 0, 1, 0, 0, 0, 0, -1],
    [0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 1, 0],
], dtype=float)
"""Four gyro triads of Rupniewski, Section IV (paper 001, a_model)."""

TRIAD = np.eye(3)
"""One orthogonal triad."""


def perturbed(a_nominal: np.ndarray, sd: float, rng: np.random.Generator) -> np.ndarray:
    """A true layout: a_nominal plus N(0, sd^2) on every entry (as in Section IV, sd = 0.01)."""
    a = np.asarray(a_nominal, float)
    return a + sd * rng.standard_normal(a.shape)
