"""Weighted least squares of residual time series on effect signatures, on binned samples.

An effect's signature is the change it makes to the twin's noise-free series per unit of a
parameter. Series are averaged over bins of `RotaryData.bin` samples (white noise of standard
deviation sigma_i per sample leaves sigma_i / sqrt(bin) per bin). The nominal model gives every
sensor one bias, a nuisance parameter that least squares eliminates by centring residuals and
signatures on their mean over the session's bins: the chi2 is then the within-position part
(trends, tones, transients, the rotating level) plus the position means against orientation. Parameters are separate per sensor, per position or global, which keeps each
normal-equation block small.
"""

from dataclasses import dataclass

import numpy as np

BLOCKS = {"sensor": "m", "position": "n", "global": ""}


def centred_bins(data, x: np.ndarray) -> np.ndarray:
    """Bin means of x (n, k, m) minus their mean over the session per sensor: (n, K, m)."""
    b = data.bins(x)
    return b - b.mean((0, 1), keepdims=True)


def chi2(data, r: np.ndarray, sigma: np.ndarray) -> float:
    """Sum of squared binned residuals r (n, k, m) in units of their noise, biases eliminated."""
    return float(np.sum(centred_bins(data, r) ** 2 * (data.bin / sigma**2)))


@dataclass(frozen=True)
class LinearFit:
    """theta (blocks, P) and its covariance (blocks, P, P); h, g the normal equations."""

    theta: np.ndarray
    cov: np.ndarray
    h: np.ndarray
    g: np.ndarray

    def reduction(self, theta: np.ndarray | None = None) -> float:
        """Decrease of chi2 when the signatures times theta (default the optimum) are removed."""
        th = self.theta if theta is None else theta
        return float(np.sum(2 * th * self.g) - np.einsum("bp,bpq,bq->", th, self.h, th))


def fit(data, r: np.ndarray, basis: list, sigma: np.ndarray, by: str) -> LinearFit:
    """Least-squares coefficients of the signatures `basis` (each (n, k, m) or (n, k, 1))
    explaining the residuals r, one coefficient set per sensor, per position or global (`by`)."""
    rb = centred_bins(data, r)
    return fit_binned(rb, [centred_bins(data, b) for b in basis], data.bin / sigma**2, by)


def fit_binned(rb: np.ndarray, basis: list, w: np.ndarray, by: str) -> LinearFit:
    """`fit` on centred bins: residuals rb (n, K, m), signatures (n, K, m or 1), weights w (m,)."""
    x = np.stack([np.broadcast_to(b, rb.shape) for b in basis], -1)
    out = BLOCKS[by]
    h = np.einsum(f"nkmp,nkmq,m->{out}pq", x, x, w).reshape(-1, len(basis), len(basis))
    g = np.einsum(f"nkmp,nkm,m->{out}p", x, rb, w).reshape(-1, len(basis))
    cov = np.linalg.pinv(h)
    return LinearFit(np.einsum("bpq,bq->bp", cov, g), cov, h, g)
