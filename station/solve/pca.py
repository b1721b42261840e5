"""Closed-form PCA calibration of m unbiased single-axis sensors (Rupniewski, Algorithm 2).

Readings `M` (m x n) of a stimulus of constant magnitude c satisfy M = a^T v + noise, |v_j| = c.
The truncated SVD gives the best rank-d approximation M ~ e b (Eqs. 12-15); the symmetric g = f^T f
solves c^2 = b_j^T g b_j (Eq. 7) in the least-squares sense (Remark 3); its eigendecomposition
g = q^T lambda q (Eq. 8) gives v = lambda^1/2 q b and a = lambda^-1/2 q e^T (Eqs. 10, 11).
"""

import numpy as np

from station.solve.identifiability import (
    check_design,
    check_gram,
    check_positions,
    check_rank,
    gram_design,
)


def truncated_svd(readings: np.ndarray, d: int) -> tuple[np.ndarray, np.ndarray]:
    """Basis e (m x d) of the dominant column space and coordinates b = s w^T (d x n),
    Eqs. (13)-(15)."""
    u, s, wt = np.linalg.svd(readings, full_matrices=False)
    check_rank(s, d, readings.shape)
    return u[:, :d], s[:d, None] * wt[:d]


def solve_gram(b: np.ndarray, magnitude: float) -> np.ndarray:
    """Least-squares symmetric g with b_j^T g b_j = c^2 for every position j (Eq. 7, Remark 3)."""
    d = b.shape[0]
    design, pairs = gram_design(b)
    check_design(design)
    coef, *_ = np.linalg.lstsq(design, np.full(b.shape[1], magnitude**2), rcond=None)
    g = np.zeros((d, d))
    g[pairs] = coef
    return g + np.triu(g, 1).T


def pca_calibration(readings, magnitude: float = 1.0, d: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Rupniewski Algorithm 2: sensitivity a (d x m) and stimuli v (d x n) with a^T v ~ readings.

    The result is defined up to an orthogonal transformation (Remark 1); with an unknown magnitude
    pass c = 1 and the scale factors are known up to one common factor (Remark 2).
    """
    readings = np.asarray(readings, dtype=float)
    check_positions(readings.shape, d)
    e, b = truncated_svd(readings, d)
    g = solve_gram(b, magnitude)
    lam, vecs = np.linalg.eigh(g)
    check_gram(lam)
    q = vecs.T
    v = np.sqrt(lam)[:, None] * (q @ b)
    a = (q @ e.T) / np.sqrt(lam)[:, None]
    return a, v
