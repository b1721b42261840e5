"""The temperature model of a calibration: biases and scale factors as polynomials in T - T_ref.

Written once in docs/conventions.md ("Temperature"). For sensor i at the unit's temperature T (K),
with x = T - T_ref (K):

    b_i(T) = b_i + sum_{p=1..P_b} beta_ip x^p           beta_ip in u/K^p  (u: the readings' unit)
    a_i(T) = a_i (1 + sum_{p=1..P_s} gamma_ip x^p)      gamma_ip in 1/K^p (relative scale factor)

a_i and b_i are the calibration's sensitive vector (column i of a) and bias at T_ref; the axis
directions (the misalignment) do not change with temperature. P_b, P_s in 0..MAX_ORDER are the
orders (0: no dependence). The model is valid on the calibrated range [t_min, t_max], which holds
T_ref (the middle of the soaks' range). Pure math: no files, no fitting (station.solve.temperature).
"""

from dataclasses import dataclass

import numpy as np

from station.errors import InputError
from station.model import measurement

MAX_ORDER = 2
KELVIN_MIN = 150.0
"""Temperatures below this many kelvin are refused as a likely degC value (-123 degC is colder
than any inertial sensor is specified for)."""
KELVIN_MAX = 600.0
"""Temperatures above this many kelvin are refused as implausible for an IMU (327 degC)."""


@dataclass(frozen=True)
class Soak:
    """One soak: the unit's mean temperature (K) and its averaged readings.

    readings, sigma : (m, n) averaged readings and their standard errors, as the still-pose or
                      rotary solvers take them (station.reduce.still.StillReadings.M / .sigma,
                      Eq. 18 rotary readings)
    bias, bias_sigma: None (still poses: the biases are estimated with the calibration), or (m,)
                      biases measured apart with their 1-sigma (a rotary soak: its static
                      windows; its Eq. 18 readings are bias-free)
    constraints     : the poses' inner-product constraints (station.solve.constraints, e.g. an
                      iron's faces: `IronReadings.constraints()`), None for free poses
    """

    temperature: float
    readings: np.ndarray
    sigma: np.ndarray
    bias: np.ndarray | None = None
    bias_sigma: np.ndarray | None = None
    constraints: object = None


@dataclass(frozen=True, eq=False)
class TemperatureModel:
    """Temperature dependence of m sensors (module docstring).

    t_ref, t_min, t_max : K; t_min <= t_ref <= t_max, the calibrated range
    bias   : (m, P_b) beta_ip, u/K^p (column p-1 holds degree p)
    scale  : (m, P_s) gamma_ip, 1/K^p
    covariance : (m P_b + m P_s,) square covariance of (bias row-major, then scale row-major)
    """

    t_ref: float
    t_min: float
    t_max: float
    bias: np.ndarray
    scale: np.ndarray
    covariance: np.ndarray

    @property
    def orders(self) -> dict:
        """{"bias": P_b, "scale": P_s}."""
        return {"bias": self.bias.shape[1], "scale": self.scale.shape[1]}

    @property
    def bias_sigma(self) -> np.ndarray:
        """(m, P_b) 1-sigma of the bias coefficients."""
        return self._sigma()[: self.bias.size].reshape(self.bias.shape)

    @property
    def scale_sigma(self) -> np.ndarray:
        """(m, P_s) 1-sigma of the scale coefficients."""
        return self._sigma()[self.bias.size:].reshape(self.scale.shape)

    def _sigma(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))

    def bias_offset(self, temperature) -> np.ndarray:
        """(k, m) b(T) - b(T_ref) at the temperatures (k,) (or a scalar: (1, m))."""
        return powers(self.x(temperature), self.bias.shape[1]) @ self.bias.T

    def scale_ratio(self, temperature) -> np.ndarray:
        """(k, m) |a_i(T)| / |a_i(T_ref)| at the temperatures (k,) (or a scalar: (1, m))."""
        return 1.0 + powers(self.x(temperature), self.scale.shape[1]) @ self.scale.T

    def x(self, temperature) -> np.ndarray:
        """(k,) T - T_ref of kelvin temperatures (checked: `check_kelvin`)."""
        return check_kelvin(temperature) - self.t_ref

    def outside(self, temperature) -> np.ndarray:
        """(k,) True where a temperature lies outside [t_min, t_max]."""
        t = check_kelvin(temperature)
        return (t < self.t_min) | (t > self.t_max)

    def fuse(self, a, b, z, temperature) -> np.ndarray:
        """(d, k) calibrated vectors of readings z (m, k) taken at the temperatures (k,) (or one
        scalar for all): v = (a(T) a(T)^T)^-1 a(T) (z - b(T)) per instant, a and b the
        calibration at T_ref (docs/conventions.md)."""
        z = np.asarray(z, float)
        t = check_kelvin(temperature)
        t = np.broadcast_to(t, (z.shape[1],)) if t.size == 1 else t
        if t.shape != (z.shape[1],):
            raise InputError(f"{t.size} temperatures for {z.shape[1]} instants; give one "
                             "temperature per instant or one for all")
        a_t = np.asarray(a, float)[None] * self.scale_ratio(t)[:, None, :]  # (k, d, m)
        r = z.T - np.asarray(b, float) - self.bias_offset(t)  # (k, m)
        rhs = np.einsum("kdm,km->kd", a_t, r)[..., None]
        return np.linalg.solve(a_t @ np.swapaxes(a_t, 1, 2), rhs)[..., 0].T

    def vector_covariance(self, a, b, covariance, z, temperature) -> np.ndarray:
        """(k, d, d) covariance of the calibrated vectors `fuse` gives for readings z (m, k) at
        the temperatures (k,) (or one for all), due to the calibration's own uncertainty: the
        covariance of (a row-major, b) at t_ref (`covariance`) and the model's, taken as
        independent (the file holds no cross terms), by first-order propagation through
        station.model.measurement.fusion_jacobian at a(T), b(T). The readings' noise is not
        included."""
        z = np.asarray(z, float)
        t = np.broadcast_to(check_kelvin(temperature), (z.shape[1],))
        a = np.asarray(a, float)
        d, m = a.shape
        out = np.empty((z.shape[1], d, d))
        for temp in np.unique(t):  # one Jacobian per distinct temperature
            at = t == temp
            ratio, xp = self.scale_ratio(temp)[0], powers(temp - self.t_ref, MAX_ORDER)[0]
            jac = measurement.fusion_jacobian(a * ratio, z[:, at], b + self.bias_offset(temp)[0])
            jac_a = jac[:, :, : d * m].reshape(-1, d, d, m)
            jac_b = jac[:, :, d * m:]
            ref = np.concatenate([(jac_a * ratio).reshape(-1, d, d * m), jac_b], axis=2)
            turn = np.einsum("kdri,ri->kdi", jac_a, a)  # d v / d ratio_i
            coef = np.concatenate([(jac_b[..., None] * xp[: self.bias.shape[1]]).reshape(
                -1, d, self.bias.size), (turn[..., None] * xp[: self.scale.shape[1]]).reshape(
                -1, d, self.scale.size)], axis=2)
            out[at] = np.einsum("kpi,ij,kqj->kpq", ref, covariance, ref) + \
                np.einsum("kpi,ij,kqj->kpq", coef, self.covariance, coef)
        return out


def powers(x, order: int) -> np.ndarray:
    """(k, order) columns x, x^2, ..., x^order of x (k,)."""
    x = np.atleast_1d(np.asarray(x, float))
    return x[:, None] ** np.arange(1, order + 1)


def check_kelvin(temperature, what: str = "temperature") -> np.ndarray:
    """(k,) float kelvin temperatures, refused (InputError) when not finite, below KELVIN_MIN
    (likely degC) or above KELVIN_MAX."""
    t = np.atleast_1d(np.asarray(temperature, float))
    if t.ndim != 1:
        raise InputError(f"{what} has shape {t.shape}; give one value per instant")
    if not np.all(np.isfinite(t)):
        raise InputError(f"{what} holds non-finite values (row {int(np.argmin(np.isfinite(t)))}"
                         " is the first); drop or repair those samples")
    if t.size and t.min() < KELVIN_MIN:
        raise InputError(f"{what} {t.min():g} K is below {KELVIN_MIN:g} K: it looks like degC; "
                         "give kelvin (degC + 273.15)")
    if t.size and t.max() > KELVIN_MAX:
        raise InputError(f"{what} {t.max():g} K is above {KELVIN_MAX:g} K, beyond any IMU; give "
                         "the unit's temperature in kelvin")
    return t
