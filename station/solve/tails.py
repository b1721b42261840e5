"""Tail probabilities of the normal and chi-square laws in the standard library's `math`: what the
quality gate (`station.solve.quality`) asks on every solve, without scipy.special, whose import
alone costs more than numpy's and h5py's together (issue 35: `station solve` <= 3x their import).

The chi-square law with k degrees of freedom is the gamma law of shape k / 2 and scale 2, so its
upper tail is the regularised upper incomplete gamma function Q(k / 2, x / 2), evaluated as in
Numerical Recipes (Press et al., 3rd ed., 6.2): below x = a + 1 by the series of P = 1 - Q (each
term positive; Q there is not small, so 1 - P loses nothing), above it by Legendre's continued
fraction for Q itself (modified Lentz), both to the float's precision. The prefactor
exp(-x + a log x - lgamma(a)) is formed in logs, so a tail of 1e-300 neither underflows early
nor loses digits. tests/test_tails.py compares every function with scipy.special to 1e-12.
"""

import math
from statistics import NormalDist

_EPS = 1e-16
_TINY = 1e-300
_ITERATIONS = 100_000
_STANDARD = NormalDist()


def normal_isf(p: float) -> float:
    """The z with P(N(0, 1) > z) = p, 0 < p < 1 (scipy.special.ndtri(1 - p), kept exact in the
    upper tail by taking -ndtri(p))."""
    return -_STANDARD.inv_cdf(p)


def chi2_sf(k: float, x: float) -> float:
    """P(chi2_k >= x) for k > 0 degrees of freedom (scipy.special.chdtrc(k, x))."""
    if k <= 0:
        raise ValueError(f"chi-square degrees of freedom must be positive, got {k}")
    return _gamma_q(k / 2.0, x / 2.0)


def chi2_isf(k: float, p: float) -> float:
    """The x with P(chi2_k >= x) = p, 0 < p < 1 (scipy.special.chdtri(k, p)): bisection on the
    monotone tail, bracketed by doubling from the mean k, to the float's resolution."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"a tail probability lies in (0, 1), got {p}")
    low, high = 0.0, float(k)
    while chi2_sf(k, high) > p:
        low, high = high, 2.0 * high
    while high - low > 4 * _EPS * high:
        mid = 0.5 * (low + high)
        if mid in (low, high):
            break
        if chi2_sf(k, mid) > p:
            low = mid
        else:
            high = mid
    return 0.5 * (low + high)


def _gamma_q(a: float, x: float) -> float:
    """Q(a, x) = Gamma(a, x) / Gamma(a), the regularised upper incomplete gamma function."""
    if x <= 0.0:
        return 1.0
    log_front = -x + a * math.log(x) - math.lgamma(a)
    if x < a + 1.0:
        return 1.0 - _series(a, x, log_front)
    return _fraction(a, x, log_front)


def _series(a: float, x: float, log_front: float) -> float:
    """P(a, x) = e^-x x^a / Gamma(a + 1) sum_n x^n / ((a + 1) ... (a + n)), for x < a + 1."""
    term = total = 1.0 / a
    shape = a
    for _ in range(_ITERATIONS):
        shape += 1.0
        term *= x / shape
        total += term
        if abs(term) < abs(total) * _EPS:
            return total * math.exp(log_front)
    raise ArithmeticError(f"the incomplete gamma series did not converge (a={a}, x={x})")


def _fraction(a: float, x: float, log_front: float) -> float:
    """Q(a, x) = e^-x x^a / Gamma(a) / (x + 1 - a - 1 (1 - a) / (x + 3 - a - ...)), for
    x >= a + 1, by the modified Lentz method."""
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, _ITERATIONS):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            return math.exp(log_front) * h
    raise ArithmeticError(f"the incomplete gamma fraction did not converge (a={a}, x={x})")
