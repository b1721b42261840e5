"""`calibrate`: the public entry point. Chooses a closed-form start, refines it by maximum
likelihood, and reports the result with 1-sigma uncertainties of the gauge-invariant quantities.

Methods (station/<module>):
- `pca`           Rupniewski Algorithm 2, unbiased readings (e.g. after the Eq. 18 reduction).
- `ellipsoid`     a triad (m = d) with unknown biases from arbitrary static orientations.
- `factorization` Hwangbo & Kanade, with a constraint list and/or biases estimated jointly (m > d).
"""

from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError
from station.model import measurement
from station.model.frames import align_to, canonical_rotation
from station.solve import ml, uncertainty

METHODS = ("auto", "pca", "ellipsoid", "factorization")


@dataclass(frozen=True)
class CalibrationResult(measurement.Sensitivity):
    """A calibration: model z = a^T v + b (docs/conventions.md), its uncertainty and its fit.

    Angles are in radians, every sigma is one standard deviation. `a` and `v` are expressed in
    `frame` ("canonical" = Eq. 19 upper-triangular, or "nominal" = aligned to a nominal layout).
    """

    a: np.ndarray  # (d, m)
    bias: np.ndarray | None  # (m,) estimated or given; None when the readings were unbiased
    bias_estimated: bool
    v: np.ndarray  # (d, n)
    magnitude: float
    scale_known: bool  # False: magnitude unknown, scale factors share one unknown factor (Remark 2)
    frame: str
    method: str
    refined: bool
    iterations: int
    residuals: np.ndarray  # (m, n) readings - model
    sigma: np.ndarray  # (m, n) noise level used (estimated when sigma_estimated)
    sigma_estimated: bool
    chi2: float
    dof: int
    a_sigma: np.ndarray  # (d, m) in `frame`
    scale_factors: np.ndarray  # (m,) |a_i|
    scale_factors_sigma: np.ndarray
    axis_angles: np.ndarray  # (m, m) angle between axes i and k
    axis_angles_sigma: np.ndarray
    bias_sigma: np.ndarray | None
    covariance: np.ndarray  # (m p, m p) of theta = (a_1, b_1, a_2, ...), gauge-free pseudo-inverse
    # (d m + m or d m) covariance of (vec(a) row-major in `frame`, then b when estimated): the
    # gauge removed by the frame; None in results stored before it existed
    parameter_covariance: np.ndarray | None = None

    @property
    def normalised_residuals(self) -> np.ndarray:
        """Residuals in units of their noise level: about N(0, 1) when the model explains the
        data."""
        return self.residuals / self.sigma

    def apply(self, z) -> np.ndarray:
        """Calibrated vectors (d,) or (d, k) from readings z (m,) or (m, k):
        v = (a a^T)^-1 a (z - b) (station.model.measurement.fuse)."""
        return measurement.fuse(self.a, z, self.bias)


def calibrate(
    readings,
    magnitude: float | None = None,
    *,
    d: int = 3,
    bias=None,
    constraints=None,
    method: str = "auto",
    refine: bool = True,
    sigma=None,
    nominal=None,
    magnitude_spread: float | None = None,
) -> CalibrationResult:
    """Calibrate m sensors from readings M (m x n) of a stimulus of magnitude `magnitude`.

    bias        None: readings are unbiased (e.g. rotating minus static mean, Eq. 18);
                array (m,): known biases, subtracted; "estimate": estimated with the calibration.
    constraints inner-product constraints between positions (station.solve.constraints), for the
                factorization of Hwangbo & Kanade; default: equal magnitudes only.
    method      "auto" (from the inputs), "pca", "ellipsoid" or "factorization".
    refine      maximum-likelihood refinement of the closed form (recommended).
    sigma       noise standard deviation of the readings: scalar, (m,) or (m, n); estimated if None.
    nominal     nominal layout (d x m): report a in the frame aligned to it instead of Eq. (19)'s.
    magnitude   |v_j|; None means unknown: c = 1, scale factors up to a common factor (Remark 2).
    magnitude_spread
                s > 0: |v_j| is not exactly c but c (1 + delta_j), delta_j ~ N(0, s^2) independent
                per position (a random effect, e.g. a rotary table whose rate scatters from run to
                run; the common part stays in c). The refinement then fits each v_j as a free
                vector with that prior (docs/conventions.md, "Magnitude"), and the uncertainties
                include the spread. Needs sigma and no constraints; None or 0: |v_j| = c exactly.
    """
    readings = _as_readings(readings)
    m, n = readings.shape
    scale_known = magnitude is not None
    c = float(magnitude) if scale_known else 1.0
    if not (np.isfinite(c) and c > 0):
        raise CalibrationInputError(f"magnitude {magnitude!r} is not positive.",
                                    "Give |v| in SI units.")
    estimate_bias = isinstance(bias, str)
    if estimate_bias and bias != "estimate":
        raise CalibrationInputError(f"bias={bias!r} is not understood.",
                                    'Use None, an array or "estimate".')
    known_bias = None if bias is None or estimate_bias else _as_bias(bias, m)
    method = _choose_method(method, m, d, estimate_bias, constraints)
    if constraints is not None:
        _check_magnitudes(constraints, n)

    a0, v0, b0 = _closed_form(method, readings, known_bias, estimate_bias, constraints, c, d)
    start_bias = b0 if estimate_bias else known_bias
    fit = ml.refine(
        readings, a0, v0, bias0=start_bias, estimate_bias=estimate_bias, magnitude=c,
        sigma=sigma, constraints=constraints, magnitude_spread=magnitude_spread,
        max_iter=100 if refine else 0,
    )
    return _result(fit, method, refine, c, scale_known, estimate_bias, nominal)


def _as_readings(readings) -> np.ndarray:
    m_ = np.asarray(readings, dtype=float)
    if m_.ndim != 2:
        raise CalibrationInputError(
            f"readings have shape {m_.shape}; expected a 2-D matrix.",
            "Pass the m x n matrix of averaged readings (sensors x positions).",
        )
    if not np.all(np.isfinite(m_)):
        raise CalibrationInputError(
            "readings contain NaN or infinite values.",
            "Drop or redo the positions with invalid data.",
        )
    return m_


def _as_bias(bias, m: int) -> np.ndarray:
    b = np.asarray(bias, dtype=float).ravel()
    if b.shape != (m,):
        raise CalibrationInputError(f"{b.size} biases given for {m} sensors.",
                                    "Give one bias per sensor.")
    return b


def _choose_method(method: str, m: int, d: int, estimate_bias: bool, constraints) -> str:
    """The closed form that fits the inputs: constraints or joint biases -> factorization, etc."""
    if method not in METHODS:
        raise CalibrationInputError(f"unknown method {method!r}.",
                                    f"Choose one of {', '.join(METHODS)}.")
    if method != "auto":
        return method
    if constraints is not None:
        return "factorization"
    if estimate_bias:
        return "ellipsoid" if m == d else "factorization"
    return "pca"


def _check_magnitudes(constraints, n: int) -> None:
    """The likelihood model needs |v_j| = c at every position: a unit magnitude constraint each."""
    unit = np.zeros(n, bool)
    own = (constraints.j == constraints.k) & (constraints.j < n)
    unit[constraints.j[own & np.isclose(constraints.h, 1.0)]] = True
    if not unit.all():
        raise CalibrationInputError(
            f"{int(np.sum(~unit))} position(s) have no magnitude constraint |v_j| = c, which the "
            "maximum-likelihood refinement and the uncertainties need.",
            "Add magnitude constraints (station.solve.constraints.magnitude_constraints), or call "
            "station.solve.factorization.factorize directly for orthogonality-only constraints "
            "(Eq. 30).",
        )


def _closed_form(method, readings, known_bias, estimate_bias, constraints, c, d):
    """Start values (a, v, b) from the chosen closed-form method."""
    if method == "pca":
        from station.solve.pca import pca_calibration

        if estimate_bias:
            raise CalibrationInputError(
                "the PCA closed form needs unbiased readings.",
                "Subtract the static means first (Eq. 18), "
                'or use method="ellipsoid"/"factorization".',
            )
        z = readings if known_bias is None else readings - known_bias[:, None]
        a, v = pca_calibration(z, c, d)
        return a, v, None
    if method == "ellipsoid":
        from station.solve.ellipsoid import ellipsoid_calibration

        if readings.shape[0] != d:
            raise CalibrationInputError(
                f"the ellipsoid fit is for a triad (m = d = {d}), not m = {readings.shape[0]}.",
                'Use method="factorization" for redundant sensors.',
            )
        a, v, b = ellipsoid_calibration(readings, c)
        return a, v, b
    from station.solve.factorization import factorize

    m = readings.shape[0]
    if estimate_bias:  # jointly (p = d + 1) when m > d, else from opposite pairs (Eq. 14)
        fact = factorize(readings, constraints, magnitude=c, d=d, estimate_bias=m > d or None)
    else:  # readings unbiased, or biases known
        given = np.zeros(m) if known_bias is None else known_bias
        fact = factorize(readings, constraints, magnitude=c, d=d, bias=given, estimate_bias=False)
    return fact.a, fact.v, fact.bias


def _result(fit: ml.MLFit, method, refined, c, scale_known, estimate_bias, nominal):
    """Rotate into the reporting frame and propagate the covariance to the invariants."""
    d, m = fit.a.shape
    p = d + (1 if estimate_bias else 0)
    cov = uncertainty.global_covariance(fit.normal, d)

    if nominal is None:
        frame_name = "canonical"
        rot = canonical_rotation(fit.a)

        def frame_fn(x):
            return canonical_rotation(x) @ x
    else:
        nominal = np.asarray(nominal, float)
        if nominal.shape != fit.a.shape:
            raise CalibrationInputError(
                f"nominal layout has shape {nominal.shape}, expected {fit.a.shape} (d x m).",
                "Give one nominal axis (column) per sensor.",
            )
        frame_name = "nominal"
        rot = align_to(fit.a, nominal)

        def frame_fn(x):
            return align_to(x, nominal) @ x
    jac = uncertainty.frame_jacobian(fit.a, p, frame_fn)
    if estimate_bias:
        jac = np.vstack([jac, uncertainty.bias_jacobian(m, p)])
    parameter_cov = uncertainty.propagate(cov, jac)
    a_var = np.diag(parameter_cov)[: d * m]

    scale_sigma = np.sqrt(np.diag(
        uncertainty.propagate(cov, uncertainty.scale_factor_jacobian(fit.a, p))))
    (i, k), jac = uncertainty.axis_angle_jacobian(fit.a, p)
    angle_sigma = np.zeros((m, m))
    angle_sigma[i, k] = angle_sigma[k, i] = np.sqrt(np.diag(uncertainty.propagate(cov, jac)))
    bias_sigma = np.sqrt(np.diag(parameter_cov)[d * m:]) if estimate_bias else None

    return CalibrationResult(
        a=rot @ fit.a,
        bias=fit.bias,
        bias_estimated=estimate_bias,
        v=rot @ fit.v,
        magnitude=c,
        scale_known=scale_known,
        frame=frame_name,
        method=method,
        refined=refined,
        iterations=fit.iterations,
        residuals=fit.residuals,
        sigma=fit.sigma,
        sigma_estimated=fit.sigma_estimated,
        chi2=fit.chi2,
        dof=fit.dof,
        a_sigma=np.sqrt(np.maximum(a_var, 0)).reshape(d, m),
        scale_factors=np.linalg.norm(fit.a, axis=0),
        scale_factors_sigma=scale_sigma,
        axis_angles=uncertainty.axis_angles(fit.a),
        axis_angles_sigma=angle_sigma,
        bias_sigma=bias_sigma,
        covariance=cov,
        parameter_covariance=parameter_cov,
    )
