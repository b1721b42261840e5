"""Maximum-likelihood refinement on the reading residuals (Levenberg-Marquardt, Schur complement).

Model (docs/conventions.md): z_ij = a_i . v_j + b_i + noise_ij, noise_ij ~ N(0, sigma_ij^2), with
|v_j| = c. Unknowns: the sensitivity a (d x m), optionally the biases b (m), and one direction per
position on the sphere of radius c. This replaces the constraint cost of Hwangbo & Kanade (ill-posed
for m > 3) by the likelihood of the readings themselves.

Structure: the global parameters split per sensor into blocks theta_i = (a_i, b_i) that never couple
with each other directly, and the local parameters split per position into (d-1) tangent coordinates
of v_j. The normal equations are solved by eliminating the position blocks (Schur complement), so one
iteration costs O(m^2 n d^3) instead of a dense solve in m d + n (d - 1) unknowns.
The rotation gauge (Remark 1 of Rupniewski) leaves d(d-1)/2 flat directions; the Marquardt damping
keeps the steps finite and the gradient has no component along them.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class NormalEquations:
    """Blocks of J^T W J and J^T W r at one point (see `normal_equations`)."""

    h_global: np.ndarray  # (m, p, p)   per-sensor block of the global Hessian, p = d (+1 with bias)
    h_local: np.ndarray  # (n, d-1, d-1) per-position block
    h_cross: np.ndarray  # (m, n, p, d-1) sensor-position coupling
    g_global: np.ndarray  # (m, p)
    g_local: np.ndarray  # (n, d-1)


@dataclass(frozen=True)
class MLFit:
    """Result of `refine`: the estimate, its residuals and the noise level."""

    a: np.ndarray  # (d, m)
    v: np.ndarray  # (d, n), |v_j| = magnitude
    bias: np.ndarray | None  # (m,) when estimated or given
    residuals: np.ndarray  # (m, n) readings - model, output units
    sigma: np.ndarray  # (m, n) noise standard deviation used as weight (estimated when not given)
    sigma_estimated: bool
    chi2: float  # sum of squared normalised residuals
    dof: int  # m n - number of free parameters (gauge removed)
    iterations: int
    normal: NormalEquations  # Fisher-information blocks at the optimum, for the uncertainty


def tangent_basis(u: np.ndarray) -> np.ndarray:
    """Orthonormal bases (n, d, d-1) of the planes perpendicular to unit vectors u (d, n).

    Columns 2..d of the Householder reflection that maps e_1 onto -sign(u_1) u.
    """
    d, n = u.shape
    s = np.where(u[0] >= 0, 1.0, -1.0)
    w = u.T.copy()
    w[:, 0] += s
    house = np.eye(d)[None] - 2 * w[:, :, None] * w[:, None, :] / np.einsum("nk,nk->n", w, w)[:, None, None]
    return house[:, :, 1:]


def design(a, v, magnitude, with_bias):
    """Jacobian pieces of the prediction a_i . v_j + b_i: global rows x (n, p), local c a_i^T B_j."""
    n = v.shape[1]
    x = v.T if not with_bias else np.hstack([v.T, np.ones((n, 1))])  # (n, p)
    basis = tangent_basis(v / magnitude)  # (n, d, d-1)
    local = magnitude * np.einsum("di,ndk->ink", a, basis)  # (m, n, d-1)
    return x, local, basis


def normal_equations(a, v, bias, readings, weight, magnitude) -> tuple[NormalEquations, np.ndarray]:
    """Blocks of the Gauss-Newton normal equations and the residuals (readings - model)."""
    with_bias = bias is not None
    x, local, _ = design(a, v, magnitude, with_bias)
    resid = readings - a.T @ v - (bias[:, None] if with_bias else 0.0)
    wr = weight * resid
    neq = NormalEquations(
        h_global=np.einsum("in,np,nq->ipq", weight, x, x),
        h_local=np.einsum("in,ink,inl->nkl", weight, local, local),
        h_cross=np.einsum("in,np,ink->inpk", weight, x, local),
        g_global=wr @ x,
        g_local=np.einsum("in,ink->nk", wr, local),
    )
    return neq, resid


def reduced_system(neq: NormalEquations, damping: float = 0.0):
    """Schur complement on the global parameters: S = Hgg - Hgl Hll^-1 Hlg and its right side.

    Returns S (m p x m p), the reduced gradient, and the damped inverse local blocks.
    """
    m, p = neq.g_global.shape
    h_local = neq.h_local + damping * _diag_blocks(neq.h_local)
    h_local_inv = np.linalg.inv(h_local + 1e-300 * np.eye(h_local.shape[-1]))
    # coupling times inverse local block: (m, n, p, d-1)
    ch = np.einsum("inpk,nkl->inpl", neq.h_cross, h_local_inv)
    s = -np.einsum("inpl,jnql->ipjq", ch, neq.h_cross).reshape(m * p, m * p)
    h_global = neq.h_global + damping * _diag_blocks(neq.h_global)
    idx = np.arange(m)
    s4 = s.reshape(m, p, m, p)
    s4[idx, :, idx, :] += h_global
    g = neq.g_global - np.einsum("inpl,nl->ip", ch, neq.g_local)
    return s4.reshape(m * p, m * p), g.reshape(-1), h_local_inv


def _diag_blocks(blocks: np.ndarray) -> np.ndarray:
    """Marquardt scaling: the diagonal of each block, as diagonal matrices (plus a floor)."""
    diag = np.einsum("...kk->...k", blocks)
    floor = 1e-12 * max(float(diag.max(initial=0.0)), 1e-300)
    return np.einsum("...k,kl->...kl", np.maximum(diag, floor), np.eye(blocks.shape[-1]))


def lm_step(neq: NormalEquations, damping: float):
    """One damped Gauss-Newton step: global step by the Schur complement, then per-position steps."""
    m, p = neq.g_global.shape
    s, g, h_local_inv = reduced_system(neq, damping)
    step_global = np.linalg.solve(s, g).reshape(m, p)
    rhs = neq.g_local - np.einsum("inpk,ip->nk", neq.h_cross, step_global)
    step_local = np.einsum("nkl,nl->nk", h_local_inv, rhs)
    return step_global, step_local


def apply_step(a, v, bias, step_global, step_local, magnitude):
    """New (a, v, b): additive on a and b, along the tangent plane then back to the sphere for v."""
    d = a.shape[0]
    basis = tangent_basis(v / magnitude)
    v_new = v + magnitude * np.einsum("ndk,nk->dn", basis, step_local)
    v_new *= magnitude / np.linalg.norm(v_new, axis=0)
    a_new = a + step_global[:, :d].T
    b_new = None if bias is None else bias + step_global[:, d]
    return a_new, v_new, b_new


def free_parameters(m: int, n: int, d: int, with_bias: bool) -> int:
    """Unknowns that the data can determine: a, b, directions, minus the rotation gauge."""
    return d * m + (m if with_bias else 0) + n * (d - 1) - d * (d - 1) // 2


def refine(
    readings,
    a0,
    v0,
    *,
    bias0=None,
    estimate_bias: bool = False,
    magnitude: float = 1.0,
    sigma=None,
    max_iter: int = 100,
    tol: float = 1e-12,
) -> MLFit:
    """Maximum-likelihood a, v (and b) from a start (a0, v0[, bias0]), e.g. the closed form.

    sigma: noise standard deviation of the readings - scalar, per sensor (m,), or per entry (m, n).
    When None, all entries get equal weight and one common sigma is estimated from the residuals.
    A given bias0 with estimate_bias=False is held fixed (subtracted).
    """
    readings = np.asarray(readings, dtype=float)
    m, n = readings.shape
    a = np.array(a0, dtype=float)
    d = a.shape[0]
    v = np.array(v0, dtype=float)
    v *= magnitude / np.linalg.norm(v, axis=0)
    if bias0 is not None and not estimate_bias:
        readings = readings - np.asarray(bias0, float)[:, None]
    bias = (np.zeros(m) if bias0 is None else np.array(bias0, float)) if estimate_bias else None
    sig = np.broadcast_to(_sigma_matrix(sigma, m, n), (m, n))
    weight = 1.0 / sig**2

    neq, resid = normal_equations(a, v, bias, readings, weight, magnitude)
    cost = float(np.sum(weight * resid**2))
    damping, it = 1e-6, 0
    for it in range(1, max_iter + 1):
        step_g, step_l = lm_step(neq, damping)
        a_t, v_t, b_t = apply_step(a, v, bias, step_g, step_l, magnitude)
        neq_t, resid_t = normal_equations(a_t, v_t, b_t, readings, weight, magnitude)
        cost_t = float(np.sum(weight * resid_t**2))
        if cost_t <= cost:
            converged = cost - cost_t <= tol * max(cost, 1e-300)
            a, v, bias, neq, resid, cost = a_t, v_t, b_t, neq_t, resid_t, cost_t
            damping = max(damping / 10, 1e-12)
            if converged:
                break
        else:
            damping *= 10
            if damping > 1e12:
                break

    dof = m * n - free_parameters(m, n, d, estimate_bias)
    estimated = sigma is None
    if estimated:
        scale = np.sqrt(cost / max(dof, 1))
        sig = np.full((m, n), scale)
        neq = _rescale(neq, 1.0 / scale**2)
        cost = float(np.sum(resid**2) / scale**2)
    if bias0 is not None and not estimate_bias:
        bias = np.asarray(bias0, float)
    return MLFit(a, v, bias, resid, np.array(sig), estimated, cost, dof, it, neq)


def _sigma_matrix(sigma, m: int, n: int) -> np.ndarray:
    """sigma as an array broadcastable to (m, n); None means unit weights."""
    if sigma is None:
        return np.ones((1, 1))
    s = np.asarray(sigma, dtype=float)
    if s.ndim == 1:
        if s.shape[0] != m:
            raise ValueError(f"sigma has {s.shape[0]} entries but there are {m} sensors")
        s = s[:, None]
    if np.any(~np.isfinite(s)) or np.any(s <= 0):
        raise ValueError("sigma must be positive and finite (noise standard deviation of the readings)")
    return s


def _rescale(neq: NormalEquations, factor: float) -> NormalEquations:
    """Normal equations with every weight multiplied by `factor`."""
    return NormalEquations(*(factor * getattr(neq, f) for f in NormalEquations.__dataclass_fields__))
