"""Quantisation: samples on a grid of step Delta (an ADC's least significant bit, a printed
number's last digit), recognised from the sample values (issue 32) and kept in the noise model.

The step is the smallest gap between distinct values (gaps below 1e-3 of the median gap, the
decimal printing of imported numbers, ignored). Quantising adds to each sample an error
e = Q(x) - x. For Gaussian noise of standard deviation sigma about a mean mu, the part of e that
a window mean keeps, whatever its length, is its mean over the noise: the sawtooth's Fourier
series through the Gaussian's characteristic function (Widrow and Kollar, "Quantization Noise",
2008, ch. 4-5),

    E[e | mu] = sum_k (Delta / (pi k)) (-1)^k exp(-2 pi^2 k^2 sigma^2 / Delta^2)
                sin(2 pi k mu / Delta),

whose variance over mu (uniform within a step) is

    q(sigma) = sum_k Delta^2 / (2 pi^2 k^2) exp(-4 pi^2 k^2 sigma^2 / Delta^2):

Delta^2 / 12 for sigma -> 0 (a channel quieter than its step reads one value: the whole error
stays in the mean), below 1e-5 Delta^2 for sigma > Delta / 2 (the noise dithers the grid and the
error averages as white noise, Sheppard's sigma^2 + Delta^2 / 12 a sample). The samples' scatter
s about their window means is, on average over mu, sigma^2 + Delta^2 / 12 - q(sigma) (the rest of
the error's variance; noise and error are uncorrelated on average over mu), which gives sigma
from s (`analog_sigma`). A mean of n samples then has variance s^2 / n + q.

That average needs the windows' levels spread over the step. Where they are few, a channel
quieter than its step gives sigma better from the values each window reads (`level_sigma`):
a window at level mu reads k (in steps) with probability Phi((k + 1/2 - mu) / sigma) -
Phi((k - 1/2 - mu) / sigma), whose likelihood over the windows, each mu integrated out, has its
maximum at sigma (profiled out instead, the many mu bias it low: a window that reads one value
fits best with no noise, Neyman and Scott 1948). On 20 windows of 600 samples at levels spread
over the steps, sigma = 0.164 step: 0.163 +- 0.008 (the scatter's inversion: 0.164 +- 0.032).
"""

import numpy as np
from scipy.optimize import brentq
from scipy.special import logsumexp, ndtr

TERMS = 1000
"""Terms of the series of q (the rest is below Delta^2 / (2 pi^2 TERMS): 0.06 % of Delta^2 / 12)."""
COARSE = 1.0
"""A channel whose step exceeds this many of its noise's sigma is reported as quantised."""
WINDOWS = 200
"""The windows `level_sigma` reads at most (the first ones): 200 windows of 600 samples give
sigma to about 2 % at 0.16 step; more only cost time (2.5 ms of CPU a window)."""


def step(x: np.ndarray) -> np.ndarray:
    """(c,) quantisation step of samples x (K, c): the smallest gap between distinct values,
    ignoring gaps below 1e-3 of the median gap (decimal printing of imported numbers)."""
    out = []
    for col in x.T:
        d = np.diff(np.unique(col))
        d = d[d > 1e-3 * np.median(d)] if d.size else np.array([1.0])
        out.append(d.min())
    return np.array(out)


def kept(sigma, delta) -> np.ndarray:
    """q: the variance of the quantisation error a mean keeps (module docstring), for noise sigma
    and step delta (scalars or (c,))."""
    k = np.arange(1, TERMS + 1)[:, None]
    ratio = np.atleast_1d(np.asarray(sigma, float) / np.asarray(delta, float))
    terms = np.exp(-4 * np.pi**2 * k**2 * ratio**2) / (2 * np.pi**2 * k**2)
    return np.asarray(delta, float) ** 2 * terms.sum(axis=0)


def analog_sigma(scatter, delta) -> np.ndarray:
    """(c,) the noise sigma before quantisation, from the samples' scatter about their window
    means (s^2 = sigma^2 + Delta^2 / 12 - q(sigma), increasing in sigma)."""
    out = []
    for s, d in zip(np.atleast_1d(scatter), np.atleast_1d(delta), strict=True):
        def excess(sig, s=s, d=d):
            return sig**2 + d**2 / 12 - kept(sig, d)[0] - s**2
        out.append(brentq(excess, 0.0, s) if s > 0 and excess(0.0) < 0 else 0.0)
    return np.array(out)


def level_sigma(windows) -> float:
    """The noise sigma before quantisation, in steps, by maximum likelihood from windows of
    integer values (each an array of the counts a steady level reads; module docstring): sigma
    on a geometric grid from 0.01 to 2 steps, refined once between the best point's neighbours;
    each window's level integrated over a grid of 0.0025 step within 0.6 step of its mean (a
    uniform prior); at most the first WINDOWS windows."""
    tables = [(levels - w.mean(), n) for w in windows[:WINDOWS]
              for levels, n in [np.unique(np.asarray(w, np.int64), return_counts=True)]]
    mu = np.arange(-240, 241) / 400  # a window's level less its mean

    def loglik(sigmas):
        total = np.zeros(len(sigmas))
        for k, n in tables:  # k relative to the window's mean
            edge = (k[None, None, :] - mu[None, :, None]) / sigmas[:, None, None]
            half = 0.5 / sigmas[:, None, None]
            p = ndtr(edge + half) - ndtr(edge - half)
            total += logsumexp(np.log(np.maximum(p, 1e-300)) @ n, axis=1)
        return total

    grid = np.geomspace(0.01, 2.0, 60)
    best = int(np.argmax(loglik(grid)))
    fine = np.linspace(grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)], 41)
    return float(fine[np.argmax(loglik(fine))])


def coarse(delta, sigma) -> np.ndarray:
    """(c,) whether each channel's step exceeds `COARSE` x its noise sigma."""
    return np.asarray(delta, float) > COARSE * np.asarray(sigma, float)


def report(delta, sigma, names, units) -> dict:
    """Per channel the step, the noise sigma (before quantisation), steps of sigma per step, q and
    which channels are quantised coarser than their noise (`COARSE`), with one line saying so."""
    delta, sigma = np.asarray(delta, float), np.asarray(sigma, float)
    per = delta / np.maximum(sigma, 1e-300)
    which = coarse(delta, sigma)
    said = [f"{n} step {d:.4g}{' ' + u if u else ''} ({p:.3g} sigma per step)"
            for n, d, p, u, c in zip(names, delta, per, units, which, strict=True) if c]
    return {"step": delta, "sigma": sigma, "sigma_per_step": per, "kept": kept(sigma, delta),
            "coarse": which, "message": (
                "QUANTISED: " + ", ".join(said) + "; the error a window mean keeps (q, up to "
                "step^2 / 12) is in the noise model of every gap; no rail pile-up is judged on them"
                if said else "")}
