"""Frames of a calibration result (docs/conventions.md): canonical Eq. (19) frame and nominal
alignment.

A sensitivity matrix `a` (d x m) is known only up to an orthogonal transformation (Remark 1 of
Rupniewski); these functions pick one representative.
"""

import numpy as np


def canonical_rotation(a: np.ndarray) -> np.ndarray:
    """Orthogonal h (d x d) such that h @ a is upper triangular with a positive diagonal (Eq. 19).

    Computed from the QR decomposition of the first d columns' span: a = q r, h = s q^T with s the
    diagonal of signs making diag(r) positive.
    """
    a = np.asarray(a, dtype=float)
    d = a.shape[0]
    q, r = np.linalg.qr(a, mode="complete")
    signs = np.sign(np.diag(r[:, :d])).copy()
    signs[signs == 0] = 1.0
    return signs[:, None] * q.T


def to_canonical(a: np.ndarray) -> np.ndarray:
    """a rotated into the canonical frame: upper triangular, positive diagonal (Eq. 19)."""
    return canonical_rotation(a) @ a


def align_to(a: np.ndarray, a_nominal: np.ndarray) -> np.ndarray:
    """Orthogonal r (reflections allowed) minimising ||r a - a_nominal||_F (orthogonal
    Procrustes)."""
    u, _, vt = np.linalg.svd(np.asarray(a_nominal, float) @ np.asarray(a, float).T)
    return u @ vt


def eps(a_true: np.ndarray, a_hat: np.ndarray) -> float:
    """Calibration error of Eq. (19): ||h a - k a_hat||_F in the canonical frame."""
    return float(np.linalg.norm(to_canonical(a_true) - to_canonical(a_hat)))
