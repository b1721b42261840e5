"""Sensor noise from static data by the Allan variance: arrays in, arrays out.

A static stretch of one channel, y (k,) in its unit u at `rate` Hz, gives the overlapping Allan
variance at averaging times tau = m / rate, m = 4, 16, 64, ... up to k / 8 (`allantools.oadev`,
NIST SP 1065 eq. 11; `octave_factors` says why these). IEEE Std 952-1997 Annex C (and
El-Sheimy, Hou and Niu 2008, "Analysis and modeling of inertial sensors using Allan variance",
IEEE Trans. Instrum. Meas. 57(1)) write the Allan variance of the three noises every inertial
sensor shows as

    AVAR(tau) = N^2 / tau  +  (2 ln 2 / pi) B^2  +  K^2 tau / 3

for the continuous noises; the fit uses the Allan variance of the sampled ones (`design`:
`allan_covariance.second_moments`), whose flicker term is 5.0 % above (2 ln 2 / pi) B^2 at m = 4,
0.46 % at m = 16, and whose random walk's is K^2 tau / 3 (1 + 1 / (2 m^2)).

N   white-noise density (angle / velocity random walk), u sqrt(s); two-sided PSD N^2
B   bias instability, u; two-sided PSD B^2 / (2 pi f), the Allan deviation's floor B sqrt(2 ln2/pi)
K   rate / acceleration random walk, u / sqrt(s); two-sided PSD (K / 2 pi)^2 / f^2

The fit is linear in theta = (N^2, B^2, K^2). The estimates at different taus are correlated
(they share the same slow noise); their covariance is the model's (`covariance`: the covariance
of quadratic forms of a Gaussian process, an integral over the Allan variance's transfer
functions and the model's PSD, `station.solve.allan_covariance`, with Greenhall and Riley's
finite-length factor on the variances; docs/noise.md derives it). The fit is generalised least
squares with that covariance at the model, iterated (the quasi-likelihood equation
X^T C^-1 (AVAR_hat - X theta) = 0); the 1-sigma of theta is the inverse of its information
X^T C^-1 X, nothing added. All three terms are fitted whenever the data give `MIN_TAUS` taus: a
term left out would push its share of the Allan variance into the others (a random walk too weak
to be resolved made B too large), so its uncertainty stays in theirs. A term whose theta is not at
least `RESOLVED` sigma above zero is reported as not resolved (None: the data cannot resolve it,
e.g. too short for the random walk), never as a number. The 1-sigma of N, B, K follow from
theta's by the derivative of the square root.
"""

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from station.errors import CalibrationInputError
from station.solve.allan_covariance import EXPONENT, second_moments, stretch_covariance
from station.solve.allan_edf import allan_edf

FLOOR = 2.0 * math.log(2.0) / math.pi
"""AVAR of bias instability B = 1 at long taus: the Allan deviation floor is B sqrt(FLOOR) (IEEE
952 C.1; at short taus the sampled flicker's is above it, `design`)."""
TERMS = ("white", "bias_instability", "random_walk")
ALPHA = (0, -1, -2)
"""Power-law exponent of each term's PSD (S ~ f^alpha): white, flicker, random-walk FM."""
RESOLVED = 2.0
"""A term is reported (resolved) when its variance coefficient is this many sigma above zero."""
MIN_SAMPLES = 64
"""Fewest samples of a stretch: 64 reach m = 4 (k / 8) with 57 terms."""
MIN_TERMS = 4
"""Fewest overlapping terms (k - 2m + 1 of a stretch of k samples) for a tau to be used: the
estimates beyond hold too few degrees of freedom for the chi2 law's weights to mean much."""
ITERATIONS = 50
"""Most iterations of the fit, each with the covariance at the model (it converges in a handful)."""
MIN_TAUS = 4
"""Fewest averaging times for B and K to be fitted (three terms and one degree of freedom; fewer:
N alone, B and K unresolved)."""
LARGE = 2**40
"""Readings of a stretch long enough for the large-length covariance (`_finite_length`)."""
FIRST, STEP, LONGEST = 4, 4, 8
"""Averaging factors m = FIRST STEP^j up to k / LONGEST (`octave_factors`)."""


@dataclass(frozen=True)
class AllanCurve:
    """Overlapping Allan variance of c channels at octave taus, pooled over stretches.

    m      : (t,) averaging factors; tau : (t,) s = m / rate
    avar   : (t, c) Allan variance in u^2
    terms  : (t,) overlapping terms summed over the stretches
    lengths: (s,) samples of each stretch (their edf is found per stretch and tau)
    rate   : sample rate, Hz
    """

    m: np.ndarray
    tau: np.ndarray
    avar: np.ndarray
    terms: np.ndarray
    lengths: np.ndarray
    rate: float

    @property
    def seconds(self) -> float:
        """Seconds of data analysed."""
        return float(self.lengths.sum() / self.rate)


@dataclass(frozen=True)
class NoiseFit:
    """The fitted IEEE 952 terms of c channels (`TERMS`), each (c,) in u sqrt(s), u, u/sqrt(s),
    with 1-sigma; NaN where a channel's term is not resolved (`resolved` False).

    value, sigma : (3, c) N, B, K and their 1-sigma
    theta, cov   : (c, 3) variance coefficients (N^2, B^2, K^2) as fitted (an unresolved one
                   may be negative), (c, 3, 3) their covariance (zero rows and columns for
                   terms not fitted: B and K of fewer than `MIN_TAUS` taus)
    edf          : (t, c) equivalent degrees of freedom of each Allan variance estimate (2 AVAR^2
                   over its variance, `covariance`)
    resolved     : (3, c) bool
    """

    value: np.ndarray
    sigma: np.ndarray
    theta: np.ndarray
    cov: np.ndarray
    edf: np.ndarray
    resolved: np.ndarray

    def model_avar(self, m, rate: float) -> np.ndarray:
        """(len(m), c) fitted Allan variance at the averaging factors m (integers) at `rate` Hz."""
        return design(m, rate) @ self.theta.T


def octave_factors(length: int) -> np.ndarray:
    """Averaging factors 4, 16, 64, ... (every other octave) of a stretch of `length` samples, up
    to `_longest_factor`. m starts at 4: the shortest taus of a real sensor are shaped by its
    anti-alias filter, and of discrete flicker noise by its discreteness (1.44 times the floor at
    m = 1); the spacing of 4 keeps neighbouring estimates less correlated than octaves; beyond an
    eighth of the stretch an estimate has a handful of degrees of freedom."""
    top = _longest_factor(length)
    if top < FIRST:
        return np.zeros(0, np.int64)
    return FIRST * STEP ** np.arange(int(math.log(top / FIRST, STEP)) + 1)


def _longest_factor(length) -> int:
    """The largest averaging factor a stretch of `length` samples reaches: at least `MIN_TERMS`
    terms, at most an `LONGEST`th of the stretch."""
    return min((int(length) + 1 - MIN_TERMS) // 2, int(length) // LONGEST)


def allan_curve(stretch, rate: float, counts_per_unit=None) -> AllanCurve:
    """The overlapping Allan variance of one static stretch (k, c) at `rate` Hz, channel by
    channel, at `octave_factors` (`overlapping_avar`: the estimator of `allantools.oadev` on
    frequency data, NIST SP 1065 eq. 11, for many channels at once). `counts_per_unit` (c,): the
    stretch holds raw counts, each channel divided by its scale when it is analysed, `BLOCK`
    values at a time (so a long stretch is never held in floats whole). Each channel's mean is
    taken out first (the Allan variance does not see it; the running sum then keeps its
    precision)."""
    y = np.asarray(stretch)
    scale = np.ones(y.shape[-1]) if counts_per_unit is None else \
        np.broadcast_to(np.asarray(counts_per_unit, float), y.shape[-1:])
    k = len(y)
    if y.ndim != 2 or k < MIN_SAMPLES:
        raise CalibrationInputError(
            f"a static stretch of {k} samples is too short for the Allan variance.",
            f"Give stretches of at least {MIN_SAMPLES} samples (seconds of rest).")
    m = octave_factors(k)
    avar = np.empty((len(m), y.shape[1]))
    width = max(1, BLOCK // k)
    for first in range(0, y.shape[1], width):
        columns = y[:, first:first + width] / scale[first:first + width]
        bad = np.flatnonzero(~np.all(np.isfinite(columns), axis=0))
        if len(bad):
            raise CalibrationInputError(
                f"channel {first + bad[0] + 1} holds values that are not finite.",
                "Give finite readings in SI units.")
        avar[:, first:first + width] = overlapping_avar(columns - columns.mean(axis=0), m)
    return AllanCurve(m, m / rate, avar, (k - 2 * m + 1).astype(float), np.array([k]), rate)


BLOCK = 1 << 22
"""Values (samples x channels) of a stretch converted to floats at a time (32 MB)."""


def overlapping_avar(y: np.ndarray, m: np.ndarray) -> np.ndarray:
    """(t, c) overlapping Allan variances of the readings y (k, c) at the averaging factors m
    (t,): with the running sum x_j = y_0 + ... + y_(j-1) (x_0 = 0), the mean over the k - 2m + 1
    starts i of (x_(i+2m) - 2 x_(i+m) + x_i)^2 / (2 m^2) (NIST SP 1065 eq. 11 on the phase;
    allantools.oadev's estimator, tests/test_noise.py compares them)."""
    x = np.concatenate([np.zeros((1, y.shape[1])), np.cumsum(y, axis=0)])
    out = np.empty((len(m), y.shape[1]))
    for j, f in enumerate(int(f) for f in m):
        d = x[2 * f:] - 2.0 * x[f:len(x) - f] + x[:len(x) - 2 * f]
        out[j] = np.einsum("ij,ij->j", d, d) / (2.0 * f * f * len(d))
    return out


def pooled(curves) -> AllanCurve:
    """One Allan curve from the curves of several stretches of the same channels: at each tau
    the stretches' Allan variances averaged with their numbers of terms as weights (each term is
    one squared second difference, so this is the Allan variance of all the terms together);
    taus only the longer stretches reach take only those."""
    curves = list(curves)
    if not curves:
        raise CalibrationInputError("no static stretch to analyse.",
                                    "Record the unit at rest (static windows, still poses).")
    rate = curves[0].rate
    if any(c.rate != rate or c.avar.shape[1] != curves[0].avar.shape[1] for c in curves):
        raise CalibrationInputError("the static stretches differ in rate or channels.",
                                    "Pool stretches of one stream only.")
    m = max((c.m for c in curves), key=len)
    sums, terms = np.zeros((len(m), curves[0].avar.shape[1])), np.zeros(len(m))
    for c in curves:
        t = len(c.m)
        sums[:t] += c.avar * c.terms[:, None]
        terms[:t] += c.terms
    return AllanCurve(m, m / rate, sums / terms[:, None], terms,
                      np.concatenate([c.lengths for c in curves]), rate)


def design(m, rate: float) -> np.ndarray:
    """(t, 3) coefficients of (N^2, B^2, K^2) in the Allan variance at the averaging factors m
    (t,) of readings at `rate` Hz: the terms of IEEE 952 Annex C, 1 / tau, (2 ln 2 / pi) and tau
    / 3 for the continuous noises, as the sampled noises have them (white samples, Kasdin-Walter
    flicker, a running sum: `allan_covariance.second_moments`)."""
    return np.array([second_moments(int(f)) for f in np.asarray(m)]).reshape(-1, 3) \
        * rate ** (1.0 - EXPONENT)


@lru_cache(maxsize=4096)
def _finite_length(alpha: int, m: int, length: int) -> float:
    """Greenhall's ratio of the variance of the estimate at factor m of `length` readings to its
    large-length form 2 / M sum_l R(l)^2 (the sum's lags near the ends are counted fewer than M
    times): his edf per term at `LARGE` readings over his edf per term at `length`, for
    power-law noise alpha. (His edf itself is not taken: for discrete white noise at m = 4 and
    16 it is 11 % and 5 % below the exact 3 M / (2 m) x 4 m^2 / (4 m^2 + 5), NIST SP 1065 Table
    12, which seeded streams confirm; the ratio agrees with the exact white-noise sums to 1e-5.)"""
    per_term = [allan_edf(alpha, m, n + 1) / (n - 2 * m + 1) for n in (LARGE, length)]
    return per_term[0] / per_term[1]


def covariance(curve: AllanCurve, theta) -> np.ndarray:
    """(t, t) covariance of the pooled estimates `curve.avar` of a channel whose variance
    coefficients are theta (3,). Per stretch the model's large-length covariance
    (`allan_covariance.stretch_covariance`: the covariance of quadratic forms of a Gaussian
    process, all three terms of the model), its variances scaled by Greenhall's finite-length
    factor for the noise that dominates at that tau (`_finite_length`; the correlations kept);
    the stretches are independent, so their covariances add with the squared pooling weights
    (their numbers of terms over the sum): for the variances, Satterthwaite's pooled edf.
    Stretches of one length have one covariance, computed once and counted as often."""
    theta = np.asarray(theta, float)
    parts = design(curve.m, curve.rate) * theta
    alpha = np.array(ALPHA)[np.argmax(parts, axis=1)]
    total = np.zeros((len(curve.m), len(curve.m)))
    for n, times in zip(*np.unique(curve.lengths, return_counts=True), strict=True):
        t = int(np.sum(curve.m <= _longest_factor(n)))
        m = curve.m[:t]
        scale = np.array([_finite_length(int(a), int(f), int(n))
                          for a, f in zip(alpha[:t], m, strict=True)])
        w = np.sqrt(scale) * (n - 2 * m + 1) / curve.terms[:t]
        total[:t, :t] += times * stretch_covariance(m, int(n), theta, curve.rate) * np.outer(w, w)
    return total


def fit_noise(curve: AllanCurve, names=None) -> NoiseFit:
    """N, B, K of every channel of `curve` by generalised least squares with its estimates'
    covariance across taus, all three terms fitted together (module docstring); terms not
    resolved are NaN, `resolved` False. names: the channels' names, for the errors."""
    if not len(curve.m):
        raise CalibrationInputError(
            f"{curve.seconds:.3g} s of static data give no averaging time.",
            "Record a longer rest (at least a few seconds).")
    flat = np.flatnonzero(~np.all(curve.avar > 0, axis=0))
    if len(flat):
        which = [str(c + 1) if names is None else str(names[c]) for c in flat]
        raise CalibrationInputError(
            f"channel(s) {', '.join(which)} do not vary over the static data.",
            "A sensor without noise is stuck or its readings are cut to one value: check it.")
    c = curve.avar.shape[1]
    x = design(curve.m, curve.rate)
    keep = np.array([True] + [len(curve.m) >= MIN_TAUS] * 2)
    fitted = [_gls(curve, ch, x, keep) for ch in range(c)]
    theta, cov = np.array([f[0] for f in fitted]), np.array([f[1] for f in fitted])
    nu, resolved = np.column_stack([f[2] for f in fitted]), np.column_stack([f[3] for f in fitted])
    var = np.diagonal(cov, axis1=1, axis2=2).T
    value = np.where(resolved, np.sqrt(np.maximum(theta.T, 0.0)), np.nan)
    sigma = np.where(resolved, np.sqrt(var) / (2.0 * np.where(resolved, value, 1.0)), np.nan)
    return NoiseFit(value, sigma, theta, cov, nu, resolved)


def _gls(curve: AllanCurve, ch: int, x: np.ndarray, keep: np.ndarray) -> tuple:
    """(theta (3,), cov (3, 3), edf (t,), resolved (3,)) of channel `ch` with the terms `keep`:
    generalised
    least squares with the estimates' covariance at the model (`covariance`), iterated. theta is
    not constrained (a term too weak to resolve may come out negative, so that the others are
    not biased by a bound on it). The covariance is taken at a noise that exists (`_physical`):
    first every term at its fitted value or zero; then, again to convergence, only the terms
    that fit resolves (`RESOLVED`), so that a term absent from the data, fitted above zero by
    chance, does not widen the others' bands by the variance it would add. (Deciding the terms
    at every iteration instead can flip between two fits for ever.) A term is resolved when both
    fits resolve it (the second alone, its covariance without the term, would understate its
    sigma); the white noise whenever it is positive."""
    a = curve.avar[:, ch]
    floor = a[0] / x[0, 0] * 1e-6  # N^2 of a millionth of the first Allan variance
    theta = np.zeros(3)
    theta[keep] = np.linalg.lstsq(x[:, keep] / a[:, None], np.ones(len(a)), rcond=None)[0]
    theta, cov, c = _iterated(curve, a, x, keep, theta, np.ones(3, bool), floor)
    present = theta > RESOLVED * np.sqrt(np.diag(cov))
    theta, cov, c = _iterated(curve, a, x, keep, theta, present, floor)
    resolved = present & (theta > RESOLVED * np.sqrt(np.diag(cov)))
    resolved[0] = theta[0] > 0
    return theta, cov, 2.0 * (x @ _physical(theta, present, floor)) ** 2 / np.diag(c), resolved


def _iterated(curve: AllanCurve, a: np.ndarray, x: np.ndarray, keep: np.ndarray,
              theta: np.ndarray, present: np.ndarray, floor: float) -> tuple:
    """(theta, cov (3, 3), the estimates' covariance (t, t)): the generalised least squares fit
    of the terms `keep` to the Allan variances `a`, from `theta`, each step with the covariance at
    the last fit's terms `present` (`_physical`), until theta stops changing."""
    xs, cov = x[:, keep], np.zeros((3, 3))
    for _ in range(ITERATIONS):
        c = covariance(curve, _physical(theta, present, floor))
        whitened = np.linalg.solve(c, np.column_stack([xs, a]))  # C^-1 [X a]
        info = xs.T @ whitened[:, :-1]
        new = np.zeros(3)
        new[keep] = np.linalg.solve(info, xs.T @ whitened[:, -1])
        done = np.allclose(new, theta, rtol=1e-9, atol=1e-12 * abs(new[0]))
        theta = new
        if done:
            break
    cov[np.ix_(keep, keep)] = np.linalg.inv(info)
    return theta, cov, c


def _physical(theta: np.ndarray, present: np.ndarray, floor: float) -> np.ndarray:
    """theta of the noise the covariance is taken at: the terms `present` at their fitted value
    or zero, the others zero, the white noise at least `floor` (the covariance stays positive
    definite)."""
    out = np.where(present, np.maximum(theta, 0.0), 0.0)
    out[0] = max(theta[0], floor)
    return out
