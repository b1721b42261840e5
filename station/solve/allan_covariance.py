"""The covariance across averaging times of overlapping Allan variance estimates, from the model.

The overlapping Allan variance of readings y (k,) at averaging factor m is the mean of the
M = k - 2m + 1 squares of u_t = (ybar_{t+m} - ybar_t) / sqrt(2), ybar_t the mean of y_t ..
y_{t+m-1} (NIST SP 1065 eq. 11 with x the running sum of y): u is y through a linear filter h of
2m taps, -1/(m sqrt 2) then +1/(m sqrt 2), whose power transfer function at nu = f / rate
(cycles a sample) is

    |H_m(nu)|^2 = 2 sin^4(pi nu m) / (m sin(pi nu))^2      -> 2 sin^4(pi f tau) / (pi f tau)^2

for f << rate, the Allan variance's transfer function (NIST SP 1065 section 5.2.2; Rutman 1978,
Proc. IEEE 66(9)), so that AVAR(tau) = integral over [-rate/2, rate/2] of |H|^2 S(f) df for the
two-sided PSD S of y. h sums to zero and |H|^2 ~ 2 (pi nu m)^2 near 0, so u is stationary for the
random walk (S ~ f^-2) too.

Two estimates A_i, A_j (factors m_i, m_j of one stretch) are means of squares of jointly Gaussian
zero-mean stationary series, and Cov(u^2, v^2) = 2 Cov(u, v)^2 (Isserlis), so

    Cov(A_i, A_j) = 2 / (M_i M_j) sum_{t, s} R_ij(s - t)^2,    R_ij(l) = Cov(u^i_t, u^j_{t+l})

R_ij vanishes (white, random walk) or falls off (flicker) beyond lags of 2 max(m) samples, so for
M >> m every lag is counted min(M_i, M_j) times, and by Parseval sum_l R_ij(l)^2 = rate times the
integral of |H_i|^2 |H_j|^2 S^2 over [-rate/2, rate/2]:

    Cov(A_i, A_j) ~= 2 / max(M_i, M_j) * rate * integral |H_i(f)|^2 |H_j(f)|^2 S(f)^2 df

(the covariance of quadratic forms of a Gaussian process: e.g. Percival and Walden, "Spectral
analysis for physical applications", 1993, section 7.3; Greenhall and Riley 2004 use the same
sums for the edf). For white noise and i = j it is 2 AVAR^2 / edf with edf -> 3 M / (2 m), the
large-M limit of Greenhall's overlapping edf (NIST SP 1065 Table 12).

The noises are those of the sampled process (`shapes`): S = N^2 S_W + B^2 S_F + K^2 S_R with
S_p(f) = rate^-e_p (2 sin(pi |nu|))^-e_p, e = 0, 1, 2: white samples; Kasdin-Walter flicker, white
samples through (1 - z^-1)^(-1/2), whose power gain is 1 / (2 sin(pi nu)) (Kasdin and Walter 1992,
Proc. IEEE Frequency Control Symposium; `station.sim.noise`); the random walk, the running sum
(1 - z^-1)^-1, power gain 1 / (2 sin(pi nu))^2. For f << rate they are IEEE 952's 1, 1 / (2 pi
|f|), 1 / (2 pi f)^2 (docs/noise.md), which define N, B, K. The Allan variance of each is
rate^(1 - e_p) `second_moments` (the model's design: 1 / tau, (2 ln 2 / pi) (1 + 5.0 % at m = 4,
0.46 % at 16), tau / 3 (1 + 1 / (2 m^2))). S^2 is a quadratic form in theta = (N^2, B^2, K^2), and
the covariance is sum_pq theta_p theta_q G^pq_ij with G from `fourth_moments` (computed once per
set of factors and rate).
"""

import math
from functools import lru_cache

import numpy as np

EXPONENT = np.array([0, 1, 2])
"""S_p(f) = rate^-EXPONENT[p] (2 sin(pi |nu|))^-EXPONENT[p] for p = white, flicker, random walk
(`shapes`)."""
RESOLVE = 32.0
"""Beyond nu m = RESOLVE the factor sin^4(pi nu m) is replaced by its mean over a period (3/8;
sin^8: 35/128): the integrand there is a small tail, and the grid need not follow its wiggles."""
PER_E_FOLD = 512
"""Grid points per factor e of nu: 16 a period of sin^4 at nu m = RESOLVE."""
LOWEST = 1e-4
"""The grid starts at nu = LOWEST / max(m), where every integrand is a power of nu (the rest,
down to 0, is added as that power's integral)."""


def transfer(nu, m: int) -> np.ndarray:
    """|H_m(nu)|^2 of the overlapping Allan variance at factor m, nu = f / rate in cycles a
    sample, 0 < nu <= 1/2 (module docstring; NIST SP 1065 section 5.2.2)."""
    nu = np.asarray(nu, float)
    return 2.0 * np.sin(np.pi * nu * m) ** 4 / (m * np.sin(np.pi * nu)) ** 2


def _grid(m_max: int) -> np.ndarray:
    """Log-spaced nu from LOWEST / m_max to 1/2, PER_E_FOLD points a factor e."""
    lo = LOWEST / m_max
    return np.exp(np.linspace(math.log(lo), math.log(0.5),
                              int(PER_E_FOLD * math.log(0.5 / lo)) + 1))


def _sin4(nu: np.ndarray, m: int, power: int) -> np.ndarray:
    """sin(pi nu m)^(4 power), its mean over a period where nu m > RESOLVE (power 1: 3/8,
    power 2: 35/128)."""
    mean = {1: 3.0 / 8.0, 2: 35.0 / 128.0}[power]
    return np.where(nu * m < RESOLVE, np.sin(np.pi * nu * m) ** (4 * power), mean)


def shapes(nu: np.ndarray) -> np.ndarray:
    """(3, n) s_p(nu) = (2 sin(pi nu))^-EXPONENT[p], 0 < nu <= 1/2: the two-sided PSD shapes of
    the sampled white noise, Kasdin-Walter flicker and random walk at rate 1 (module
    docstring)."""
    return (2.0 * np.sin(np.pi * nu))[None, :] ** -EXPONENT[:, None].astype(float)


def _integral(f: np.ndarray, nu: np.ndarray, power: float) -> float:
    """Integral over nu in [-1/2, 1/2] of an even integrand f sampled on `_grid` nu: the
    trapezoid rule in log nu, and below the grid f ~ nu^power integrated exactly."""
    g = f * nu  # d nu = nu d ln nu
    body = np.sum((g[1:] + g[:-1]) * np.diff(np.log(nu))) / 2.0
    return 2.0 * (body + g[0] / (power + 1.0))  # both signs of nu


@lru_cache(maxsize=4096)
def second_moments(m: int) -> np.ndarray:
    """(3,) integrals over nu in [-1/2, 1/2] of |H_m|^2 s_p (`shapes`): the Allan variance at
    factor m of the sampled noise p of unit coefficient at rate 1; at `rate`, rate^(1 -
    EXPONENT[p]) times this. White: 1 / m; random walk: m / 3 + 1 / (6 m); flicker: (2 ln 2 /
    pi) (1 + 5.0e-2, 4.6e-3, 3.8e-4 at m = 4, 16, 64), its discreteness (module docstring)."""
    nu = _grid(m)
    h2 = 2.0 * _sin4(nu, m, 1) / (m * np.sin(np.pi * nu)) ** 2
    return np.array([_integral(h2 * s, nu, 2.0 - e) for s, e in zip(shapes(nu), EXPONENT,
                                                                    strict=True)])


@lru_cache(maxsize=4096)
def fourth_moments(m_i: int, m_j: int) -> np.ndarray:
    """(3, 3) integrals over nu in [-1/2, 1/2] of |H_i|^2 |H_j|^2 s_p s_q (`shapes`): with nu =
    f / rate, rate * integral |H_i|^2 |H_j|^2 S_p S_q df is rate^(2 - EXPONENT[p] -
    EXPONENT[q]) times this. Trapezoid rule in log nu on `_grid`, the power-law piece below the
    grid added exactly."""
    nu = _grid(max(m_i, m_j))
    sines = _sin4(nu, m_i, 2) if m_i == m_j else _sin4(nu, m_i, 1) * _sin4(nu, m_j, 1)
    h4 = 4.0 * sines / (m_i * m_j * np.sin(np.pi * nu) ** 2) ** 2
    s = shapes(nu)
    out = np.zeros((3, 3))
    for p in range(3):
        for q in range(p, 3):
            out[p, q] = out[q, p] = _integral(h4 * s[p] * s[q], nu,
                                              4.0 - EXPONENT[p] - EXPONENT[q])
    return out


@lru_cache(maxsize=256)
def _moments(m: tuple, rate: float) -> np.ndarray:
    """(t, t, 3, 3) rate * integral |H_i|^2 |H_j|^2 S_p S_q df for the factors m."""
    power = rate ** (2.0 - EXPONENT[:, None] - EXPONENT[None, :])
    return np.array([[fourth_moments(min(a, b), max(a, b)) * power for b in m] for a in m])


def stretch_covariance(m, length: int, theta, rate: float) -> np.ndarray:
    """(t, t) large-M covariance of the overlapping Allan variance estimates at factors m (t,) of
    one stretch of `length` readings at `rate` Hz whose noise has theta = (N^2, B^2, K^2)
    (module docstring)."""
    m = np.asarray(m, np.int64)
    terms = length - 2 * m + 1
    theta = np.asarray(theta, float)
    g = np.einsum("ijpq,p,q->ij", _moments(tuple(int(v) for v in m), float(rate)), theta, theta)
    return 2.0 * g / np.maximum.outer(terms, terms)


def correlation(cov: np.ndarray) -> np.ndarray:
    """The correlation matrix of a covariance matrix."""
    sd = np.sqrt(np.diag(cov))
    return cov / np.outer(sd, sd)
