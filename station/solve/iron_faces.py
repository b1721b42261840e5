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

from dataclasses import dataclass

import numpy as np

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


def calibrate_faces(readings, faces, magnitude: float | None, *, bias=None, sigma=None,
                    general: bool = False) -> CalibrationResult:
    """`station.calibrate(readings, magnitude, d=3, bias=bias, constraints=from_faces(faces),
    sigma=sigma)` for positions of one mounting (faces[j]: the face, "+x" .. "-z", that position
    j's stimulus points along), in closed form (module notes): the same result, every field to
    rounding, but `iterations` (0) and `covariance`, which each path gives at its own estimate
    of a (the iron's frame here, the iterate's frame there): the same up to a rotation of the
    gauge (equal eigenvalues; every figure in the reporting frame equal).

    bias None (unbiased readings) or "estimate" (then every axis on both its faces); any other
    design, a parameter that may be loose (module notes), or general=True: `station.calibrate`.
    """
    readings = as_readings(readings)
    m, n = readings.shape
    estimate_bias = isinstance(bias, str) and bias == "estimate"
    if general or not _closed_form_fits(faces, n, bias, estimate_bias):
        return calibrate(readings, magnitude, d=3, bias=bias, constraints=from_faces(faces),
                         sigma=sigma)
    scale_known = magnitude is not None
    c = float(magnitude) if scale_known else 1.0
    x = c * face_directions(faces).T
    if estimate_bias:
        x = np.hstack([x, np.ones((n, 1))])
    white = np.broadcast_to(ml.sigma_matrix(sigma, m), (m, n))
    try:
        fit = _fit_at(readings, x, 1.0 / white**2, None, sigma is None)
    except np.linalg.LinAlgError:
        fit = None
    if fit is None or not _vouched(fit, c, estimate_bias, sigma is not None or fit.dof > 0):
        return calibrate(readings, magnitude, d=3, bias=bias, constraints=from_faces(faces),
                         sigma=sigma)
    args = ("factorization", "closed form", True, c, scale_known, estimate_bias, None)
    if sigma is None:
        return calibration_result(fit, fit, None, *args, uncertainty.t_widening(fit.dof),
                                  covariance=covariance)
    total, pose_var = with_pose_term(
        fit, lambda f, noise: _fit_at(readings, x, 1.0 / noise**2, None, False))
    plain = total if pose_var == 0 else _fit_at(readings, x, 1.0 / white**2, total, False)
    widen = uncertainty.estimation_widening(pose_var, fit.sigma, fit.dof)
    return calibration_result(total, plain, float(np.sqrt(pose_var)), *args, widen,
                              covariance=covariance)


def _closed_form_fits(faces, n: int, bias, estimate_bias: bool) -> bool:
    """Whether `calibrate_faces` solves this design itself: one face per position, the three
    axes seen, and with biases estimated every axis on both its faces; bias None or "estimate"."""
    seen = set(faces)
    if len(faces) != n or not seen <= set(FACES) or not (bias is None or estimate_bias):
        return False
    return seen == set(FACES) if estimate_bias else {f[1] for f in seen} == set("xyz")


def _fit_at(readings, x, weight, at: LinearFit | None, estimated: bool) -> LinearFit:
    """The weighted least-squares fit (module notes) with the weights `weight` (m, n), or the
    estimate of `at` evaluated with them (`station.solve.ml.refine` with max_iter=0). estimated:
    the weights are relative, the noise level is estimated from the residuals (as `ml.refine`
    does without sigma: sigma^2 = chi2 / dof, the information rescaled)."""
    m, n = readings.shape
    p = x.shape[1]
    info = np.einsum("in,nk,nl->ikl", weight, x, x)
    inverse = np.linalg.inv(info)
    if at is None:
        theta = np.einsum("ikl,il->ik", inverse, (weight * readings) @ x)
        a, bias = theta[:, :3].T, theta[:, 3] if p > 3 else None
    else:
        a, bias = at.a, at.bias
    resid = readings - a.T @ x[:, :3].T
    if bias is not None:
        resid -= bias[:, None]
    chi2 = float(np.sum(weight * resid**2))
    dof = m * n - 3 * m - (m if p > 3 else 0)  # the rotation's 3 unknowns are the gauge's 3
    sigma = 1.0 / np.sqrt(weight)
    if estimated:
        scale = np.sqrt(chi2 / max(dof, 1))
        scale = scale if scale > 0 else 1.0
        sigma = np.full((m, n), scale)
        info, inverse, chi2 = info / scale**2, inverse * scale**2, chi2 / scale**2
    return LinearFit(a, x[:, :3].T.copy(), bias, resid, sigma, estimated, chi2, dof, info, inverse)


def _vouched(fit: LinearFit, c: float, estimate_bias: bool, noise_known: bool) -> bool:
    """True when the residuals stay within MISFIT_MAX of each sensor's full reading c |a_i| (RMS;
    beyond it `station.calibrate` decides: a wrong face label, a unit that moved) and no
    parameter can be undetermined or loose: the trace bounds of the module notes against
    `identifiability.check_information`'s floors."""
    m, p, _ = fit.information.shape
    misfit = np.sqrt(np.mean(fit.residuals**2, axis=1)) / (c * np.linalg.norm(fit.a, axis=0))
    if not misfit.max() <= MISFIT_MAX:
        return False
    scale = identifiability.natural_scale(fit.a, c, estimate_bias).reshape(m, p)
    spread = np.einsum("ikk,ik->", fit.inverse, scale**-2.0)  # trace(D^-1 F^-1 D^-1)
    strength = np.einsum("ikk,ik->", fit.information, scale**2.0)  # trace(D F D)
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
