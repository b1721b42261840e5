"""Repeatability: what a calibration is worth in the next session, from several sessions of a unit.

One session's 1-sigma says how well that session determined the parameters. A unit re-seated and
switched on again moves its biases (turn-on bias repeatability), and its mounting and temperature
move the rest, by more than any scatter inside one session can show (the MIMU4444 array's biases
moved 8x their per-session 1-sigma between recordings; docs/solvers.md "Repeatability"). With K
sessions of the same unit, each parameter x_kp (session k, parameter p of one class, e.g. the
biases) is modelled as

    x_kp = mu_p + delta_kp + e_kp,   delta_kp ~ N(0, tau^2),   e_kp ~ N(0, s_kp^2)

(a random-effects model: s_kp the session's own 1-sigma, tau^2 the between-session variance common
to a class). Few sessions determine tau^2 poorly (two sessions of a triad: 3 degrees of freedom),
and its point estimate is 0 whenever they happen to agree within their own noise; used as if known,
a tau of 0 says the next session repeats this one exactly. So tau^2 is taken with its uncertainty:
the restricted likelihood (REML: each mu_p integrated out) times a weak prior, a half-Cauchy on tau
(Gelman 2006, for few groups) of scale the larger of the class's median own 1-sigma and the
Paule-Mandel point estimate below (heavy-tailed: it holds a spread well beyond its scale back only
by the tail's 1 / tau^2), summed on a grid of tau; the tau used is the posterior mean of tau^2
(never 0: the data cannot exclude a spread below their noise; it is the variance a new session's
shift has, averaged over what the sessions leave possible), on nu = P (K - 1) degrees of freedom
(the sessions' scatter about their means). mu_p is the weighted mean
with weights 1 / (s_kp^2 + tau^2). The figure for the next session is the prediction sigma
sqrt(var(mu_p) + tau^2): the spread a new session's value has about mu_p, beside its own
estimation noise; tau^2's share f of the prediction variance widens the figure by
t_nu'(0.975) / 1.96, nu' = nu / f^2 (Welch-Satterthwaite, as `uncertainty.estimation_widening`
does for the per-pose term). The Paule-Mandel point estimate (the generalised Q statistic equal to
its degrees of freedom, 0 when Q <= P (K - 1)) and Q are kept beside it for the record.
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
    tau              : the between-session standard deviation of the class: sqrt of the
                       posterior mean of tau^2 (module docstring; 0 only when nothing varies)
    dof              : the degrees of freedom of the sessions' scatter, P' (K - 1) over the P'
                       parameters that vary
    q                : the generalised Q statistic at tau = 0 (chi2 with P' (K - 1) degrees of
                       freedom when the sessions agree within their own 1-sigma)
    widening         : the factor on sqrt(mean_sigma^2 + tau^2) that gives `sigma` (1: tau = 0)
    tau_point        : the Paule-Mandel point estimate (0 when Q <= P' (K - 1))
    tau_upper        : the posterior's 95 % upper bound on tau
    sessions         : K
    """

    mean: np.ndarray
    mean_sigma: np.ndarray
    sigma: np.ndarray
    tau: float
    dof: int
    q: float
    widening: float = 1.0
    tau_point: float = 0.0
    tau_upper: float = 0.0
    sessions: int = 0


@dataclass(frozen=True)
class Between:
    """The between-session variance of one class: tau2 (posterior mean), dof = P' (K - 1) (the
    sessions' scatter's), point (Paule-Mandel), upper (95 % upper bound of tau^2), q (Q at
    tau = 0)."""

    tau2: float
    dof: int
    point: float
    upper: float
    q: float


GRID = 600
"""Points of the grid of log tau the posterior is summed on."""


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


def _paule_mandel(x: np.ndarray, s2: np.ndarray, q0: float, dof: int) -> float:
    """The root of Q(tau^2) = dof, 0 when Q(0) <= dof."""
    from scipy.optimize import brentq  # here: `import station` stays light

    if q0 <= dof:
        return 0.0
    high = float(np.max(np.var(x, axis=0))) + float(np.max(s2))
    while _q(x, s2, high) > dof:
        high *= 4
    return float(brentq(lambda t: _q(x, s2, t) - dof, 0.0, high, xtol=1e-14 * high, rtol=1e-12))


def restricted_loglik(x: np.ndarray, s2: np.ndarray, tau2: np.ndarray) -> np.ndarray:
    """REML log-likelihood (up to a constant) of tau^2 values (g,) for estimates x (K, P) with
    variances s2 (K, P): each parameter's mean integrated out."""
    v = s2[None] + tau2[:, None, None]  # (g, K, P)
    w = 1.0 / v
    sw = w.sum(axis=1)
    mu = (w * x[None]).sum(axis=1) / sw
    return -0.5 * (np.log(v).sum(axis=(1, 2)) + np.log(sw).sum(axis=1)
                   + (w * (x[None] - mu[:, None]) ** 2).sum(axis=(1, 2)))


def between_variance(x, s) -> Between:
    """The between-session variance of estimates x (K, P) with 1-sigma s (K, P) over K sessions
    (module docstring): its posterior under REML and a half-Cauchy prior on tau.

    Parameters fixed by the frame (every session 0 +- 0, e.g. the canonical frame's zeros of a) are
    left out. A parameter with s = 0 in a session is given a floor of 1e-12 of its class's largest
    variance."""
    x, s = np.asarray(x, float), np.asarray(s, float)
    varies = ~fixed_by_frame(x, s)
    x, s2 = x[:, varies], s[:, varies] ** 2
    k, p = x.shape
    nu = p * (k - 1)
    if nu == 0:
        return Between(0.0, 0, 0.0, 0.0, 0.0)
    spread = float(np.max(np.var(x, axis=0))) + float(np.max(s2))
    s2 = np.maximum(s2, 1e-12 * spread)
    q0 = _q(x, s2, 0.0)
    point = _paule_mandel(x, s2, q0, nu)
    scale = float(np.sqrt(max(np.median(s2), point)))  # the prior's (module docstring)
    tau = np.geomspace(1e-4 * scale, 1e2 * max(scale, np.sqrt(spread)), GRID)
    log_post = restricted_loglik(x, s2, tau**2) + np.log(tau / (1 + (tau / scale) ** 2))
    weight = np.exp(log_post - log_post.max())  # per unit of log tau (the grid's spacing)
    weight /= weight.sum()
    upper = float(tau[np.searchsorted(np.cumsum(weight), 0.95)] ** 2)
    return Between(float(weight @ tau**2), nu, point, upper, q0)


def pool(x, s) -> Pooled:
    """The parameters of one class (x, s: (K, P) estimates and 1-sigma of K sessions) pooled into
    their mean and the 1-sigma for the next session (module docstring)."""
    x, s = np.asarray(x, float), np.asarray(s, float)
    between = between_variance(x, s)
    tau2 = between.tau2
    fixed = fixed_by_frame(x, s)
    w = 1.0 / np.maximum(s**2 + tau2, 1e-300)
    mean = np.sum(w * x, axis=0) / np.sum(w, axis=0)
    mean_var = np.where(fixed, 0.0, 1.0 / np.sum(w, axis=0))
    sigma, widen = next_session_sigma(np.sqrt(mean_var), tau2, between.dof, fixed)
    return Pooled(mean=mean, mean_sigma=np.sqrt(mean_var), sigma=sigma, tau=float(np.sqrt(tau2)),
                  dof=between.dof, q=between.q, widening=widen,
                  tau_point=float(np.sqrt(between.point)), tau_upper=float(np.sqrt(between.upper)),
                  sessions=len(x))


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
