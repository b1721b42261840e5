"""Effect `temperature`: biases and scale factors that move with the unit's temperature.

Parameters
----------
bias : scalar or (m,), output units per K
    Linear bias tempco.
bias2 : scalar or (m,), output units per K^2
    Quadratic bias tempco.
scale : scalar or (m,), 1/K
    Linear relative scale-factor tempco.
scale2 : scalar or (m,), 1/K^2
    Quadratic relative scale-factor tempco.
t_ref : float, K
    Temperature at which the unit's own a and b hold.
hysteresis : scalar or (m,), output units
    Bias difference between a temperature reached by heating and the same one reached by
    cooling: +hysteresis/2 after heating, -hysteresis/2 after cooling.

Distortion at temperature T, x = T - t_ref: column i of a times 1 + scale_i x + scale2_i x^2, and
bias_i + bias_i' x + bias2_i x^2 +- hysteresis_i / 2 (the model of station.model.temperature, plus
the hysteresis it does not hold). Simulated per soak by station.sim.thermal.
"""

from dataclasses import dataclass

import numpy as np

from station.model.temperature import check_kelvin


@dataclass(frozen=True)
class Temperature:
    """Temperature coefficients of the biases and scale factors; see the module docstring."""

    bias: float | tuple = 0.0
    bias2: float | tuple = 0.0
    scale: float | tuple = 0.0
    scale2: float | tuple = 0.0
    t_ref: float = 298.15
    hysteresis: float | tuple = 0.0

    def __post_init__(self):
        check_kelvin(self.t_ref, "temperature effect t_ref")


def apply(temperature: float, heating: bool, p: Temperature) -> tuple:
    """((m,) or scalar scale-factor ratio, (m,) or scalar bias offset) at `temperature` (K),
    reached by heating (True) or by cooling (False)."""
    x = float(check_kelvin(temperature)[0]) - p.t_ref
    ratio = 1.0 + np.asarray(p.scale) * x + np.asarray(p.scale2) * x**2
    offset = bias_offsets(x, p) + (0.5 if heating else -0.5) * np.asarray(p.hysteresis)
    return ratio, offset


def bias_offsets(x, p: Temperature) -> np.ndarray:
    """Bias offsets bias_i x + bias2_i x^2 at temperature differences x = T - t_ref (K): a
    scalar x gives (m,) or a scalar, an array x (...) gives (..., m) or (..., 1); no
    hysteresis (it needs the direction of each change)."""
    x = np.asarray(x, float)
    x = x[..., None] if x.ndim else x
    return np.asarray(p.bias) * x + np.asarray(p.bias2) * x**2
