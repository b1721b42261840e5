"""Is a drift more than a bias random walk? (issue 32: coloured noise in the model)

A bias random walk of K (units / sqrt(s)) moves the mean of a window taken at time t_j by a
walk: Cov(y_j, y_k) = K^2 min(t_j, t_k), beside the window's white noise var_j. Its slow part
looks like a warm-up or a linear drift, so against white noise alone a drift fitted to a walk
is hugely significant (a walk-only rotary session named `bias_drift` at log10 p -60). Here the
drift's columns (its shapes at the windows' times, the time constants as fitted) are tested
against the walk: per channel the likelihood of the window means with a free level and a
free K^2 >= 0 (maximum likelihood, profiled) with and without the drift's columns; the sum of
the ratios over channels is chi2(channels x columns + time constants) without a drift (the
time constants chosen on the data count as parameters, as in the drift's own test).
"""

import numpy as np
from scipy.optimize import minimize_scalar

from station.diagnose.goodness import log_sf


def deviance(y: np.ndarray, x: np.ndarray, walk: np.ndarray, var: np.ndarray) -> float:
    """-2 log likelihood (up to a constant) of y (n,) = x beta + e, e ~ N(0, s walk + diag
    var), beta by generalised least squares, minimised over s = K^2 >= 0 (0 included)."""

    def dev(s: float) -> float:
        v = s * walk + np.diag(var)
        c = np.linalg.cholesky(v)
        wx, wy = np.linalg.solve(c, x), np.linalg.solve(c, y)
        beta = np.linalg.lstsq(wx, wy, rcond=None)[0]
        return float(2 * np.log(np.diag(c)).sum() + np.sum((wy - wx @ beta) ** 2))

    top = max(np.var(y) / max(walk.diagonal().mean(), 1e-300), var.mean()) * 1e3
    low = var.min() / max(walk.diagonal().max(), 1e-300) * 1e-6
    sol = minimize_scalar(lambda u: dev(np.exp(u)), bounds=np.log([low, top]), method="bounded")
    return min(dev(0.0), dev(float(np.exp(sol.x))))


def log10_p(y: np.ndarray, t: np.ndarray, var: np.ndarray, shapes: np.ndarray,
            taus: int) -> float:
    """log10 p of the drift columns `shapes` (n, q) in the window means y (n, c) at times t
    (n,) with white variances var (n, c), against a bias random walk per channel (module
    docstring); `taus` time constants were fitted to choose the shapes."""
    walk = np.minimum.outer(t - t.min(), t - t.min())
    ones = np.ones((len(t), 1))
    lr = sum(deviance(y[:, i], ones, walk, var[:, i])
             - deviance(y[:, i], np.hstack([ones, shapes]), walk, var[:, i])
             for i in range(y.shape[1]))
    dof = y.shape[1] * shapes.shape[1] + taus
    return log_sf(max(lr, 0.0), dof) / np.log(10) if lr > 0 else 0.0
