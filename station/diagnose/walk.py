"""Is a drift more than a bias random walk? (issue 32: coloured noise in the model)

A bias random walk of K (units / sqrt(s)) moves the mean of a window taken at time t_j by a
walk: Cov(y_j, y_k) = K^2 min(t_j, t_k) (from the first window on), beside the window's white
noise var_j. Its slow part looks like a warm-up or a linear drift, so against white noise alone
a drift fitted to a walk is hugely significant (a walk-only rotary session named `bias_drift` at
log10 p -60). Here the drift's columns (its shapes at the windows' times, the time constants as
fitted) are tested against the walk, per channel: K^2 >= 0 by restricted maximum likelihood
(REML) with a free level and the drift's columns (so that the columns' share of the walk is not
taken off K^2: plain maximum likelihood doubled the ratio's mean on walks of about the white
noise per window), then the generalised least-squares decrease of chi2 the columns bring under
that covariance. Summed over channels it is about chi2(channels x columns + time constants)
without a drift (the time constants chosen on the data count as parameters, as in the drift's
own test).
"""

import numpy as np
from scipy.optimize import minimize_scalar

from station.diagnose import linear
from station.diagnose.goodness import log_sf

GRID = 40
"""Points of the log K^2 grid over which the restricted likelihood is first scanned (it can have
more than one minimum), the best then refined between its neighbours."""
ROUNDS = 3
"""Passes over the streams' K^2 in `profile` (each fitted with the others fixed)."""


def _whitened(y: np.ndarray, x: np.ndarray, cov: np.ndarray) -> tuple:
    """(L^-1 y, L^-1 x, log det cov), L the Cholesky factor of cov."""
    c = np.linalg.cholesky(cov)
    return np.linalg.solve(c, y), np.linalg.solve(c, x), 2 * np.log(np.diag(c)).sum()


def _rss(wy: np.ndarray, wx: np.ndarray) -> float:
    """Residual sum of squares of wy on the columns wx."""
    if wx.shape[1] == 0:
        return float(np.sum(wy**2))
    return float(np.sum((wy - wx @ np.linalg.lstsq(wx, wy, rcond=None)[0]) ** 2))


def reml(y: np.ndarray, x: np.ndarray, walk: np.ndarray, rest: np.ndarray) -> float:
    """K^2 >= 0 minimising the restricted deviance of y (n,) = x beta + e, e ~ N(0, K^2 walk +
    rest), rest (n, n) the rest of the noise (white: diagonal): log det V + log det (x^T V^-1 x)
    + the generalised residual sum of squares (`deviance`)."""

    def dev(s: float) -> float:
        return deviance(y, x, s * walk + rest, True)

    var = rest.diagonal()
    top = max(np.var(y) / max(walk.diagonal().mean(), 1e-300), var.mean()) * 1e3
    low = var.min() / max(walk.diagonal().max(), 1e-300) * 1e-6
    grid = np.linspace(np.log(low), np.log(top), GRID)
    values = [dev(np.exp(u)) for u in grid]
    k = int(np.argmin(values))
    sol = minimize_scalar(lambda u: dev(np.exp(u)), method="bounded",
                          bounds=(grid[max(k - 1, 0)], grid[min(k + 1, GRID - 1)]))
    return 0.0 if dev(0.0) <= min(values[k], sol.fun) else float(np.exp(sol.x))


def deviance(y: np.ndarray, x: np.ndarray, cov: np.ndarray, restricted: bool) -> float:
    """-2 log likelihood (less constants) of y = x beta + e, e ~ N(0, cov), at the best beta:
    log det cov + the GLS residual sum of squares, + log det (x^T cov^-1 x) when restricted."""
    wy, wx, logdet = _whitened(y, x, cov)
    return logdet + (np.linalg.slogdet(wx.T @ wx)[1] if restricted else 0.0) + _rss(wy, wx)


def log10_p(y: np.ndarray, t: np.ndarray, var: np.ndarray, shapes: np.ndarray,
            taus: int) -> float:
    """log10 p of the drift columns `shapes` (n, q) in the window means y (n, c) at times t
    (n,) with white variances var (n, c), against a bias random walk per channel (module
    docstring); `taus` time constants were fitted to choose the shapes."""
    walk = np.minimum.outer(t - t.min(), t - t.min())
    ones = np.ones((len(t), 1))
    full = np.hstack([ones, shapes])
    chi2 = 0.0
    for i in range(y.shape[1]):
        white = np.diag(var[:, i])
        chi2 += _decrease(y[:, i], full, 1, reml(y[:, i], full, walk, white) * walk + white)
    return _log10_sf(chi2, y.shape[1] * shapes.shape[1] + taus)


def joint_log10_p(y: np.ndarray, x: np.ndarray, blocks: list, walks: list, var: np.ndarray,
                  taus: int) -> tuple:
    """([log10 p of each block], (groups,) K^2 of the walks without a drift, nan where x takes a
    walk whole): each block of drift columns (n, q) in `blocks` tested alone in residuals y (n,)
    of a model linear in the columns x (n, p) near its fit (channels coupled by shared
    parameters, stacked in one vector), against bias random walks: `walks` the (n, n)
    covariances of a unit walk on the rows of each group of channels that shares one K (a
    stream), beside the white variances var (n,). Columns of a block that x takes whole are
    dropped (none left: log10 p 0).

    The model's columns are taken out first (the error contrasts A^T y, A an orthonormal basis
    of their complement: REML's data); then the likelihood ratio of the contrasts with the
    block's mean to the contrasts with none (one fit for every block), each at its own REML K^2
    (`profile`): about chi2(q + taus) without a drift. Measured on walks alone
    (bench/diagnose_static.py `none_walk`): the rotary test's form (REML K^2 with the drift
    free, then the drift's GLS chi2) read log10 p below -5 in 2 of 4 sessions (a free-static
    stream shows a walk in few numbers, one radial residual a pose for the accelerometer: the
    drift takes the walk's slow part and K^2 comes out 0); the plain likelihood's K^2 (biased
    low by the drift's q columns) below -2.7 in 3 of 10; this form, each stream's drift a block
    (station.diagnose.static_walk), in 0 of 50 (at most -2.2; below -1 in 8 of 50, 5
    expected)."""
    u, s, _ = np.linalg.svd(x, full_matrices=True)
    a = u[:, int(np.sum(s > s[0] * 1e-10)):]
    seen = [np.trace(a.T @ w @ a) > 1e-12 * np.trace(w) for w in walks]  # else x takes it all
    contrasts = [a.T @ w @ a for w, keep in zip(walks, seen, strict=True) if keep]
    rest = a.T @ (var[:, None] * a)
    y = a.T @ y
    null, k2 = profile(y, np.empty((len(y), 0)), contrasts, rest)
    out = np.full(len(walks), np.nan)  # a walk x takes whole is not seen
    out[np.flatnonzero(seen)] = k2
    return [_block_log10_p(y, a.T @ b, np.linalg.norm(b), null, contrasts, rest, taus)
            for b in blocks], out


def _block_log10_p(y, block, size: float, null: float, contrasts: list, rest, taus: int):
    """log10 p of one block of drift columns on the contrasts (`joint_log10_p`): what x left of
    them (singular values above 1e-8 of their size), the null deviance `null` without them."""
    u, s, _ = np.linalg.svd(block, full_matrices=False)
    block = u[:, s > 1e-8 * size]  # what x leaves of them, full rank
    if not block.size:
        return 0.0
    return _log10_sf(null - profile(y, block, contrasts, rest)[0], block.shape[1] + taus)


def profile(y: np.ndarray, x: np.ndarray, walks: list, rest: np.ndarray) -> tuple:
    """(the plain deviance of y on the columns x, the K^2 >= 0 of every group by REML): noise
    rest + sum K_g^2 walks[g], a group at a time with the others at their values (ROUNDS
    passes)."""
    k2 = np.zeros(len(walks))

    def cov(skip=None):
        return rest + sum(k * w for g, (k, w) in enumerate(zip(k2, walks, strict=True))
                          if g != skip)

    for _ in range(ROUNDS if len(walks) > 1 else 1):
        for g, w in enumerate(walks):
            k2[g] = reml(y, x, w, cov(skip=g))
    return deviance(y, x, cov(), restricted=False), k2


def _decrease(y: np.ndarray, full: np.ndarray, p: int, cov: np.ndarray) -> float:
    """The GLS decrease of chi2 under cov when the columns of full after its first p join."""
    wy, wx, _ = _whitened(y, full, cov)
    return _rss(wy, wx[:, :p]) - _rss(wy, wx)


def _log10_sf(chi2: float, dof: int) -> float:
    """log10 P(chi2(dof) >= chi2), 0 for a decrease of 0 or less."""
    return log_sf(chi2, dof) / np.log(10) if chi2 > 0 else 0.0


def static_log10_p(current, shapes: np.ndarray, taus: int) -> float:
    """`log10_p` of the drift columns `shapes` (n, q: their static-window means) in the static
    windows' mean residuals of `current` (station.diagnose.model.Model, the model without the
    drift; made a chunk at a time), each with the white noise of its window."""
    data = current.ctx.data
    s0, s1 = data.windows["static"]
    y = linear.signature_parts(data, current.twin.residual)[1]  # static means
    var = np.broadcast_to(current.ctx.sigma**2 / (s1 - s0) + data.kept, y.shape)
    return log10_p(y, data.t_session[:, s0:s1].mean(1), var, shapes, taus)
