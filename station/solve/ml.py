"""Maximum-likelihood refinement on the reading residuals (Levenberg-Marquardt, Schur complement).

Model (docs/conventions.md): z_ij = a_i . v_j + b_i + noise_ij, noise_ij ~ N(0, sigma_ij^2), with
|v_j| = c. Unknowns: the sensitivity a (d x m), optionally the biases b (m), and the stimuli v,
parametrised by station/solve/poses.py (a free direction per position, or one rotation per rigid
group of positions of a right-angle iron, or a free vector per position whose magnitude is a random
effect |v_j| = c (1 + delta_j), delta_j ~ N(0, s^2), with one extra residual row (|v_j| - c) / (c s)
per position: the h-likelihood, whose maximum over a is the marginal-likelihood estimate of the
linearised model). This replaces the constraint cost of Hwangbo & Kanade (ill-posed for m > 3) by
the likelihood of the readings themselves.

Structure: the global parameters split per sensor into blocks theta_i = (a_i, b_i) that never couple
with each other directly; the local parameters split per position group. The normal equations are
solved by eliminating the local blocks (Schur complement), so an iteration costs O(m^2 n d^3)
instead of a dense solve, its contractions as matrix products (BLAS). The rotation gauge (Remark 1
of Rupniewski) leaves d(d-1)/2 flat directions; the Marquardt damping keeps the steps finite and
the gradient has no component along them.
"""

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from station.errors import CalibrationInputError
from station.model import measurement
from station.solve.poses import Directions, SoftMagnitudes, rigid_groups


@dataclass(frozen=True)
class NormalEquations:
    """Blocks of J^T W J and J^T W r at one point (see `normal_equations`)."""

    h_global: np.ndarray  # (m, p, p)   per-sensor block, p = d (+1 with bias)
    h_local: np.ndarray  # (G, k, k)   per-group block
    h_cross: np.ndarray  # (m, p, k, G) sensor-group coupling: rows of a (m p, k G) matrix
    g_global: np.ndarray  # (m, p)
    g_local: np.ndarray  # (G, k)


@dataclass(frozen=True)
class MLFit:
    """Result of `refine`: the estimate, its residuals and the noise level."""

    a: np.ndarray  # (d, m)
    v: np.ndarray  # (d, n), |v_j| = magnitude (about it, with a magnitude spread)
    bias: np.ndarray | None  # (m,) when estimated or given
    residuals: np.ndarray  # (m, n) readings - model, output units
    sigma: np.ndarray  # (m, n) noise standard deviation used as weight (estimated when not given)
    sigma_estimated: bool
    chi2: float  # sum of squared normalised residuals (and prior rows, with a magnitude spread)
    dof: int  # m n (+ prior rows) - number of free parameters (gauge removed)
    iterations: int
    normal: NormalEquations  # Fisher-information blocks at the optimum, for the uncertainty
    objective: float  # the minimised cost with the weights used (`cost`)
    converged: bool  # the cost stopped decreasing before max_iter iterations

    @cached_property
    def fisher(self) -> np.ndarray:
        """Fisher information (m p x m p) of theta = (a_1, b_1, a_2, b_2, ...) at the optimum, the
        poses eliminated (the undamped Schur complement of `normal`); computed once, for the
        identifiability check and the covariance alike."""
        return reduced_system(self.normal)[0]


def _by_group(x: np.ndarray, poses, axis: int) -> np.ndarray:
    """Sum per-position terms over each group along `axis` (identity for one position per group)."""
    if isinstance(poses, (Directions, SoftMagnitudes)):
        return x
    x = np.moveaxis(x, axis, 0)
    out = np.zeros((poses.count,) + x.shape[1:])
    np.add.at(out, poses.group, x)
    return np.moveaxis(out, 0, axis)


def normal_equations(a, poses, bias, readings, weight) -> tuple[NormalEquations, np.ndarray]:
    """Blocks of the Gauss-Newton normal equations and the residuals (readings - model); the
    sums over sensors and positions as matrix products or broadcasts (linear in n)."""
    v = poses.vectors()
    n = v.shape[1]
    x = v.T if bias is None else np.hstack([v.T, np.ones((n, 1))])  # d prediction / d theta_i
    local = np.einsum("di,ndk->ink", a, poses.jacobian())  # d prediction_ij / d local_j
    resid = readings - measurement.forward(a, v, bias)
    wr = weight * resid
    wl = weight[..., None] * local
    h_local = _by_group(wl.transpose(1, 2, 0) @ local.transpose(1, 0, 2), poses, 0)
    g_local = _by_group(np.einsum("in,ink->nk", wr, local), poses, 0)
    if isinstance(poses, SoftMagnitudes):
        prior, jac = poses.prior()
        h_local = h_local + np.einsum("nk,nl->nkl", jac, jac)
        g_local = g_local + prior[:, None] * jac
    m, p = a.shape[1], x.shape[1]
    neq = NormalEquations(
        h_global=(weight @ (x[:, :, None] * x[:, None, :]).reshape(n, p * p)).reshape(m, p, p),
        h_local=h_local + _null_identity(poses),
        h_cross=_by_group(_coupling(wl, x), poses, 3),
        g_global=wr @ x,
        g_local=g_local,
    )
    return neq, resid


def prior_rows(poses) -> np.ndarray:
    """Residuals of the pose prior, (n,) for soft magnitudes, none for hard constraints."""
    return poses.prior()[0] if isinstance(poses, SoftMagnitudes) else np.zeros(0)


def cost(poses, weight, resid) -> float:
    """The minimised objective: weighted squared residuals plus prior rows (-2 log h-likelihood)."""
    return float(np.sum(weight * resid**2) + np.sum(prior_rows(poses) ** 2))


def _null_identity(poses) -> np.ndarray:
    """Unit curvature on local directions that move nothing (rotation of a one-axis group about
    its axis), so every local block is invertible; they couple to nothing and never move."""
    null = poses.null.astype(float)
    return np.einsum("gk,kl->gkl", null, np.eye(null.shape[1]))


SCHUR_CHUNK = 4096
"""Groups per block of the Schur contraction: its products stay in the cache (at n = 10^5 the
whole (m p, k G) product would stream 57 MB twice more; blocks of 4096 take a third less time)."""


def reduced_system(neq: NormalEquations, damping: float = 0.0):
    """Schur complement on the global parameters: S = Hgg - Hgl Hll^-1 Hlg and its right side.

    Returns S (m p x m p), the reduced gradient, and the damped inverse local blocks. The
    contraction over the local parameters runs as matrix products (m p x k c) (k c x m p) through
    BLAS over blocks of c = SCHUR_CHUNK groups: O(m^2 p^2 G k), linear in the number of positions.
    """
    m, p = neq.g_global.shape
    h_local_inv = np.linalg.inv(_damped(neq.h_local, damping))
    s = np.zeros((m * p, m * p))
    g = neq.g_global.ravel().copy()
    for start in range(0, len(h_local_inv), SCHUR_CHUNK):
        part = slice(start, start + SCHUR_CHUNK)
        cross = np.ascontiguousarray(neq.h_cross[..., part])
        ch = _times_blocks(cross, h_local_inv[part]).reshape(m * p, -1)  # coupling x Hll^-1
        s -= ch @ cross.reshape(m * p, -1).T
        g -= ch @ neq.g_local[part].T.ravel()
    s4 = s.reshape(m, p, m, p)
    idx = np.arange(m)
    s4[idx, :, idx, :] += _damped(neq.h_global, damping)
    return s, g, h_local_inv


def _times_blocks(h_cross: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Each group's coupling (m, p, k, G) times its (k, k) block (G, k, k), as k^2 broadcasts
    along the groups (k <= 3)."""
    out = np.empty_like(h_cross)
    k = blocks.shape[-1]
    for col in range(k):
        acc = out[:, :, col]
        np.multiply(h_cross[:, :, 0], blocks[:, 0, col], out=acc)
        for row in range(1, k):
            acc += h_cross[:, :, row] * blocks[:, row, col]
    return out


def _coupling(weighted_local: np.ndarray, x: np.ndarray) -> np.ndarray:
    """h_cross (m, p, k, n) = w_ij x_jp local_ijk from w local (m, n, k) and x (n, p), one
    broadcast per local column (along n)."""
    m, n, k = weighted_local.shape
    out = np.empty((m, x.shape[1], k, n))
    for col in range(k):
        np.multiply(x.T[None], weighted_local[:, None, :, col], out=out[:, :, col])
    return out


def _damped(blocks: np.ndarray, damping: float) -> np.ndarray:
    """The blocks with Marquardt damping, blocks + damping diag(blocks) (`_diag_blocks`); the
    blocks themselves undamped (the Fisher information)."""
    return blocks + damping * _diag_blocks(blocks) if damping else blocks


def _diag_blocks(blocks: np.ndarray) -> np.ndarray:
    """Marquardt scaling: the diagonal of each block, as diagonal matrices (with a floor)."""
    diag = np.einsum("...kk->...k", blocks)
    floor = 1e-12 * max(float(diag.max(initial=0.0)), 1e-300)
    return np.einsum("...k,kl->...kl", np.maximum(diag, floor), np.eye(blocks.shape[-1]))


def lm_step(neq: NormalEquations, damping: float):
    """One damped Gauss-Newton step (global and local steps), eliminating first the side with
    more unknowns: the poses' (`poses_first`, the usual case: positions outnumber sensors) or the
    sensors' (`sensors_first`: many sensors at few positions)."""
    m, p = neq.g_global.shape
    if neq.g_local.size < m * p:
        return sensors_first(neq, damping)
    return poses_first(neq, damping)


def sensors_first(neq: NormalEquations, damping: float):
    """The damped step by the Schur complement on the poses' unknowns (`sensors_eliminated`):
    K step_local = g_local - C^T U^-1 g, then the sensors' steps U^-1 (g - C step_local):
    O(m p (k G)^2) instead of `poses_first`'s O((m p)^2 k G + (m p)^3)."""
    m, p = neq.g_global.shape
    u_inv, c, uc, poses = sensors_eliminated(neq, damping)
    ug = by_sensor(u_inv, neq.g_global.ravel())
    step_local = np.linalg.solve(poses, neq.g_local.ravel() - c.T @ ug)
    return (ug - uc @ step_local).reshape(m, p), step_local.reshape(neq.g_local.shape)


def sensors_eliminated(neq: NormalEquations, damping: float = 0.0) -> tuple:
    """(U^-1 (m, p, p), C (m p, k G, columns by group then k), U^-1 C, K = L - C^T U^-1 C): the
    damped normal equations with the sensors' blocks U (block-diagonal) eliminated, K the Schur
    complement on the poses' unknowns (`sensors_first`; `uncertainty.woodbury_pinv` at
    damping 0)."""
    m, p = neq.g_global.shape
    groups, k = neq.g_local.shape
    u_inv = np.linalg.inv(_damped(neq.h_global, damping))
    c = neq.h_cross.transpose(0, 1, 3, 2).reshape(m * p, groups * k)
    uc = by_sensor(u_inv, c)
    poses = -(c.T @ uc)
    blocks = poses.reshape(groups, k, groups, k)
    idx = np.arange(groups)
    blocks[idx, :, idx, :] += _damped(neq.h_local, damping)
    return u_inv, c, uc, poses


def by_sensor(u_inv: np.ndarray, x: np.ndarray) -> np.ndarray:
    """blockdiag(u_inv) x for the sensors' blocks u_inv (m, p, p) and x (m p,) or (m p, r)."""
    m, p, _ = u_inv.shape
    return np.einsum("ipq,iq...->ip...", u_inv, x.reshape(m, p, *x.shape[1:])).reshape(x.shape)


def poses_first(neq: NormalEquations, damping: float):
    """The damped step by the Schur complement on the sensors' unknowns (`reduced_system`), then
    the local steps."""
    m, p = neq.g_global.shape
    s, g, h_local_inv = reduced_system(neq, damping)
    step_global = np.linalg.solve(s, g).reshape(m, p)
    coupled = step_global.ravel() @ neq.h_cross.reshape(m * p, -1)  # (k G,)
    rhs = neq.g_local - coupled.reshape(neq.g_local.shape[::-1]).T
    return step_global, np.einsum("gkl,gl->gk", h_local_inv, rhs)


def free_parameters(m: int, d: int, with_bias: bool, poses) -> int:
    """Unknowns that the data can determine: a, b, the local pose parameters, minus the gauge."""
    return d * m + (m if with_bias else 0) + poses.free - d * (d - 1) // 2


def start_poses(v0, magnitude, constraints=None, spread=None, fitted: bool = False):
    """Pose parametrisation: soft magnitudes when a spread > 0 is given, rigid groups when the
    constraints describe them, else directions. fitted: v0 is a fit's own (soft magnitudes keep
    their lengths instead of starting on the prior's mean)."""
    v0 = np.asarray(v0, float)
    if spread:
        if constraints is not None:
            raise CalibrationInputError(
                "a magnitude spread (random table rate) cannot be combined with constraints.",
                "Give either the constraints of a right-angle iron or magnitude_spread, not both.",
            )
        if fitted:
            return SoftMagnitudes(v0, float(magnitude), float(spread))
        return SoftMagnitudes.start(v0, magnitude, spread)
    groups = None if constraints is None else rigid_groups(constraints, v0, magnitude)
    return Directions.start(v0, magnitude) if groups is None else groups


def refine(
    readings,
    a0,
    v0,
    *,
    bias0=None,
    estimate_bias: bool = False,
    magnitude: float = 1.0,
    sigma=None,
    constraints=None,
    magnitude_spread: float | None = None,
    max_iter: int = 100,
    tol: float = 1e-12,
    fitted: bool = False,
) -> MLFit:
    """Maximum-likelihood a, v (and b) from a start (a0, v0[, bias0]), e.g. the closed form.

    sigma: noise standard deviation of the readings - scalar, per sensor (m,), or per entry (m, n).
    When None, all entries get equal weight and one common sigma is estimated from the residuals.
    A given bias0 with estimate_bias=False is held fixed (subtracted). constraints
    (station.solve.constraints) that fix all inner products within groups of positions (a
    right-angle iron's mountings) make each group rigid; otherwise each position has its own
    direction. magnitude_spread s > 0: the magnitudes are a random effect, |v_j| = c (1 + delta_j)
    with delta_j ~ N(0, s^2) (each v_j a free vector with that prior); it needs sigma, since it
    weighs the readings against the prior. fitted: (a0, v0, bias0) is a fit to go on from (its
    stimuli's magnitudes kept; `start_poses`), e.g. with other weights.
    """
    readings = np.asarray(readings, dtype=float)
    m, n = readings.shape
    a = np.array(a0, dtype=float)
    d = a.shape[0]
    check_spread(magnitude_spread, sigma)
    poses = start_poses(v0, magnitude, constraints, magnitude_spread, fitted)
    if bias0 is not None and not estimate_bias:
        readings = readings - np.asarray(bias0, float)[:, None]
    bias = (np.zeros(m) if bias0 is None else np.array(bias0, float)) if estimate_bias else None
    sig = np.broadcast_to(sigma_matrix(sigma, m), (m, n))
    weight = 1.0 / sig**2

    neq, resid = normal_equations(a, poses, bias, readings, weight)
    objective = cost(poses, weight, resid)
    damping, it, converged = 1e-6, 0, False
    for it in range(1, max_iter + 1):  # noqa: B007 - `it` is returned: the iterations done
        step_g, step_l = lm_step(neq, damping)
        a_t = a + step_g[:, :d].T
        b_t = None if bias is None else bias + step_g[:, d]
        poses_t = poses.moved(step_l)
        neq_t, resid_t = normal_equations(a_t, poses_t, b_t, readings, weight)
        cost_t = cost(poses_t, weight, resid_t)
        if cost_t <= objective:
            converged = bool(objective - cost_t <= tol * max(objective, 1e-300))
            a, poses, bias, neq, resid, objective = a_t, poses_t, b_t, neq_t, resid_t, cost_t
            damping = max(damping / 10, 1e-12)
            if converged:
                break
        else:
            damping *= 10
            if damping > 1e12:  # no step lowers the cost: a minimum to machine precision
                converged = True
                break

    dof = m * n + prior_rows(poses).size - free_parameters(m, d, estimate_bias, poses)
    minimised = objective
    estimated = sigma is None
    if estimated:
        scale = np.sqrt(objective / max(dof, 1))
        if not scale > 0:  # an exact fit: the residuals say nothing about the noise level
            scale = 1.0
        sig = np.full((m, n), scale)
        neq = _rescale(neq, 1.0 / scale**2)
        objective = float(np.sum(resid**2) / scale**2)
    if bias0 is not None and not estimate_bias:
        bias = np.asarray(bias0, float)
    return MLFit(a, poses.vectors(), bias, resid, np.array(sig), estimated, objective, dof, it, neq,
                 minimised, converged)


def check_spread(spread, sigma) -> None:
    """A magnitude spread must be >= 0 and finite, and comes with the readings' noise level."""
    if spread is None or spread == 0:
        return
    if not (np.isfinite(spread) and spread > 0):
        raise CalibrationInputError(
            f"magnitude_spread {spread!r} is not a non-negative number.",
            "Give the relative standard deviation of |v_j| (e.g. 1.5e-4); 0 or None: |v_j| = c.",
        )
    if sigma is None:
        raise CalibrationInputError(
            "magnitude_spread weighs the readings against the magnitudes' prior, so the readings' "
            "noise level is needed.",
            "Pass sigma (e.g. the standard error of M from the static windows).",
        )


def sigma_matrix(sigma, m: int) -> np.ndarray:
    """sigma as an array broadcastable to (m, n); None means unit weights."""
    if sigma is None:
        return np.ones((1, 1))
    s = np.asarray(sigma, dtype=float)
    if s.ndim == 1:
        if s.shape[0] != m:
            raise ValueError(f"sigma has {s.shape[0]} entries but there are {m} sensors")
        s = s[:, None]
    if not (np.isfinite(s).all() and (s > 0).all()):
        raise ValueError("sigma must be positive and finite "
                         "(noise standard deviation of the readings)")
    return s


def _rescale(neq: NormalEquations, factor: float) -> NormalEquations:
    """Normal equations with every weight multiplied by `factor`."""
    return NormalEquations(
        neq.h_global * factor, neq.h_local * factor, neq.h_cross * factor,
        neq.g_global * factor, neq.g_local * factor,
    )
