"""Simulated thermal calibrations for tests/test_temperature_model.py and bench/temperature.py.

An accelerometer triad (station.sim.layouts.accelerometer_triad: 100 ug/sqrt(Hz) at 200 Hz) soaked
at SOAKS (4 setpoints over -40 .. 85 degC), 20 free-static poses of 2 s per soak, with datasheet-
sized tempcos (TRUE_LINEAR: biases 0.2-0.3 mg/K, scale factors 50-200 ppm/K; TRUE_QUADRATIC adds
a curvature of 0.1 ug/K^2 and 0.1 ppm/K^2). The effect's t_ref is the soaks' middle, the model's
T_ref, so the true coefficients are the model's.
"""

import numpy as np

from station.model.earth import normal_gravity
from station.model.effects.temperature import Temperature
from station.model.temperature import Soak
from station.reduce.eq18 import reduce_arrays
from station.reduce.rotary import pooled_static_bias
from station.sim.layouts import accelerometer_triad, gyro_array
from station.sim.rotary import simulate_rotary
from station.sim.thermal import simulate_soaks, soak_recordings, unit_at
from station.solve.calibrate import calibrate
from station.solve.temperature import fit_temperature

G = normal_gravity(52.2)
SOAKS = (233.15, 273.15, 318.15, 358.15)
T_REF = 0.5 * (SOAKS[0] + SOAKS[-1])
GYRO_SOAKS = (263.15, 283.15, 313.15, 333.15)
GYRO_TRUTH = Temperature(bias=2e-5, scale=(1e-4, -5e-5) * 6, t_ref=0.5 * (263.15 + 333.15))
"""A 12-gyro unit (station.sim.layouts.gyro_array): 20 ndeg/s/K ... 1 mdeg/s/K biases (2e-5
rad/s/K), 50-100 ppm/K scale factors."""
BETWEEN = (243.15, 258.15, 288.15, 303.15, 333.15, 348.15)
"""Six temperatures inside the range, none a soak's."""
TRUE_LINEAR = Temperature(bias=(2e-3, -3e-3, 2.5e-3), scale=(1e-4, -5e-5, 2e-4), t_ref=T_REF)
TRUE_QUADRATIC = Temperature(bias=TRUE_LINEAR.bias, scale=TRUE_LINEAR.scale,
                             bias2=(1e-6, -1e-6, 1e-6), scale2=(1e-7, 1e-7, -1e-7), t_ref=T_REF)


def thermal_fit(seed: int, truth: Temperature = TRUE_LINEAR, orders=None):
    """(the unit, its TemperatureFit) of one simulated 4-soak set."""
    unit = accelerometer_triad(np.random.default_rng(seed))
    return unit, fit_temperature(simulate_soaks(unit, SOAKS, truth), G, orders=orders)


def rotary_fit(seed: int, truth: Temperature = GYRO_TRUTH, positions: int = 20, timing=None,
               fs: float = 200.0):
    """The linear TemperatureFit of a 12-gyro unit's rotary sessions (`positions` each, default
    RotaryTiming, `fs` Hz) at GYRO_SOAKS, each through the Eq. 18 reduction with its biases from
    the static windows (`pooled_static_bias`), as `station solve` gets them."""
    unit = gyro_array(np.random.default_rng(seed), fs=fs)
    sims = soak_recordings(unit, GYRO_SOAKS, truth,
                           lambda u: simulate_rotary(u, positions, timing))
    reduced = [reduce_arrays(sim.arrays) for sim in sims]
    soaks = [Soak(temp, r.M, r.sigma, bias=b["bias"], bias_sigma=b["bias_sigma"])
             for temp, r, b in zip(GYRO_SOAKS, reduced, pooled_static_bias(reduced), strict=True)]
    return fit_temperature(soaks, float(sims[0].arrays["c_cmd"]),
                           orders={"bias": 1, "scale": 1})


def z_scores(fit, truth: Temperature) -> tuple:
    """((m,) bias, (m,) scale) (estimate - truth) / sigma of a fit's linear tempcos."""
    model = fit.model
    return ((model.bias[:, 0] - truth.bias) / model.bias_sigma[:, 0],
            (model.scale[:, 0] - truth.scale) / model.scale_sigma[:, 0])


def probe(unit, temperature: float, truth: Temperature, rng, n: int = 500,
          magnitude: float = G):
    """(noise-free readings (m, n) of `unit` at `temperature`, true stimuli (3, n) of
    `magnitude`: specific forces of |g| by default, or rates of a gyro unit)."""
    at = unit_at(unit, temperature, True, truth)
    u = rng.standard_normal((3, n))
    v = magnitude * u / np.linalg.norm(u, axis=0)
    return at.a.T @ v + at.bias[:, None], v


def magnitude_errors(v, magnitude: float = G) -> np.ndarray:
    """|v_j| - magnitude (default g) of calibrated vectors (3, n)."""
    return np.linalg.norm(v, axis=0) - magnitude


def direct_calibration(unit, temperature: float, truth: Temperature):
    """A calibration made at that very temperature (one soak, the same poses and noise)."""
    (soak,) = simulate_soaks(unit, [temperature], truth)
    return calibrate(soak.readings, G, d=3, bias="estimate", sigma=soak.sigma)
