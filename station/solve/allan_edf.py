"""Equivalent degrees of freedom of the overlapping Allan variance (Greenhall and Riley).

C. A. Greenhall and W. J. Riley, "Uncertainty of stability variances based on finite
differences", 35th PTTI meeting, 2003 (2004): the edf of a variance built from d-th differences
of N phase points, at averaging factor m, for power-law frequency noise S_y(f) ~ f^alpha. Here
only what the noise fit needs (`station.solve.noise`): the overlapping Allan variance (d = 2,
stride S = m, unmodified: filter factor F = m) for white, flicker and random-walk FM (alpha = 0,
-1, -2), numpy only (the reference, `allantools.edf_greenhall`, brings scipy.stats, 0.7 s of
imports, into every solve; a test holds this module to it).

Their Eqs. (7)-(10): sw(t) is the generalised autocovariance of the noise integrated twice, sx
its second difference at step 1 / F (the phase's, averaged over a sample), sz the d-th difference
of sx at step 1 (the estimator's terms', lags in units of tau), and

    1 / edf = BasicSum(J, M, S, F) / (M sz(0)^2),
    BasicSum = sz(0)^2 + (1 - J/M) sz(J/S)^2 + 2 sum_{j=1}^{J-1} (1 - j/M) sz(j/S)^2

with M = N - 2m terms and J = min(M, (d + 1) S) lags. Their case 2 (unmodified variances, alpha <=
0): the sum when J <= J_MAX (with F = m when m (d + 1) <= J_MAX, else F = inf), their Table 2's
asymptote 1 / edf = (a0 - a1 / r) / r when r = M / S > d + 1, else the sum at J_MAX lags with S
= J_MAX / r and F = inf.
"""

import numpy as np

D = 2
"""Order of the differences: 2, the Allan variance."""
J_MAX = 100
"""Most lags summed (Greenhall and Riley's J_max)."""
TABLE2 = {0: (2.0 / 3.0, 1.0 / 3.0), -1: (0.852, 0.375), -2: (1.079, 0.368)}
"""(a0, a1) of their Table 2 at d = 2, per alpha: the large-r form of 1 / edf."""


def sw(t: np.ndarray, alpha: int) -> np.ndarray:
    """Eq. (7): the generalised autocovariance of power-law noise alpha integrated twice (up to a
    constant factor, which cancels in the edf); alpha from 2 down to -2."""
    t = np.abs(np.asarray(t, float))
    power = 3 - alpha
    if power % 2:  # alpha even: |t|^power (their signs; one sign for an alpha cancels in the edf)
        return (-t if alpha == 2 else t ** power)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = t ** power * np.log(t)
    return np.where(t == 0, 0.0, -out if alpha == -1 else out)


def sx(t: np.ndarray, f: float, alpha: int) -> np.ndarray:
    """Eq. (8): sw's second difference at step 1 / F times F^2 (F = inf: sw of alpha + 2)."""
    if np.isinf(f):
        return sw(t, alpha + 2)
    return f * f * (2 * sw(t, alpha) - sw(t - 1.0 / f, alpha) - sw(t + 1.0 / f, alpha))


def sz(t: np.ndarray, f: float, alpha: int) -> np.ndarray:
    """Eq. (9) at d = 2: sx's fourth difference at step 1 (binomial weights 1 -4 6 -4 1)."""
    t = np.asarray(t, float)
    return (6 * sx(t, f, alpha) - 4 * (sx(t - 1, f, alpha) + sx(t + 1, f, alpha))
            + sx(t - 2, f, alpha) + sx(t + 2, f, alpha))


def basic_sum(j_top: int, m_terms: float, stride: float, f: float, alpha: int) -> float:
    """Eq. (10): the triangle-weighted sum of sz^2 over the lags 0 .. J."""
    j = np.arange(1, int(j_top))
    inner = 2.0 * np.sum((1.0 - j / m_terms) * sz(j / stride, f, alpha) ** 2)
    return float(sz(0.0, f, alpha) ** 2 + (1.0 - j_top / m_terms)
                 * sz(j_top / stride, f, alpha) ** 2 + inner)


def allan_edf(alpha: int, m: int, n: int) -> float:
    """edf of the overlapping Allan variance at factor m of n phase points (n - 1 readings) for
    power-law FM noise alpha (0 white, -1 flicker, -2 random walk); n >= 2 m + 1."""
    if alpha not in TABLE2:
        raise ValueError(f"alpha {alpha!r}: only white, flicker and random-walk FM (0, -1, -2)")
    m, n = int(m), int(n)
    terms = n - 2 * m  # M = 1 + floor(S (N - L) / m), L = m / F + m d = 2 m + 1
    if m < 1 or terms < 1:
        raise ValueError(f"factor m = {m} needs at least {2 * m + 1} phase points, got {n}")
    lags = min(terms, (D + 1) * m)
    r = terms / m
    if lags <= J_MAX:
        f = m if m * (D + 1) <= J_MAX else np.inf
        return terms * float(sz(0.0, f, alpha)) ** 2 / basic_sum(lags, terms, m, f, alpha)
    if r > D + 1:
        a0, a1 = TABLE2[alpha]
        return r / (a0 - a1 / r)
    return J_MAX * float(sz(0.0, np.inf, alpha)) ** 2 / basic_sum(J_MAX, J_MAX, J_MAX / r,
                                                                   np.inf, alpha)
