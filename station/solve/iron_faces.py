"""Positions of one mounting of a right-angle iron, each along a face: the maximum likelihood in
closed form (the six faces of a Ferraris recording, its three turns; `calibrate_faces`).

When every position lies along a face of one mounting, the constraints of Eq. 15 (Hwangbo &
Kanade) fix all their inner products: the stimuli are v_j = c R e_j, e_j the unit vector of face j
in the iron's frame and R one unknown rotation. R is the rotation gauge of Remark 1 (Rupniewski:
a^T R e = (R^T a)^T e), so the maximum likelihood of z_ij = a_i . v_j + b_i + noise is weighted
linear least squares, one sensor at a time, with no iteration:

    theta_i = (a_i, b_i) = F_i^-1 X^T W_i z_i,   F_i = X^T W_i X,   X = [c E^T, 1]   (n x p)

W_i the weights 1 / sigma_ij^2 (the factorization of Eq. 15 with the poses known). Six faces with
equal weights: F_i = diag(2 c^2, 2 c^2, 2 c^2, 6) w, so b_i is the mean of the six readings and
a_i's component k is (z_i(+k) - z_i(-k)) / (2 c).

Covariance: F = blockdiag(F_i) is the information at fixed poses; the pose rotation moves theta
along the gauge directions G (J_R = J_theta G), so eliminating it leaves S = F - F G (G^T F G)^-1
G^T F, whose pseudo-inverse is Q F^-1 Q, Q = I - G (G^T G)^-1 G^T the projector off the gauge
(S G = 0 and G^T Q = 0 give S (Q F^-1 Q) S = S, (Q F^-1 Q) S (Q F^-1 Q) = Q F^-1 Q, both
products symmetric): the gauge-free covariance that `station.calibrate` computes by the Schur
complement and a pseudo-inverse.

Identifiability without an eigen-decomposition: in natural units (D, `identifiability.
natural_scale`) the largest eigenvalue of that covariance is at most trace(D^-1 F^-1 D^-1) (Q
only shrinks a trace) and the largest information at most trace(D F D) (S <= F): when
trace(D^-1 F^-1 D^-1) max(INFO_TOL trace(D F D), 1 / LOOSE^2) < 1, no parameter is undetermined or
loose (`identifiability.check_information` would find none). Residuals beyond MISFIT_MAX of a
sensor's full reading (a wrong face label misses by about a third of it) are what the general path
refuses or refits from other starts: there, when asked (`general=True`), or for any other design,
`station.calibrate` solves the readings and says what it finds.
"""

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from station.model.frames import align_to
from station.solve import identifiability, ml, uncertainty
from station.solve.calibrate import (
    MISFIT_MAX,
    CalibrationResult,
    as_readings,
    calibrate,
    calibration_result,
    with_pose_term,
)
from station.solve.constraints import FACES, face_directions, from_faces


@dataclass(frozen=True)
class LinearFit:
    """A fit of one mounting's faces: the fields of `station.solve.ml.MLFit` that
    `calibration_result` and `with_pose_term` read, and the information blocks F_i (m, p, p) at
    fixed poses with their inverses (the weights' units: scaled by 1 / sigma^2 when sigma is
    estimated)."""

    a: np.ndarray
    v: np.ndarray
    bias: np.ndarray | None
    residuals: np.ndarray
    sigma: np.ndarray
    sigma_estimated: bool
    chi2: float
    dof: int
    information: np.ndarray
    inverse: np.ndarray
    iterations: int = 0


@dataclass(frozen=True)
class FacesFit:
    """One mounting's faces solved: the sensitivities in the iron's frame and the biases at once,
    the full `CalibrationResult` (the reporting frame and every uncertainty: three quarters of the
    work) when `result` is first read.

    a : (3, m) sensitivity in the iron's frame (column i = sensor i's axis times its scale).
    bias : (m,) estimated biases, or the given / None of the call.
    """

    a: np.ndarray
    bias: np.ndarray | None
    finish: Callable[[], CalibrationResult] = field(repr=False, compare=False)

    @cached_property
    def result(self) -> CalibrationResult:
        """What `station.calibrate` returns for these readings (`calibrate_faces`)."""
        return self.finish()


def calibrate_faces(readings, faces, magnitude: float | None, *, bias=None, sigma=None,
                    general: bool = False) -> CalibrationResult:
    """`station.calibrate(readings, magnitude, d=3, bias=bias, constraints=from_faces(faces),
    sigma=sigma)` for positions of one mounting (faces[j]: the face, "+x" .. "-z", that position
    j's stimulus points along), in closed form (module notes): the same result, every field to
    rounding, but `iterations` (0) and `covariance`, which each path gives at its own estimate
    of a (the iron's frame here, the iterate's frame there): the same up to a rotation of the
    gauge (equal eigenvalues; every figure in the reporting frame equal). `fit_faces(...).result`.
    """
    return fit_faces(readings, faces, magnitude, bias=bias, sigma=sigma, general=general).result


def fit_faces(readings, faces, magnitude: float | None, *, bias=None, sigma=None,
              general: bool = False) -> FacesFit:
    """The estimate of `calibrate_faces` in the iron's frame at once, its result made when read.

    The closed form covers positions along the faces of one mounting (bias None, or "estimate"
    with every axis on both its faces) whose estimate the weights do not move: equal weights per
    sensor (sigma None, a scalar or one per sensor; a per-pose term keeps them equal) or as many
    positions as unknowns (three turns). Then theta_i = H^T z_i (`_design`), and only a residual
    beyond MISFIT_MAX sends the readings to `station.calibrate` at once (it refits from other
    starts or refuses). A parameter that may be loose (module notes) moves no estimate, only how
    the result tells it: that result is `station.calibrate`'s (the same optimum, the loose
    parameters named), decided when it is made. Any other design, or general=True:
    `station.calibrate` at once, its estimate rotated into the iron's frame.
    """
    # copies: the result is made later, from what the caller gave now
    readings, faces = as_readings(readings).copy(), tuple(faces)
    sigma = None if sigma is None else np.array(sigma, float)
    m, n = readings.shape
    estimate_bias = isinstance(bias, str) and bias == "estimate"
    c = 1.0 if magnitude is None else float(magnitude)

    def general_result() -> CalibrationResult:
        return calibrate(readings, magnitude, d=3, bias=bias, constraints=from_faces(faces),
                         sigma=sigma)

    if not general and _closed_form_fits(faces, n, bias, estimate_bias):
        white = ml.sigma_matrix(sigma, m)
        x, hat = _design(faces, c, estimate_bias)
        if np.ndim(sigma) < 2 or n == x.shape[1]:
            theta = readings @ hat
            if _within_misfit(readings - theta @ x.T, theta[:, :3], c):
                return FacesFit(theta[:, :3].T, theta[:, 3] if estimate_bias else None,
                                functools.partial(_closed_result, readings, x, white,
                                                  sigma is None, c, magnitude is not None,
                                                  estimate_bias, theta, general_result))
    result = general_result()
    iron = align_to(result.v, c * face_directions(faces))
    return FacesFit(iron @ result.a, result.bias, lambda: result)


@functools.lru_cache(maxsize=64)
def _design(faces: tuple[str, ...], c: float, estimate_bias: bool):
    """(X, H), read-only, of one mounting's faces: X = [c E^T, 1] (n, p) (module notes) and
    H = X (X^T X)^-1, so that theta_i = H^T z_i wherever the weights are equal per sensor
    (F_i = w_i X^T X) or X is square (theta_i = X^-1 z_i, whatever the weights)."""
    x = c * face_directions(faces).T
    if estimate_bias:
        x = np.hstack([x, np.ones((len(faces), 1))])
    hat = x @ np.linalg.inv(x.T @ x)
    x.setflags(write=False)
    hat.setflags(write=False)
    return x, hat


def _closed_result(readings, x, white, estimated: bool, c: float, scale_known: bool,
                   estimate_bias: bool, theta: np.ndarray, general) -> CalibrationResult:
    """The `CalibrationResult` at the closed form's estimate theta (m, p) (`fit_faces`; white:
    the readings' stated noise, broadcast to (m, n), or ones when `estimated`): with the
    per-pose term when the noise is given (the estimate stays: the weights stay equal per
    sensor), or `general()` when a parameter may be loose."""

    def fit_with(noise) -> LinearFit:
        return _fit_at(readings, x, 1.0 / noise**2, theta, estimated)

    fit = fit_with(np.broadcast_to(white, readings.shape))
    if not _determined(fit, c, estimate_bias, not estimated or fit.dof > 0):
        return general()
    args = ("factorization", "closed form", True, c, scale_known, estimate_bias, None)
    if estimated:
        return calibration_result(fit, fit, None, *args, uncertainty.t_widening(fit.dof),
                                  covariance=covariance)
    total, pose_var = with_pose_term(fit, lambda f, noise: fit_with(noise))
    widen = uncertainty.estimation_widening(pose_var, fit.sigma, fit.dof)
    return calibration_result(total, fit, float(np.sqrt(pose_var)), *args, widen,
                              covariance=covariance)


def _closed_form_fits(faces, n: int, bias, estimate_bias: bool) -> bool:
    """Whether the closed form solves this design: one face per position, the three axes seen,
    and with biases estimated every axis on both its faces; bias None or "estimate"."""
    seen = set(faces)
    if len(faces) != n or not seen <= set(FACES) or not (bias is None or estimate_bias):
        return False
    return seen == set(FACES) if estimate_bias else {f[1] for f in seen} == set("xyz")


def _fit_at(readings, x, weight, theta, estimated: bool) -> LinearFit:
    """The fit at theta (m, p) with the weights `weight` (m, n): its residuals, chi2 and the
    information blocks (`station.solve.ml.refine` with max_iter=0). estimated: the weights are
    relative, the noise level is estimated from the residuals (as `ml.refine` does without
    sigma: sigma^2 = chi2 / dof, the information rescaled)."""
    m, n = readings.shape
    p = x.shape[1]
    info = np.einsum("in,nk,nl->ikl", weight, x, x)
    inverse = np.linalg.inv(info)
    resid = readings - theta @ x.T
    chi2 = float(np.einsum("in,in,in->", weight, resid, resid))
    dof = m * n - 3 * m - (m if p > 3 else 0)  # the rotation's 3 unknowns are the gauge's 3
    if estimated:
        var = chi2 / max(dof, 1) or 1.0
        sigma = np.full((m, n), np.sqrt(var))
        info, inverse, chi2 = info / var, inverse * var, chi2 / var
    else:
        sigma = 1.0 / np.sqrt(weight)
    bias = theta[:, 3] if p > 3 else None
    return LinearFit(theta[:, :3].T, x[:, :3].T.copy(), bias, resid, sigma, estimated, chi2, dof,
                     info, inverse)


def _within_misfit(residuals: np.ndarray, a: np.ndarray, c: float) -> bool:
    """Whether each sensor's RMS residual (residuals (m, n)) stays within MISFIT_MAX of its full
    reading c |a_i| (a (m, d)); beyond it (a wrong face label, a unit that moved)
    `station.calibrate` decides."""
    limit = (MISFIT_MAX * c) ** 2 * residuals.shape[1] * (a * a).sum(axis=1)
    return bool(((residuals * residuals).sum(axis=1) <= limit).all())  # False for NaN


def _determined(fit: LinearFit, c: float, estimate_bias: bool, noise_known: bool) -> bool:
    """True when no parameter can be undetermined or loose: the trace bounds of the module notes
    against `identifiability.check_information`'s floors (the residuals at the same estimate
    passed `_within_misfit` in `fit_faces`)."""
    m, p, _ = fit.information.shape
    scale = identifiability.natural_scale(fit.a, c, estimate_bias).reshape(m, p) ** 2
    spread = np.einsum("ikk,ik->", fit.inverse, 1.0 / scale)  # trace(D^-1 F^-1 D^-1)
    strength = np.einsum("ikk,ik->", fit.information, scale)  # trace(D F D)
    floor = identifiability.INFO_TOL * strength
    if noise_known:
        floor = max(floor, 1.0 / identifiability.LOOSE**2)
    return bool(spread * floor < 1.0)


def covariance(fit: LinearFit) -> np.ndarray:
    """The gauge-free covariance Q F^-1 Q of theta = (a_1, b_1, ...) (module notes)."""
    m, p, _ = fit.inverse.shape
    dense = np.zeros((m, p, m, p))
    idx = np.arange(m)
    dense[idx, :, idx, :] = fit.inverse
    dense = dense.reshape(m * p, m * p)
    q = np.linalg.qr(identifiability.gauge_directions(fit.a, p))[0]
    moved = q @ (q.T @ dense)
    return dense - moved - moved.T + q @ (q.T @ moved.T)
