"""`calibrate`: the public entry point. Chooses a closed-form start, refines it by maximum
likelihood, and reports the result with 1-sigma uncertainties of the gauge-invariant quantities.

Methods (station/<module>):
- `pca`           Rupniewski Algorithm 2, unbiased readings (e.g. after the Eq. 18 reduction).
- `ellipsoid`     a triad (m = d) with unknown biases from arbitrary static orientations.
- `factorization` Hwangbo & Kanade, with a constraint list and/or biases estimated jointly (m > d).

When the closed form fails, the next start of station/solve/starts.py is refined instead; the fit
is refused only when its Fisher information leaves a parameter unidentified (a rank test: named,
with the pose that would fix it; station/solve/identifiability.py) or no start explains the
readings; a parameter identified but loosely is named in `weakly_determined`, with its 1-sigma.
With the readings' noise given, the 1-sigma figures include a per-pose error term estimated from
the residuals (the total figure), beside the white-noise figure (docs/solvers.md).
"""

from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError
from station.model import measurement
from station.solve import identifiability, ml, starts, uncertainty

METHODS = ("auto", "pca", "ellipsoid", "factorization")
# RMS misfit of a fit from a fallback start, as a fraction of a sensor's full reading c |a_i|,
# beyond which the readings are declared inconsistent with a constant magnitude: the noise of a
# sensor worth calibrating is far below 1 % of its range; wrong units or a moving unit miss more.
MISFIT_MAX = 0.01
# rounds of (estimate sigma_pose, re-weight, refine) at most; it settles in 2 to 4
POSE_ROUNDS = 8


@dataclass(frozen=True)
class CalibrationResult(measurement.Sensitivity):
    """A calibration: model z = a^T v + b (docs/conventions.md), its uncertainty and its fit.

    Angles are in radians, every sigma is one standard deviation; where the noise level is
    estimated (from the residuals, or the per-pose term), widened by t_nu(0.975) / 1.96 for its
    nu degrees of freedom, so that +-1.96 sigma is a 95 % interval (docs/solvers.md). `a` and `v`
    are expressed in `frame` ("canonical" = Eq. 19 upper-triangular, or "nominal" = aligned to a
    nominal layout).
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
    # which start the maximum likelihood was refined from (station.solve.starts): "closed form",
    # "axis-aligned ellipsoid", "nominal layout" or "principal axes"; None in older results
    start: str | None = "closed form"
    # the per-pose error term (readings' units, each reading of each pose) folded into every sigma
    # above (the total figure): 0 when the white noise explains the residuals; None when sigma
    # was estimated from the residuals (that figure holds all the scatter) or in older results
    pose_sigma: float | None = None
    # the white-noise figure: the same sigmas from the readings' stated noise alone (at the same
    # estimate); None in older results
    a_sigma_white: np.ndarray | None = None
    scale_factors_sigma_white: np.ndarray | None = None
    axis_angles_sigma_white: np.ndarray | None = None
    bias_sigma_white: np.ndarray | None = None
    # parameters the poses identify but only loosely (a 1-sigma beyond 10 % of a scale factor, 6
    # degrees of axis or 0.1 of the stimulus as a bias; station.solve.identifiability.LOOSE), in
    # words ("the scale of g3"); their sigmas above say how loose
    weakly_determined: tuple = ()

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
    names=None,
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
    names       the sensors' names for the messages (default s1 .. sm).

    The closed form is the first start; when it fails, the fallbacks of station.solve.starts are
    refined and the best kept (`start` says which). Refused (CalibrationInputError) when the Fisher
    information at the solution leaves a parameter undetermined (the message names it and the
    pose that would fix it) or when no start explains the readings. With sigma given, every sigma
    of the result is the total figure (white noise plus the per-pose term `pose_sigma`), the
    `*_sigma_white` fields the white-noise figure.
    """
    readings = as_readings(readings)
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
    starts.check_method(method, readings, estimate_bias, d)
    if constraints is not None:
        _check_magnitudes(constraints, n)
    names = [f"s{i + 1}" for i in range(m)] if names is None else [str(x) for x in names]

    def refined(a0, v0, b0, noise, max_iter=100 if refine else 0, fitted=False):
        return ml.refine(
            readings, a0, v0, bias0=b0 if estimate_bias else known_bias,
            estimate_bias=estimate_bias, magnitude=c, sigma=noise, constraints=constraints,
            magnitude_spread=magnitude_spread, max_iter=max_iter, fitted=fitted,
        )

    fit, start, refusal = _best_start(
        lambda a0, v0, b0: refined(a0, v0, b0, sigma),
        lambda: starts.closed_form(method, readings, known_bias, estimate_bias, constraints, c, d),
        lambda name: starts.fallback(name, readings, known_bias, estimate_bias, c, d, nominal),
        refine,
    )
    if refusal is not None:
        _check_consistent(fit, c, refusal)
    weak = identifiability.check_information(
        fit.fisher, fit.a, readings, estimate_bias, c, names,
        noise_known=sigma is not None or fit.dof > 0,
        free=m * n + (n if magnitude_spread else 0) - fit.dof,
        distinct=None if constraints is not None or magnitude_spread else lambda: _distinct(fit),
        context=refusal,
    )
    if sigma is None:
        return calibration_result(fit, fit, None, method, start, refine, c, scale_known,
                                  estimate_bias, nominal, uncertainty.t_widening(fit.dof), weak)
    total, pose_var = with_pose_term(
        fit, lambda f, noise: refined(f.a, f.v, f.bias, noise, fitted=True))
    white = total if pose_var == 0 else refined(total.a, total.v, total.bias, sigma, max_iter=0,
                                                fitted=True)
    widen = uncertainty.estimation_widening(pose_var, fit.sigma, fit.dof)
    return calibration_result(total, white, float(np.sqrt(pose_var)), method, start, refine, c,
                              scale_known, estimate_bias, nominal, widen, weak)


def _distinct(fit: ml.MLFit) -> np.ndarray | None:
    """The information of the fit's distinct poses (repeats merged:
    `identifiability.distinct_directions`, the poses' standard errors those of the scatter the
    residuals show, chi2/dof >= 1: hand-placed repeats of a face differ by their seating), None
    when every pose is distinct."""
    scatter = np.sqrt(max(1.0, fit.chi2 / fit.dof)) if fit.dof > 0 else 1.0
    v = identifiability.distinct_directions(fit.a, fit.v, scatter * fit.sigma)
    if v is None:
        return None
    sigma = np.sqrt(np.mean(fit.sigma**2, axis=1))
    return uncertainty.design_information(fit.a, v, fit.bias, sigma)


def with_pose_term(fit: ml.MLFit, refit) -> tuple[ml.MLFit, float]:
    """(the fit weighted by sigma^2 + sigma_pose^2, sigma_pose^2): the per-pose term estimated
    from the residuals (`uncertainty.pose_variance`) and the fit redone (`refit(fit, sigma)`)
    until it settles; (fit, 0) when the white noise explains the residuals."""
    white, total, pose_var = fit.sigma, fit, 0.0
    for _ in range(POSE_ROUNDS):
        prior = np.sqrt(max(total.chi2 - np.sum((total.residuals / total.sigma) ** 2), 0.0))
        new = uncertainty.pose_variance(total.residuals, white, fit.dof, [prior])
        if new == pose_var or abs(new - pose_var) <= 1e-6 * max(new, pose_var):
            break
        pose_var = new
        total = refit(total, np.sqrt(white**2 + pose_var))
    return total, pose_var


def _best_start(refined, closed_form, fallback, refine: bool):
    """(ML fit, name of its start, the closed form's refusal or None): the closed form's fit when
    it converged, or else the lowest-cost fit among it and the fallback starts; the closed form's
    refusal when none works."""
    fits, refusal = {}, None
    try:
        fits["closed form"] = refined(*closed_form())
    except (CalibrationInputError, np.linalg.LinAlgError) as exc:
        refusal = exc if isinstance(exc, CalibrationInputError) else CalibrationInputError(
            f"the closed form failed ({exc}).", "Add poses in new orientations.")
    if fits and (fits["closed form"].converged or not refine):
        return fits["closed form"], "closed form", None
    for candidate in starts.FALLBACKS:
        try:
            fits[candidate] = refined(*fallback(candidate))
        except (CalibrationInputError, np.linalg.LinAlgError):
            continue
    fits = {k: f for k, f in fits.items() if np.isfinite(f.objective)}
    if not fits:
        raise refusal
    name = min(fits, key=lambda k: fits[k].objective)
    return fits[name], name, refusal


def _check_consistent(fit: ml.MLFit, c: float, refusal: CalibrationInputError) -> None:
    """Refuse a fit from a fallback start that misses its readings by more than MISFIT_MAX of
    their range: no calibration explains them (the closed form's refusal says how)."""
    norms = np.linalg.norm(fit.a, axis=0)
    rms = np.sqrt(np.mean(fit.residuals**2, axis=1)) / (c * np.maximum(norms, 1e-6 * norms.max()))
    if rms.max() > MISFIT_MAX:
        raise CalibrationInputError(
            f"no calibration explains the readings: the best fit misses them by {rms.max():.1%} "
            f"of the stimulus (RMS), far more than noise; the closed form said: "
            f"{refusal.problem}",
            refusal.advice)


def as_readings(readings) -> np.ndarray:
    m_ = np.asarray(readings, dtype=float)
    if m_.ndim != 2:
        raise CalibrationInputError(
            f"readings have shape {m_.shape}; expected a 2-D matrix.",
            "Pass the m x n matrix of averaged readings (sensors x positions).",
        )
    if not np.isfinite(m_).all():
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


def calibration_result(total: ml.MLFit, white: ml.MLFit, pose_sigma, method, start, refined, c,
                       scale_known, estimate_bias, nominal, widen: float = 1.0, weak: tuple = (),
                       covariance=None):
    """Rotate into the reporting frame and propagate both covariances to the invariants: `total`
    (the estimate, weighted by the total noise; its covariance times `widen`) and `white` (the
    same estimate, weighted by the readings' stated noise: its residuals, sigma and chi2 are the
    result's). covariance(fit): the gauge-free covariance of theta at a fit, default
    `ml_covariance` (station.solve.iron_faces gives its closed form's)."""
    covariance = covariance or ml_covariance
    if nominal is not None:
        nominal = np.asarray(nominal, float)
        if nominal.shape != total.a.shape:
            raise CalibrationInputError(
                f"nominal layout has shape {nominal.shape}, expected {total.a.shape} (d x m).",
                "Give one nominal axis (column) per sensor.",
            )
    rot = uncertainty.frame_rotation(total.a, nominal)
    honest = _sigmas(total.a, rot, widen * covariance(total), nominal, estimate_bias)
    plain = honest if white is total else _sigmas(white.a, rot, covariance(white), nominal,
                                                  estimate_bias)
    return CalibrationResult(
        a=rot @ total.a,
        bias=total.bias,
        bias_estimated=estimate_bias,
        v=rot @ total.v,
        magnitude=c,
        scale_known=scale_known,
        frame="canonical" if nominal is None else "nominal",
        method=method,
        refined=refined,
        iterations=total.iterations,
        residuals=white.residuals,
        sigma=white.sigma,
        sigma_estimated=white.sigma_estimated,
        chi2=white.chi2,
        dof=white.dof,
        a_sigma=honest["a"],
        scale_factors=np.linalg.norm(total.a, axis=0),
        scale_factors_sigma=honest["scale"],
        axis_angles=uncertainty.axis_angles(total.a),
        axis_angles_sigma=honest["angles"],
        bias_sigma=honest["bias"],
        covariance=honest["theta"],
        parameter_covariance=honest["parameters"],
        start=start,
        pose_sigma=pose_sigma,
        a_sigma_white=plain["a"],
        scale_factors_sigma_white=plain["scale"],
        axis_angles_sigma_white=plain["angles"],
        bias_sigma_white=plain["bias"],
        weakly_determined=tuple(weak),
    )


def ml_covariance(fit: ml.MLFit) -> np.ndarray:
    """The gauge-free covariance of theta from the Fisher information of `fit`."""
    return uncertainty.normal_covariance(fit.normal, fit.a, lambda: fit.fisher)


def _sigmas(a: np.ndarray, rot: np.ndarray, cov: np.ndarray, nominal, estimate_bias: bool) -> dict:
    """Covariances (theta, parameters in the frame) and 1-sigma of a, the scale factors, the axis
    angles and the biases, from the gauge-free covariance `cov` of theta at `a` (rot: its
    rotation into the frame): each figure from the blocks of the covariance it depends on,
    O((m p)^2) memory."""
    d, m = a.shape
    parameter_cov = uncertainty.in_parameter_order(
        uncertainty.frame_covariance(cov, a, nominal, rot), m)
    sd = np.sqrt(np.maximum(np.diag(parameter_cov), 0.0))
    scale, angles = uncertainty.axis_sigmas(cov, a)
    return {"theta": cov, "parameters": parameter_cov, "a": sd[: d * m].reshape(d, m),
            "scale": scale, "angles": angles, "bias": sd[d * m:] if estimate_bias else None}
