"""The measurement model of m single-axis sensors, written once (docs/conventions.md).

Forward:  z = a^T v + b        (Rupniewski Eq. (3) with a bias after the projection)
Fusion:   v = (a a^T)^-1 a (z - b)   (least squares over the m sensors of one instant)

One array orientation everywhere, the conventions' own: instants are COLUMNS. `a` is d x m,
a stimulus v is (d,) or (d, k), readings z are (m,) or (m, k), a bias b is (m,) or None
(unbiased readings). A time series of samples stored as rows (k, m) is passed transposed:
`fuse(a, samples.T, b).T`.
"""

import numpy as np


class Sensitivity:
    """The shape of a sensitivity matrix `a` (d x m), for every class that holds one (a sensor
    unit, a calibration result, a calibration file)."""

    @property
    def d(self) -> int:
        """Dimension of the stimulus (rows of a)."""
        return self.a.shape[0]

    @property
    def m(self) -> int:
        """Number of sensors (columns of a)."""
        return self.a.shape[1]


def _columns(x, rows: int, what: str) -> np.ndarray:
    """x as floats of shape (rows,) or (rows, k), refused otherwise."""
    x = np.asarray(x, float)
    if x.ndim not in (1, 2) or x.shape[0] != rows:
        raise ValueError(f"{what} have shape {x.shape}; expected ({rows},) or ({rows}, k) "
                         "(one column per instant, docs/conventions.md)")
    return x


def _bias(b, z: np.ndarray) -> np.ndarray:
    """The bias (m,) shaped to broadcast against readings z (m,) or (m, k); 0 for None."""
    if b is None:
        return np.zeros(())
    b = np.asarray(b, float)
    return b if z.ndim == 1 else b[:, None]


def forward(a, v, b=None) -> np.ndarray:
    """Readings z = a^T v + b: (m,) for v (d,), (m, k) for v (d, k)."""
    a = np.asarray(a, float)
    v = _columns(v, a.shape[0], "stimuli")
    z = a.T @ v
    return z + _bias(b, z)


def fusion_matrix(a) -> np.ndarray:
    """(d, m) least-squares fusion matrix F = (a a^T)^-1 a, so that v = F (z - b)."""
    a = np.asarray(a, float)
    return np.linalg.solve(a @ a.T, a)


def fuse(a, z, b=None) -> np.ndarray:
    """Calibrated vectors v = (a a^T)^-1 a (z - b): (d,) for z (m,), (d, k) for z (m, k)."""
    a = np.asarray(a, float)
    z = _columns(z, a.shape[1], "readings")
    return fusion_matrix(a) @ (z - _bias(b, z))


def fusion_jacobian(a, z, b) -> np.ndarray:
    """(k, d, d m + m) Jacobian of v = F (z - b) in (a row-major, then b) at readings z (m,) or
    (m, k) (k = 1 for one instant):

        dv/db_i = -F[:, i],  dv/da_ri = G^-1[:, r] (y - a^T v)_i - F[:, i] v_r,

    with G = a a^T, F = G^-1 a, y = z - b, v = F y (first order)."""
    a = np.asarray(a, float)
    z = _columns(z, a.shape[1], "readings").reshape(a.shape[1], -1)
    y = (z - np.asarray(b, float)[:, None]).T
    g_inv = np.linalg.inv(a @ a.T)
    f = g_inv @ a
    v = y @ f.T
    res = y - v @ a
    d, m = a.shape
    jac_a = (g_inv[None, :, :, None] * res[:, None, None, :]
             - f[None, :, None, :] * v[:, None, :, None]).reshape(len(y), d, d * m)
    return np.concatenate([jac_a, np.broadcast_to(-f, (len(y), d, m))], axis=2)
