"""Repeatability: what a calibration is worth in the next session, from several sessions of a unit.

One session's 1-sigma says how well that session determined the parameters. A unit re-seated and
switched on again moves its biases (turn-on bias repeatability), and its mounting and temperature
move the rest, by more than any scatter inside one session can show (the MIMU4444 array's biases
moved 8x their per-session 1-sigma between recordings; docs/solvers.md "Repeatability"). With K
sessions of the same unit, each parameter x_kp (session k, parameter p of one class, e.g. the
biases) is modelled as

    x_kp = mu_p + delta_kp + e_kp,   delta_kp ~ N(0, tau^2),   e_kp ~ N(0, s_kp^2)

(a random-effects model: s_kp the session's own 1-sigma, tau^2 the between-session variance common
to a class). tau^2 is the Paule-Mandel estimate (the generalised Q statistic equal to its degrees of
freedom); mu_p the weighted mean with weights 1 / (s_kp^2 + tau^2). The figure for the next
session is the prediction sigma sqrt(var(mu_p) + tau^2): the spread a new session's value has about
mu_p, beside its own estimation noise. tau^2 is estimated from nu = P (K - 1) degrees of freedom;
its share f of the prediction variance widens the figure by t_nu'(0.975) / 1.96, nu' = nu / f^2
(Welch-Satterthwaite, as `uncertainty.estimation_widening` does for the per-pose term).
A NEW single session of the unit, given the tau^2 of a combination of earlier ones, gets the same
figure about its own estimate: sqrt(s_p^2 + tau^2), widened alike (`next_session_sigma`; `station
solve --repeatability`).
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Pooled:
    """One class of parameters pooled over K sessions (shapes: P parameters).

    mean, mean_sigma : the weighted mean and its 1-sigma
    sigma            : the 1-sigma for the next session: sqrt(mean_sigma^2 + tau^2), widened for
                       the estimated tau^2 (module docstring)
    tau              : the between-session standard deviation of the class (0: none shown)
    dof              : degrees of freedom of tau^2, P' (K - 1) over the P' parameters that vary
    q                : the generalised Q statistic at tau = 0 (chi2 with dof degrees of freedom
                       when the sessions agree within their own 1-sigma)
    widening         : the factor on sqrt(mean_sigma^2 + tau^2) that gives `sigma` (1: tau = 0)
    """

    mean: np.ndarray
    mean_sigma: np.ndarray
    sigma: np.ndarray
    tau: float
    dof: int
    q: float
    widening: float = 1.0


def _q(x: np.ndarray, s2: np.ndarray, tau2: float) -> float:
    """Generalised Q: sum_kp (x_kp - mu_p)^2 / (s_kp^2 + tau^2), mu_p the weighted mean."""
    w = 1.0 / (s2 + tau2)
    mu = np.sum(w * x, axis=0) / np.sum(w, axis=0)
    return float(np.sum(w * (x - mu) ** 2))


def fixed_by_frame(x: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(P,) the parameters of estimates x (K, P) with 1-sigma s (K, P) that every session fixes:
    0 +- 0 in each (the canonical frame's zeros of a), equal to rounding (1e-12 of the class's
    largest |x|; a solver's zeros come out as +-1e-21, not 0)."""
    return np.all(s == 0, axis=0) & (np.ptp(x, axis=0) <= 1e-12 * np.max(np.abs(x)))


def between_variance(x, s) -> tuple[float, int, float]:
    """(tau^2, dof, Q at tau = 0) of estimates x (K, P) with 1-sigma s (K, P) over K sessions.

    Parameters fixed by the frame (every session 0 +- 0, e.g. the canonical frame's zeros of a) are
    left out. tau^2 = 0 when Q(0) <= dof (the sessions agree within their own noise), else the
    root of Q(tau^2) = dof (Paule-Mandel). A parameter with s = 0 in a session is given a floor
    of 1e-12 of its class's largest variance."""
    from scipy.optimize import brentq  # here: `import station` stays light

    x, s = np.asarray(x, float), np.asarray(s, float)
    varies = ~fixed_by_frame(x, s)
    x, s2 = x[:, varies], s[:, varies] ** 2
    k, p = x.shape
    dof = p * (k - 1)
    if dof == 0:
        return 0.0, 0, 0.0
    spread = float(np.max(np.var(x, axis=0))) + float(np.max(s2))
    s2 = np.maximum(s2, 1e-12 * spread)
    q0 = _q(x, s2, 0.0)
    if q0 <= dof:
        return 0.0, dof, q0
    high = spread
    while _q(x, s2, high) > dof:
        high *= 4
    return float(brentq(lambda t: _q(x, s2, t) - dof, 0.0, high, xtol=1e-14 * high,
                        rtol=1e-12)), dof, q0


def pool(x, s) -> Pooled:
    """The parameters of one class (x, s: (K, P) estimates and 1-sigma of K sessions) pooled into
    their mean and the 1-sigma for the next session (module docstring)."""
    x, s = np.asarray(x, float), np.asarray(s, float)
    tau2, dof, q0 = between_variance(x, s)
    fixed = fixed_by_frame(x, s)
    w = 1.0 / np.maximum(s**2 + tau2, 1e-300)
    mean = np.sum(w * x, axis=0) / np.sum(w, axis=0)
    mean_var = np.where(fixed, 0.0, 1.0 / np.sum(w, axis=0))
    sigma, widen = next_session_sigma(np.sqrt(mean_var), tau2, dof, fixed)
    return Pooled(mean=mean, mean_sigma=np.sqrt(mean_var), sigma=sigma, tau=float(np.sqrt(tau2)),
                  dof=dof, q=q0, widening=widen)


def next_session_sigma(sigma, tau2: float, dof: int, fixed=None) -> tuple[np.ndarray, float]:
    """(the 1-sigma for the next session, widening) of parameters of one class known to `sigma`
    (P,) (a pooled mean's, or one session's own) whose sessions spread by tau2 estimated on `dof`
    degrees of freedom: widening x sqrt(sigma^2 + tau2), the widening t_nu'(0.975) / 1.96 with
    nu' = dof / f^2, f the mean share of tau2 in the variance (module docstring; 1 when tau2 = 0).
    Parameters `fixed` by the frame (default: those with sigma 0) stay 0."""
    from scipy import stats

    sigma = np.asarray(sigma, float)
    fixed = sigma == 0 if fixed is None else np.asarray(fixed, bool)
    total = sigma**2 + np.where(fixed, 0.0, tau2)
    widen = 1.0
    if tau2 > 0 and not np.all(fixed):
        share = float(np.mean(tau2 / total[~fixed]))
        widen = float(stats.t.ppf(0.975, dof / share**2) / stats.norm.ppf(0.975))
    return widen * np.sqrt(total), widen
