"""Nominal sensor layouts (d x m) and the default simulated units built on them."""

import numpy as np

from station.model.constants import STANDARD_GRAVITY
from station.model.unit import SensorUnit

A_MODEL = np.array(
    [
        [1, 0, 0, 0, 1, 0, 0, -1, 0, 1, 0, 0],
        [0, 1, 0, -1, 0, 0, 1, 0, 0, 0, 0, -1],
        [0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 1, 0],
    ],
    dtype=float,
)
"""Four gyro triads of Rupniewski, Section IV (paper 001, a_model)."""

TRIAD = np.eye(3)
"""One orthogonal triad."""


def perturbed(a_nominal: np.ndarray, sd: float, rng: np.random.Generator) -> np.ndarray:
    """A true layout: a_nominal plus N(0, sd^2) on every entry (as in Section IV, sd = 0.01)."""
    a = np.asarray(a_nominal, float)
    return a + sd * rng.standard_normal(a.shape)


GYRO_TOLERANCES = {"scale_factor": 0.05, "bias": 0.03, "axis_angle_deg": 3.0}
"""The limits of the simulated MEMS gyro type (`gyro_array`: scale factors and axes within 1 % sd
of nominal, biases of 0.005 rad/s sd), as a datasheet would state them: a bench profile's
`[tolerances]` table (station.solve.verdict), which the demo and the twins' profiles judge by."""
ACCELEROMETER_TOLERANCES = {"scale_factor": 0.05, "bias": 0.3, "axis_angle_deg": 3.0}
"""The limits of the simulated MEMS accelerometer type (`accelerometer_triad`: scale factors and
axes within 1 % sd of nominal, biases of 0.05 m/s^2 sd), as `GYRO_TOLERANCES`."""


def gyro_array(rng: np.random.Generator, a_nominal=A_MODEL, fs: float = 200.0, **kwargs):
    """A MEMS-grade gyro unit on `a_nominal` (rad/s): 0.01 deg/s/sqrt(Hz) noise, biases of
    0.005 rad/s, 16.4 counts per deg/s, +-2000 deg/s range; keyword arguments override."""
    m = np.shape(a_nominal)[1]
    params = {
        "bias": 0.005 * rng.standard_normal(m),
        "noise_density": np.radians(0.01),
        "counts_per_unit": 16.4 / np.radians(1.0),
        "output_range": np.radians(2000.0),
    }
    params.update(kwargs)
    return SensorUnit(perturbed(a_nominal, 0.01, rng), fs=fs, rng=rng, **params)


def accelerometer_triad(rng: np.random.Generator, a_nominal=TRIAD, fs: float = 200.0, **kwargs):
    """A MEMS-grade accelerometer unit on `a_nominal` (m/s^2): 100 ug/sqrt(Hz) noise, biases of
    0.05 m/s^2, 4096 counts per g, +-8 g range; keyword arguments override."""
    g0 = STANDARD_GRAVITY
    m = np.shape(a_nominal)[1]
    params = {
        "bias": 0.05 * rng.standard_normal(m),
        "noise_density": 100e-6 * g0,
        "counts_per_unit": 4096 / g0,
        "output_range": 8 * g0,
    }
    params.update(kwargs)
    return SensorUnit(perturbed(a_nominal, 0.01, rng), fs=fs, rng=rng, **params)
