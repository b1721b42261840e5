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


def _whitened(y: np.ndarray, x: np.ndarray, cov: np.ndarray) -> tuple:
    """(L^-1 y, L^-1 x, log det cov), L the Cholesky factor of cov."""
    c = np.linalg.cholesky(cov)
    return np.linalg.solve(c, y), np.linalg.solve(c, x), 2 * np.log(np.diag(c)).sum()


def _rss(wy: np.ndarray, wx: np.ndarray) -> float:
    """Residual sum of squares of wy on the columns wx."""
    return float(np.sum((wy - wx @ np.linalg.lstsq(wx, wy, rcond=None)[0]) ** 2))


def reml(y: np.ndarray, x: np.ndarray, walk: np.ndarray, var: np.ndarray) -> float:
    """K^2 >= 0 minimising the restricted deviance of y (n,) = x beta + e, e ~ N(0, K^2 walk +
    diag var): log det V + log det (x^T V^-1 x) + the generalised residual sum of squares."""

    def dev(s: float) -> float:
        wy, wx, logdet = _whitened(y, x, s * walk + np.diag(var))
        return logdet + np.linalg.slogdet(wx.T @ wx)[1] + _rss(wy, wx)

    top = max(np.var(y) / max(walk.diagonal().mean(), 1e-300), var.mean()) * 1e3
    low = var.min() / max(walk.diagonal().max(), 1e-300) * 1e-6
    grid = np.linspace(np.log(low), np.log(top), GRID)
    values = [dev(np.exp(u)) for u in grid]
    k = int(np.argmin(values))
    sol = minimize_scalar(lambda u: dev(np.exp(u)), method="bounded",
                          bounds=(grid[max(k - 1, 0)], grid[min(k + 1, GRID - 1)]))
    return 0.0 if dev(0.0) <= min(values[k], sol.fun) else float(np.exp(sol.x))


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
        cov = reml(y[:, i], full, walk, var[:, i]) * walk + np.diag(var[:, i])
        wy, wx, _ = _whitened(y[:, i], full, cov)
        chi2 += _rss(wy, wx[:, :1]) - _rss(wy, wx)
    dof = y.shape[1] * shapes.shape[1] + taus
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
