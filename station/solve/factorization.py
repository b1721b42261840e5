"""Factorization calibration of Hwangbo & Kanade: readings = sensitivity x stimuli, the factors
resolved by inner-product constraints between positions (paper 004).

The paper writes the transposed problem `Z = F S + 1 b^T` (motions x sensors). Here, as everywhere
in the station, `M = a^T v + b 1^T` (sensors x positions): their `S` is our `a` (d x m), their `F^T`
our `v` (d x n), their m/n our n/m. The steps:

1. rank-p factorization of the readings (Eqs. 7-9): `M ~ shape_hat @ motion_hat`, p = d with the
   biases known or taken from opposite pairs (Eqs. 13-14), p = d + 1 with the biases estimated
   jointly (Eqs. 4-5, needs m >= d + 1 sensors);
2. the true stimuli are `v = G motion_hat` for an unknown d x p matrix G; each constraint
   `v_j . v_k = h c^2` is linear in the symmetric `Q = G^T G` (Eqs. 20-22, 27-28);
3. G is recovered from Q up to a rotation (Eqs. 23-26), then `a` and `b` from `shape_hat`.

Special cases: all h equal with joint biases (Eq. 29, a quartic in alpha) and orthogonality only
(Eq. 30, one reference position fixes the scale). Results are returned in the canonical frame of
Eq. (19) (docs/conventions.md).
"""

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from station.errors import CalibrationInputError
from station.model.frames import canonical_rotation
from station.solve.constraints import Constraints, magnitude_constraints

# Relative size below which a singular value or an eigenvalue counts as zero.
RANK_TOL = 1e-9
# RMS miss of the constraints (units of c^2) above which they are declared inconsistent: noise of
# a sensor worth calibrating misses by well under 1 %; a wrong face label misses by 0.3 or more.
CONSTRAINT_TOL = 0.1


@dataclass(frozen=True)
class FactorizationResult:
    """Calibration from the factorization, in the canonical frame of Eq. (19).

    a : (d, m) sensitivity, column i = sensor i's axis times its scale factor.
    v : (d, n) stimulus at each position, in the frame of `a`.
    bias : (m,) bias of each sensor in output units (given, from opposite pairs, or estimated).
    """

    a: np.ndarray
    v: np.ndarray
    bias: np.ndarray


def factorize(readings, constraints: Constraints | None = None, *, magnitude: float = 1.0,
              d: int = 3, bias=None, estimate_bias: bool | None = None,
              reference: int | None = None) -> FactorizationResult:
    """Calibrate m sensors from n averaged readings (m x n) and inner-product constraints.

    constraints : `v_j . v_k = h c^2` with c = `magnitude` (station.solve.constraints); default: the
        magnitude constraints |v_j| = c of every position.
    bias : known biases (m,); then the triad case p = d is solved on `M - b 1^T` (Eq. 13).
    estimate_bias : estimate the biases jointly (p = d + 1, Eqs. 16-26; needs m >= d + 1). Default:
        when no bias is given and m >= d + 1; otherwise biases come from opposite pairs (Eq. 14).
    reference : with orthogonality constraints only (all h = 0), the position whose magnitude is
        `magnitude`; it fixes the scale that the constraints leave free (Eq. 30).
    """
    M = _checked_readings(readings, d)
    m, n = M.shape
    c = _checked_magnitude(magnitude)
    constraints = magnitude_constraints(n) if constraints is None else constraints
    constraints.check_positions(n)
    joint = _estimates_bias(m, d, bias, estimate_bias)
    if joint:
        shape_hat, motion_hat = _factor_readings(M, d, joint=True)
    else:
        b = _checked_bias(bias, m) if bias is not None else bias_from_opposites(M, constraints)
        shape_hat, motion_hat = _factor_readings(M - b[:, None], d, joint=False)
    G = _gram_factor(_solve_gram(motion_hat, constraints, joint, reference, n), d)
    # with joint bias, the last row of [v; 1] = [G; a4^T] motion_hat: a4 = pinv(motion_hat^T) 1
    # (Eqs. 17-18), and motion_hat has orthonormal rows, so the pseudo-inverse is motion_hat itself.
    T = np.vstack([G, motion_hat.sum(axis=1)]) if joint else G
    if np.linalg.cond(T) > 1 / RANK_TOL:
        raise CalibrationInputError(
            "The constraints give a singular metric upgrade: no calibration explains the readings.",
            "Check the face labels and that the unit was still; add positions on other faces.")
    shape = np.linalg.solve(T.T, shape_hat.T)  # rows: [a; b^T] (Eq. 12), a scaled to |v| = 1
    a, v = shape[:d] / c, c * (G @ motion_hat)
    if joint:
        b = shape[d]
    r = canonical_rotation(a)
    return FactorizationResult(a=r @ a, v=r @ v, bias=b)


def bias_from_opposites(readings: np.ndarray, constraints: Constraints) -> np.ndarray:
    """Biases from opposite positions, b = (z_j + z_k) / 2 averaged over the pairs (Eq. 14).

    Assumes both stimuli of a pair have the same magnitude, as on a right-angle iron.
    """
    pairs = constraints.opposite_pairs()
    if len(pairs) == 0:
        raise CalibrationInputError(
            "No opposite pairs (h = -1) among the constraints, so the biases cannot be found.",
            "Record both faces of each axis (e.g. +x and -x), give bias=..., or use "
            "estimate_bias=True with m >= d + 1 sensors.")
    M = np.asarray(readings, float)
    return 0.5 * (M[:, pairs[:, 0]] + M[:, pairs[:, 1]]).mean(axis=1)


def _checked_readings(readings, d: int) -> np.ndarray:
    """Readings as a finite float (m x n) array with m >= d sensors."""
    M = np.asarray(readings, dtype=float)
    if M.ndim != 2:
        raise CalibrationInputError(
            f"Readings must be a 2-D array (sensors x positions), got shape {M.shape}.",
            "Pass one column of m readings per position.")
    if not np.all(np.isfinite(M)):
        raise CalibrationInputError("Readings contain NaN or infinite values.",
                                    "Drop or re-record the positions with invalid samples.")
    if M.shape[0] < d:
        raise CalibrationInputError(
            f"Need at least d = {d} sensors, got m = {M.shape[0]} (rows of the readings).",
            "Pass the readings as sensors x positions (transpose them if needed).")
    return M


def _checked_magnitude(magnitude: float) -> float:
    """The magnitude c as a positive float."""
    c = float(magnitude)
    if not (np.isfinite(c) and c > 0):
        raise CalibrationInputError(f"The magnitude must be positive and finite, got {magnitude}.",
                                    "Give |v| in SI units (e.g. 9.81 m/s^2), or 1 if unknown.")
    return c


def _checked_bias(bias, m: int) -> np.ndarray:
    """Given biases as a finite float array of length m."""
    b = np.asarray(bias, dtype=float)
    if b.shape != (m,) or not np.all(np.isfinite(b)):
        raise CalibrationInputError(f"bias must be {m} finite values, one per sensor; got shape "
                                    f"{b.shape}.", "Give one bias per sensor in output units.")
    return b


def _estimates_bias(m: int, d: int, bias, estimate_bias: bool | None) -> bool:
    """Whether the biases are estimated jointly (p = d + 1) rather than given or from Eq. (14)."""
    if estimate_bias is None:
        return bias is None and m >= d + 1
    if estimate_bias and bias is not None:
        raise CalibrationInputError("Both bias=... and estimate_bias=True were given.",
                                    "Give known biases or ask for their estimation, not both.")
    if estimate_bias and m < d + 1:
        raise CalibrationInputError(
            f"Estimating the biases jointly needs at least d + 1 = {d + 1} sensors, got m = {m}.",
            "Record opposite pairs (both faces of each axis) and use estimate_bias=False, "
            "or give bias=... (e.g. from a static gyro recording).")
    return bool(estimate_bias)


def _factor_readings(M: np.ndarray, d: int, joint: bool) -> tuple[np.ndarray, np.ndarray]:
    """Rank-p factorization M ~ shape_hat (m x p) @ motion_hat (p x n), p = d + joint (Eqs. 7-9).

    motion_hat = V_p^T has orthonormal rows and shape_hat = U_p Sigma_p (the paper splits
    sqrt(Sigma) between both; the difference is absorbed by the unknown upgrade).
    """
    p = d + int(joint)
    if M.shape[1] < p:
        raise CalibrationInputError(
            f"Need at least {p} positions for this factorization, got n = {M.shape[1]}.",
            "Record the unit in more orientations (e.g. all six faces of the iron).")
    u, s, vt = np.linalg.svd(M, full_matrices=False)
    rank = int(np.sum(s[:p] > RANK_TOL * s[0]))
    if rank < d:
        raise CalibrationInputError(
            f"The readings span only {rank} of the {d} dimensions of the stimulus: all positions "
            "are parallel or lie in one plane.",
            "Turn the unit to another face, so that the stimuli point along all three axes.")
    if rank < p:
        raise CalibrationInputError(
            f"Joint bias estimation needs readings of rank {p}, got rank {rank}: either the "
            "positions lie on one plane, or the biases are zero or a combination of the axes.",
            "Add positions on other faces, or give bias=... (zeros if the biases were removed).")
    return u[:, :p] * s[:p], vt[:p]


def _gram_rows(motion_hat: np.ndarray, constraints: Constraints) -> np.ndarray:
    """Rows l(f_j, f_k) with l(x, y) . q = x^T Q y, q the upper triangle of Q (Eqs. 21, 28)."""
    p = motion_hat.shape[0]
    r, s = np.triu_indices(p)
    x, y = motion_hat[:, constraints.j].T, motion_hat[:, constraints.k].T
    rows = x[:, r] * y[:, s] + x[:, s] * y[:, r]
    rows[:, r == s] *= 0.5
    return rows


def _symmetric(q: np.ndarray, p: int) -> np.ndarray:
    """The symmetric p x p matrix whose upper triangle is q."""
    Q = np.zeros((p, p))
    Q[np.triu_indices(p)] = q
    return Q + np.triu(Q, 1).T


def _solve_gram(motion_hat: np.ndarray, constraints: Constraints, joint: bool,
                reference: int | None, n: int) -> np.ndarray:
    """Q = G^T G from the constraints, with the magnitude normalised to c = 1 (Eqs. 22, 28-30)."""
    p = motion_hat.shape[0]
    h = constraints.h
    orthogonal_only = len(h) > 0 and np.all(h == 0)
    all_equal = joint and len(h) > 0 and np.all(h == h[0]) and not orthogonal_only
    if reference is not None and not orthogonal_only:
        raise CalibrationInputError(
            "reference= is only used when all constraints are orthogonality constraints (h = 0).",
            "Drop reference=, or give only orthogonality constraints.")
    if orthogonal_only and reference is None:
        raise CalibrationInputError(
            "Orthogonality constraints alone leave the scale undetermined (Eq. 30).",
            "Give reference=j for one position j whose magnitude is known (pass it as "
            "magnitude=...), or add magnitude constraints (from_faces or magnitude_constraints).")
    unknowns = p * (p + 1) // 2
    needed = unknowns - 1 if (orthogonal_only or all_equal) else unknowns
    if len(h) < needed:
        raise CalibrationInputError(
            f"Need at least {needed} constraints for this case, got {len(h)}.",
            "Record more positions (e.g. the other faces of the iron) to add constraints.")
    L = _gram_rows(motion_hat, constraints)
    u, s, vt = np.linalg.svd(L, full_matrices=False)
    if s[needed - 1] <= RANK_TOL * s[0]:
        raise CalibrationInputError(
            f"The constraints determine only {int(np.sum(s > RANK_TOL * s[0]))} of the {needed} "
            "unknowns of the metric upgrade: they relate too few or too similar positions.",
            "Add constraints between other positions: more faces, or another mounting in the iron.")
    if orthogonal_only:
        Q = _scaled_to_reference(_symmetric(vt[-1], p), motion_hat, reference, n)
    else:
        q = vt[:needed].T @ ((u[:, :needed].T @ h) / s[:needed])  # least squares, rank `needed`
        Q = _symmetric(q, p)
        if all_equal:
            Q = _quartic_root(Q, _symmetric(vt[-1], p), p - 1)
    _check_consistent(L @ Q[np.triu_indices(p)] - h)
    return Q


def _check_consistent(residual: np.ndarray) -> None:
    """Raise if the constraints miss by more than CONSTRAINT_TOL (in units of c^2) on average."""
    rms = float(np.sqrt(np.mean(residual**2)))
    if rms > CONSTRAINT_TOL:
        raise CalibrationInputError(
            f"The constraints contradict the readings: v_j . v_k misses h c^2 by {rms:.2f} c^2 "
            "(RMS), far more than sensor noise explains.",
            "Check the face and mounting labels of each position, that the unit was still, and "
            "that every position has the same magnitude.")


def _scaled_to_reference(Qn: np.ndarray, motion_hat: np.ndarray, reference: int,
                         n: int) -> np.ndarray:
    """Q = beta Qn with beta such that |v_reference| = 1 (Eq. 30)."""
    if not (isinstance(reference, (int, np.integer)) and 0 <= reference < n):
        raise CalibrationInputError(f"reference must be a position index in [0, {n}), got "
                                    f"{reference!r}.", "Give the column number of that position.")
    f = motion_hat[:, reference]
    return Qn / (f @ Qn @ f)


def _quartic_root(Qp: np.ndarray, Qn: np.ndarray, rank: int) -> np.ndarray:
    """Q = Qp + alpha Qn with alpha the valid root of det(Q) = 0 (Eqs. 24, 29).

    det(Qp + alpha Qn) is the quartic of the paper: its roots are the generalized eigenvalues of
    the pencil (Qp, -Qn). Three of them sit at a trivial rank-1 solution; the valid one leaves Q
    positive semi-definite of rank d, i.e. with the largest d-th eigenvalue.
    """
    alphas = scipy.linalg.eigvals(Qp, -Qn)
    real = alphas[np.isfinite(alphas) & (np.abs(alphas.imag) <= 1e-9 * np.abs(alphas))].real
    best, best_score = None, 0.0
    for alpha in real:
        Q = Qp + alpha * Qn
        lam = np.linalg.eigvalsh(Q)[::-1]
        score = lam[rank - 1] / lam[0] if lam[0] > 0 else 0.0
        if score > best_score:
            best, best_score = Q, score
    if best is None or best_score <= RANK_TOL:
        raise CalibrationInputError(
            "Magnitude constraints alone admit no valid calibration (Eq. 29 has no root with a "
            f"positive semi-definite Q of rank {rank}): the readings do not have a constant "
            "magnitude.",
            "Check that the unit was still and the magnitude is right; add orthogonal or "
            "opposite constraints (right-angle iron faces).")
    return best


def _gram_factor(Q: np.ndarray, d: int) -> np.ndarray:
    """G (d x p) with G^T G the best positive semi-definite rank-d approximation of Q (Eqs. 23-26).

    Without noise Q is exactly G^T G and this equals the paper's Cholesky route up to a rotation;
    with noise the eigen-decomposition does not single out any (arbitrary) SVD coordinate.
    """
    lam, vec = np.linalg.eigh(Q)
    lam, vec = lam[::-1][:d], vec[:, ::-1][:, :d]
    if lam[-1] <= RANK_TOL * abs(lam[0]) or lam[0] <= 0:
        raise CalibrationInputError(
            "The constraints contradict the readings (Q is not positive definite): no sensor "
            "layout explains both.",
            "Check the face labels and mountings, that the unit was still at each position, and "
            "the bias or opposite-pair assumptions.")
    return np.sqrt(lam)[:, None] * vec.T
