"""Uncertainty from the Fisher information, with the rotation gauge handled; the Cramer-Rao bound.

The Fisher information of the readings model (station/solve/ml.py) reduced to the per-sensor
parameters theta_i = (a_i, b_i) by the Schur complement over the position directions is singular
along the d(d-1)/2 rotations of Remark 1 (Rupniewski). Its pseudo-inverse over the remaining
directions is the covariance of every gauge-invariant function of theta: scale factors |a_i|, angles
between axes, biases, and a expressed in a frame defined by a itself (the canonical frame
of Eq. 19).

Each reported figure is computed from the blocks of the covariance it depends on (a scale factor
from its sensor's p x p block, an angle from the 2 d x 2 d block of its two axes, a in the reporting
frame by a gauge transformation onto the frame's conditions), so memory stays O((m p)^2) and time
O((m p)^3) for m sensors (docs/solvers.md, "Scale").

The white-noise figure trusts the readings' stated noise (e.g. sd / sqrt(N) of a pose's samples).
Real poses carry more: coloured noise, settling, re-seating. `pose_variance` estimates that excess
as one error term per reading of a pose, sigma_pose^2, from the between-pose scatter of the
residuals (docs/solvers.md, "Honest uncertainties"); the total figure weighs the readings by
sigma^2 + sigma_pose^2.
"""

import functools

import numpy as np

from station.model import measurement
from station.model.frames import align_to, canonical_rotation, to_canonical
from station.solve.identifiability import gauge_directions
from station.solve.ml import (
    NormalEquations,
    by_sensor,
    check_spread,
    normal_equations,
    reduced_system,
    sensors_eliminated,
    sigma_matrix,
)
from station.solve.poses import Directions, SoftMagnitudes
from station.solve.tails import chi2_sf

SINGULAR = "the information is singular beyond the rotation gauge"
WOODBURY_BELOW = 3
"""`normal_covariance` takes the Woodbury identity when this many times the poses' unknowns (and
the gauge's) are fewer than the sensors' parameters: then its (m p)^2 (k G) products cost less
than the (m p)^3 factorisation (m = 768 sensors at 100 poses: 0.03 s for 0.55 s)."""
LAPACK_FROM = 300
"""From this size on, `gauge_pinv` inverts by LAPACK's Cholesky inverse (scipy.linalg.lapack:
potri, half the flops of an inverse through the factor); below it by numpy's, whose import every
solve has paid already, where scipy.linalg's import costs more than the solve (issue 35)."""


def gauge_pinv(fisher: np.ndarray, gauge: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of a symmetric PSD matrix whose null space is spanned by the columns of
    `gauge`: (S + s Q Q^T)^-1 - Q Q^T / s, Q an orthonormal basis of the gauge, s the mean
    eigenvalue (one Cholesky inversion, about a tenth of an eigen-decomposition's cost).
    np.linalg.LinAlgError when S + s Q Q^T is not positive definite (S singular beyond the gauge,
    which station.solve.identifiability refuses first)."""
    q = np.linalg.qr(gauge)[0]
    level = float(np.trace(fisher)) / len(fisher)
    projector = q @ q.T
    inv = _spd_inverse(fisher + level * projector)
    inv -= projector / level
    return inv


def _spd_inverse(sym: np.ndarray) -> np.ndarray:
    """The inverse of a symmetric positive definite matrix through its Cholesky factor L
    (L^-T L^-1, exactly symmetric); np.linalg.LinAlgError when it is not positive definite."""
    if len(sym) < LAPACK_FROM:
        try:
            low = np.linalg.inv(np.linalg.cholesky(sym))
        except np.linalg.LinAlgError:
            raise np.linalg.LinAlgError(SINGULAR) from None
        return low.T @ low
    from scipy.linalg import lapack

    chol, info = lapack.dpotrf(sym, lower=True)
    if info == 0:
        inv, info = lapack.dpotri(chol, lower=True)
    if info != 0:
        raise np.linalg.LinAlgError(SINGULAR)
    inv += inv.T  # dpotri fills the lower triangle; dpotrf left the upper one zero
    inv[np.diag_indices_from(inv)] /= 2
    return inv


def reduced_fisher(neq: NormalEquations) -> np.ndarray:
    """Fisher information (m p x m p) of theta = (a_1, b_1, a_2, b_2, ...), the poses eliminated
    (Schur complement)."""
    return reduced_system(neq)[0]


def global_covariance(fisher: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Covariance (m p x m p) of theta = (a_1, b_1, a_2, b_2, ...) from its reduced Fisher
    matrix (`reduced_fisher`, `ml.MLFit.fisher`), free of the rotation gauge (zero along it)."""
    return gauge_pinv(fisher, gauge_directions(a, len(fisher) // a.shape[1]))


def normal_covariance(neq: NormalEquations, a: np.ndarray, fisher) -> np.ndarray:
    """`global_covariance` of the reduced Fisher matrix of `neq` (`fisher()` gives it): by the
    Woodbury identity (`woodbury_pinv`) when the poses' unknowns are few beside the sensors'
    (WOODBURY_BELOW), else by `gauge_pinv`."""
    m, p = neq.g_global.shape
    gauge = gauge_directions(a, p)
    if WOODBURY_BELOW * (neq.g_local.size + gauge.shape[1]) < m * p:
        return woodbury_pinv(neq, gauge)
    return gauge_pinv(fisher(), gauge)


def woodbury_pinv(neq: NormalEquations, gauge: np.ndarray) -> np.ndarray:
    """`gauge_pinv` of the reduced Fisher matrix S = U - C L^-1 C^T (U: the sensors' blocks,
    block-diagonal; C: the coupling (m p, k G); L: the poses' blocks) without forming or factoring
    an (m p)^2 matrix: S + s Q Q^T = U + Y E Y^T with Y = [C, Q], E = blockdiag(-L^-1, s I), so
    (Woodbury) its inverse is U^-1 - U^-1 Y K^-1 Y^T U^-1, K = E^-1 + Y^T U^-1 Y of the poses'
    size k G + 3: O((m p)^2 k G) for the (m p)^3 of a factorisation. s as `gauge_pinv`'s (its
    trace per parameter; U's here, which bounds S's). np.linalg.LinAlgError when K is singular
    (S singular beyond the gauge)."""
    m, p = neq.g_global.shape
    u_inv, _, uc, poses = sensors_eliminated(neq)
    q = np.linalg.qr(gauge)[0]
    level = float(np.einsum("ikk->", neq.h_global)) / (m * p)
    uq = by_sensor(u_inv, q)
    uy = np.hstack([uc, uq])  # U^-1 Y, Y = [C, Q]
    cross = uc.T @ q
    inner = np.block([[-poses, cross],  # K = E^-1 + Y^T U^-1 Y: C^T U^-1 C - L = -poses
                      [cross.T, q.T @ uq + np.eye(q.shape[1]) / level]])
    try:
        inv = -uy @ np.linalg.solve(inner, uy.T)
    except np.linalg.LinAlgError:
        raise np.linalg.LinAlgError(SINGULAR) from None
    inv += inv.T
    inv /= 2
    blocks = inv.reshape(m, p, m, p)
    idx = np.arange(m)
    blocks[idx, :, idx, :] += u_inv
    inv -= q @ q.T / level
    return inv


EXCESS_P = 0.05
"""A per-pose error term is estimated only when the white-noise chi2 exceeds its upper EXCESS_P
quantile: honest white-noise data are left alone in 1 - EXCESS_P of the fits (the plain
estimator, truncated at 0, would inflate half of them)."""


def pose_variance(residuals: np.ndarray, sigma: np.ndarray, dof: int, prior=()) -> float:
    """sigma_pose^2 >= 0 with sum r_ij^2 / (sigma_ij^2 + sigma_pose^2) + sum prior^2 = dof: the
    variance a per-pose error term must have for chi2 / dof = 1. 0 when the white-noise chi2 is
    within its chi2(dof) distribution (P(chi2 >= observed) >= EXCESS_P), or no reading is spare.
    """
    r2, s2 = np.asarray(residuals, float) ** 2, np.asarray(sigma, float) ** 2
    extra = float(np.sum(np.square(prior)))

    def excess(x: float) -> float:
        return float(np.sum(r2 / (s2 + x))) + extra - dof

    observed = excess(0.0) + dof
    # P(chi2_k >= k) > 0.3 > EXCESS_P for k >= 1: a chi2 at most its dof needs no tail
    if dof <= extra or observed <= dof or chi2_sf(dof, observed) >= EXCESS_P:
        return 0.0
    from scipy.optimize import brentq  # only now: scipy.optimize is 0.1-0.2 s of imports

    high = max(float(np.mean(r2)), float(s2.max()))
    while excess(high) > 0:
        high *= 4
    return float(brentq(excess, 0.0, high, xtol=1e-12 * high, rtol=1e-10))


def estimation_widening(pose_var: float, sigma: np.ndarray, dof: int) -> float:
    """Factor (>= 1) on the total covariance for an estimated sigma_pose^2: its dof spare readings
    give it the relative variance 2 / dof, so the total variance has nu = dof / f^2 effective
    degrees of freedom (Welch-Satterthwaite, the white part known; f = the pose term's mean share
    of each reading's variance), and the factor is `t_widening(nu)`."""
    if pose_var <= 0:
        return 1.0
    share = float(np.mean(pose_var / (np.asarray(sigma, float) ** 2 + pose_var)))
    return t_widening(dof / share**2)


def t_widening(nu: float) -> float:
    """Factor (>= 1) on a covariance whose scale is estimated with nu degrees of freedom, e.g. the
    noise level from the residuals of a fit with nu = dof spare readings: (t_nu(0.975) / 1.96)^2,
    so that +-1.96 sigma is a 95 % interval (Student t; the coverage factor of GUM G.4). 1 for
    nu <= 0: no spare reading, the estimated sigma says nothing."""
    from scipy import special  # here: `import station` stays light; not scipy.stats (0.5 s)

    if nu <= 0:
        return 1.0
    return float((special.stdtrit(nu, 0.975) / special.ndtri(0.975)) ** 2)  # t and normal ppf


def frame_rotation(a: np.ndarray, nominal: np.ndarray | None = None) -> np.ndarray:
    """The rotation (d x d) into the reporting frame: the canonical one of Eq. (19), or the one
    aligning a to a nominal layout (orthogonal Procrustes)."""
    return canonical_rotation(a) if nominal is None else align_to(a, nominal)


def frame_conditions(a_frame: np.ndarray, p: int, nominal: np.ndarray | None = None) -> np.ndarray:
    """(d(d-1)/2, m p) the linear conditions C theta = 0 that the reporting frame imposes on
    theta = (a_1, b_1, ...) expressed in it, and so fix the rotation gauge: canonical, the entries
    of a below the diagonal of its first d columns vanish (Eq. 19); nominal, a nominal^T is
    symmetric (the optimality of the orthogonal Procrustes rotation)."""
    d, m = a_frame.shape
    if nominal is None:
        return _canonical_conditions(d, m, p)
    pairs = np.triu_indices(d, 1)
    rows = np.zeros((len(pairs[0]), m, p))
    for row, (r, s) in enumerate(zip(*pairs, strict=True)):
        rows[row, :, r] = nominal[s]
        rows[row, :, s] = -nominal[r]
    return rows.reshape(len(pairs[0]), m * p)


@functools.cache
def _canonical_conditions(d: int, m: int, p: int) -> np.ndarray:
    """`frame_conditions` of the canonical frame: entry (s, r) of a, r < s, is 0 (read-only)."""
    pairs = np.triu_indices(d, 1)
    rows = np.zeros((len(pairs[0]), m, p))
    rows[np.arange(len(pairs[0])), pairs[0], pairs[1]] = 1.0  # component s of column r < s
    rows.setflags(write=False)
    return rows.reshape(len(pairs[0]), m * p)


def frame_covariance(cov: np.ndarray, a: np.ndarray, nominal: np.ndarray | None = None,
                     rotation: np.ndarray | None = None):
    """Covariance (m p x m p) of theta with a in the reporting frame (`frame_rotation`), from the
    gauge-free covariance `cov` of theta at a: each a_i rotated, then every perturbation moved
    along the rotation gauge G onto the frame's conditions C (`frame_conditions`), the linearised
    frame map T = I - G (C G)^-1 C (an S-transformation): T R cov R^T T^T in O((m p)^2 d).
    rotation: `frame_rotation(a, nominal)` when the caller has it."""
    d, m = a.shape
    p = cov.shape[0] // m
    rot = np.eye(p)
    rot[:d, :d] = frame_rotation(a, nominal) if rotation is None else rotation
    a_frame = rot[:d, :d] @ a
    rotated = (rot @ cov.reshape(m, p, m * p)).reshape(m * p, m, p) @ rot.T
    rotated = rotated.reshape(m * p, m * p)
    gauge = gauge_directions(a_frame, p)
    cond = frame_conditions(a_frame, p, nominal)
    move = np.linalg.solve(cond @ gauge, cond)  # (C G)^-1 C
    moved = move @ rotated
    out = rotated - gauge @ moved
    out -= moved.T @ gauge.T
    out += gauge @ (moved @ move.T) @ gauge.T
    pinned = np.flatnonzero(cond.sum(axis=0) == 1.0) if nominal is None else []
    out[pinned, :] = out[:, pinned] = 0.0  # entries the canonical frame fixes: exactly zero
    return out


def in_parameter_order(cov: np.ndarray, m: int) -> np.ndarray:
    """A covariance of theta = (a_1, b_1, ...) (m sensors) reordered to vec(a) row-major (d, m),
    then b when estimated: theta as an (m, p) array transposed (one copy)."""
    mp = cov.shape[0]
    p = mp // m
    return cov.reshape(m, p, m, p).transpose(1, 0, 3, 2).reshape(mp, mp)


def sensor_blocks(cov: np.ndarray, d: int, m: int) -> np.ndarray:
    """The (d x d) blocks cov(a_i, a_k) of a covariance of theta, (m, d, m, d) (a view)."""
    return cov.reshape(m, -1, m, cov.shape[0] // m)[:, :d, :, :d]


def axis_angles(a: np.ndarray) -> np.ndarray:
    """Angles (rad) between the sensitive axes, (m, m)."""
    u = a / np.linalg.norm(a, axis=0)
    return np.arccos(np.clip(u.T @ u, -1.0, 1.0))


def axis_sigmas(cov: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """1-sigma of the scale factors |a_i| (m,) and of the angles between the sensitive axes
    (m, m), zero on the diagonal (gauge-invariant: any gauge-free covariance of theta gives the
    same). A scale factor's is sqrt(u_i^T cov(a_i, a_i) u_i), u_i = a_i / |a_i|; each angle(i, k)'s
    is the quadratic form of its gradient (g_ik on a_i, g_ki on a_k) on the 2 d x 2 d covariance
    of (a_i, a_k), all pairs at once in O(m^2 d^2)."""
    d, m = a.shape
    norms = np.linalg.norm(a, axis=0)
    u = a / norms
    blocks = sensor_blocks(cov, d, m)
    idx = np.arange(m)
    own = blocks[idx, :, idx, :]
    scale = np.sqrt(np.maximum(np.einsum("di,ide,ei->i", u, own, u), 0.0))
    cos = u.T @ u
    sin = np.sqrt(np.maximum(1.0 - cos**2, 1e-300))
    # grad[i, k] = d angle(a_i, a_k) / d a_i
    grad = (cos[:, :, None] * u.T[:, None, :] - u.T[None, :, :]) / (sin * norms[:, None])[..., None]
    own_var = np.einsum("ikd,ide,ike->ik", grad, own, grad)
    cross = np.einsum("ikd,idke,kie->ik", grad, blocks, grad)
    var = own_var + own_var.T + 2 * cross
    var[idx, idx] = 0.0
    return scale, np.sqrt(np.maximum(var, 0.0))


def frame_jacobian(a: np.ndarray, p: int, frame=to_canonical, step: float = 1e-7) -> np.ndarray:
    """d vec(frame(a)) / d theta by central differences, (d m, m p); frame(a) must be
    gauge-invariant."""
    d, m = a.shape
    jac = np.zeros((d * m, m, p))
    h = step * max(np.abs(a).max(), 1e-300)
    for i in range(m):
        for k in range(d):
            da = np.zeros_like(a)
            da[k, i] = h
            jac[:, i, k] = (frame(a + da) - frame(a - da)).ravel() / (2 * h)
    return jac.reshape(d * m, m * p)


def crlb(a, v, sigma, *, estimate_bias: bool = False, spread: float | None = None) -> np.ndarray:
    """Cramer-Rao bound on a in the canonical frame of Eq. (19): covariance (d m x d m), row-major.

    For readings M = a^T v (+ b) + noise with noise standard deviation `sigma` (scalar, (m,) or
    (m, n)) and |v_j| = c known, trace(crlb) is the smallest achievable E[eps^2] of Eq. (19).
    spread s > 0: the bound of the random-effects model |v_j| = c (1 + delta_j), delta_j ~ N(0, s^2)
    (calibrate(..., magnitude_spread=s)), c = the mean |v_j|: the Fisher information of the readings
    and of the prior on the magnitudes, with each v_j a free vector, reduced to a (the hybrid bound;
    for the linearised model the covariance of the marginal-likelihood estimate). It is larger than
    the bound with known magnitudes, which it approaches as s -> 0.
    """
    check_spread(spread, sigma)
    a = np.asarray(a, float)
    v = np.asarray(v, float)
    d, m = a.shape
    norms = np.linalg.norm(v, axis=0)
    poses = (SoftMagnitudes(v, float(norms.mean()), float(spread)) if spread
             else Directions.start(v, float(norms[0])))
    sig = np.broadcast_to(sigma_matrix(sigma, m), (m, v.shape[1]))
    bias = np.zeros(m) if estimate_bias else None
    neq, _ = normal_equations(a, poses, bias, measurement.forward(a, v, bias), 1.0 / sig**2)
    cov = in_parameter_order(frame_covariance(global_covariance(reduced_fisher(neq), a), a), m)
    return cov[: d * m, : d * m]


def design_information(a, v, bias, sigma) -> np.ndarray:
    """The reduced Fisher information (m p x m p, the poses eliminated) of sensors a (d, m) at
    free directions v (d, k) of magnitude |v_j|, biases `bias` (m,) estimated or None, noise
    sigma (m,) per sensor: what poses in those directions alone would determine."""
    poses = Directions.start(v, float(np.linalg.norm(v[:, 0])))
    weight = np.broadcast_to(1.0 / np.asarray(sigma, float)[:, None] ** 2, (a.shape[1],
                                                                         v.shape[1]))
    neq, _ = normal_equations(a, poses, bias, measurement.forward(a, v, bias), weight)
    return reduced_fisher(neq)


def eps_tail_probability(eps: float, bound: np.ndarray, samples: int = 200_000) -> float:
    """Probability that an efficient estimator's error exceeds `eps` (Eq. 19), given `bound` =
    crlb(...).

    In the small-noise limit an efficient estimate of the canonical a is Gaussian with covariance
    `bound`, so eps^2 is distributed as sum_k lambda_k chi2_1 over the bound's eigenvalues (a
    generalised chi-square); its tail is evaluated by Monte Carlo with a fixed seed (deterministic,
    resolution 1 / samples). A small value says the calibration is worse than the noise explains.
    """
    lam = np.linalg.eigvalsh(np.asarray(bound, float))
    lam = lam[lam > 1e-12 * lam.max()]
    z = np.random.default_rng(0).standard_normal((samples, lam.size))
    return float(np.mean((z**2) @ lam >= eps**2))
