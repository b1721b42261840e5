"""Static sensor readings with known IEEE Std 952 noise terms, for benchmarks and tests.

    y = simulated_noise(k, rate, white=N, bias_instability=B, random_walk=K, rng=rng)

White noise of density N (u sqrt(s)): independent samples of standard deviation N sqrt(rate).
Flicker noise of bias instability B (u): the Kasdin-Walter filter (Kasdin and Walter 1992,
"Discrete simulation of power law noise", Proc. IEEE Frequency Control Symposium, eq. 39;
`allantools.Noise` implements the same filter but draws from NumPy's global generator): white
samples of variance Q_d through the filter h_0 = 1, h_j = h_{j-1} (j - 1 + 1/2) / j, whose
one-sided PSD is 2 Q_d tau0 (2 pi f tau0)^-1 = (Q_d / pi) / f = h_-1 / f. The Allan variance of
h_-1 / f is 2 ln 2 h_-1 (NIST SP 1065 Table 5), and IEEE 952's is (2 ln 2 / pi) B^2, so
B^2 = pi h_-1 = Q_d: the white samples' variance is B^2.
Rate / acceleration random walk K (u / sqrt(s)): the running sum of independent steps of
standard deviation K / sqrt(rate).
"""

import numpy as np


def flicker(k: int, bias_instability: float, rng) -> np.ndarray:
    """(k,) flicker (1/f) noise whose Allan deviation floor is B sqrt(2 ln 2 / pi) (module
    docstring): Kasdin-Walter filter of white samples of standard deviation B, by FFT."""
    n = 2 * k
    h = np.ones(k)
    j = np.arange(1, k)
    h[1:] = np.cumprod((j - 0.5) / j)
    w = np.zeros(n)
    w[:k] = rng.normal(0.0, bias_instability, k)
    return np.fft.irfft(np.fft.rfft(w) * np.fft.rfft(h, n), n)[:k]


def simulated_noise(k: int, rate: float, *, white: float = 0.0, bias_instability: float = 0.0,
                    random_walk: float = 0.0, rng=None) -> np.ndarray:
    """(k,) readings of a sensor at rest with white-noise density `white` (u sqrt(s)), bias
    instability `bias_instability` (u) and random walk `random_walk` (u / sqrt(s)), at `rate`
    Hz; `rng`: a numpy Generator."""
    rng = np.random.default_rng() if rng is None else rng
    y = rng.normal(0.0, white * np.sqrt(rate), k)
    if bias_instability:
        y += flicker(k, bias_instability, rng)
    if random_walk:
        y += np.cumsum(rng.normal(0.0, random_walk / np.sqrt(rate), k))
    return y
