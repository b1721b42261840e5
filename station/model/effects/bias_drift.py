"""Effect `bias_drift`: biases drift with warm-up (session time) and heat while the table spins.

Parameters
----------
warmup : scalar or (m,), output units
    Bias offset at session time 0, decaying as exp(-t / warmup_tau).
warmup_tau : float, s
    Warm-up time constant.
heating : scalar or (m,), output units per rad/s
    Bias change per rad/s of sustained table rate.
heating_tau : float, s
    Time constant of the heating: the heat state H follows dH/dt = (|rate| - H) / heating_tau, and
    cools down between positions.

Distortion: offset_i(t) = warmup_i exp(-t / warmup_tau) + heating_i H(t), added to the outputs.
"""

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter


@dataclass(frozen=True)
class BiasDrift:
    """Warm-up and heating drift of the biases; see the module docstring for units."""

    warmup: float | tuple = 0.0
    warmup_tau: float = 300.0
    heating: float | tuple = 0.0
    heating_tau: float = 60.0

    def __post_init__(self):
        if not (self.warmup_tau > 0 and self.heating_tau > 0):
            raise ValueError(
                "bias_drift time constants warmup_tau and heating_tau must be positive"
            )


def heat(t_session: np.ndarray, rate: np.ndarray, tau: float) -> np.ndarray:
    """Heat state H (n, k): first-order low-pass of |rate| with time constant tau.

    Exact for a rate held constant over each sample interval: H[i] = alpha H[i-1] + (1 - alpha)
    |rate[i]| with alpha = exp(-dt / tau); between recordings H decays by exp(-gap / tau).
    """
    t = np.asarray(t_session, float)
    out = np.empty_like(t)
    h = 0.0
    for j in range(t.shape[0]):
        dt = np.diff(t[j]).mean() if t.shape[1] > 1 else 1.0
        alpha = np.exp(-dt / tau)
        if j:
            h *= np.exp(-max(t[j, 0] - t[j - 1, -1] - dt, 0.0) / tau)
        out[j], _ = lfilter([1 - alpha], [1, -alpha], np.abs(rate[j]), zi=[alpha * h])
        h = out[j, -1]
    return out


def apply(t_session: np.ndarray, rate: np.ndarray, p: BiasDrift, out=None,
          heated: np.ndarray | None = None) -> np.ndarray:
    """Bias offsets (n, k, m) at session times t_session (n, k) for the table rate (n, k); with
    `out` (n, k, m) they are added to it in place, one channel at a time (the same sums, and no
    array of its size made), and `out` returned. `heated`: the heat state H (n, k) at those
    samples when already made: for a part of a session (the diagnosis' twin works a few
    positions at a time), whose heat carries over from the positions before it."""
    decay = np.exp(-np.asarray(t_session, float) / p.warmup_tau)
    if not np.any(p.heating):
        heated = None
    elif heated is None:
        heated = heat(t_session, rate, p.heating_tau)
    if out is None:
        warm = decay[..., None] * np.asarray(p.warmup)
        return warm if heated is None else warm + heated[..., None] * np.asarray(p.heating)
    warmup, heating = (np.broadcast_to(np.asarray(x, float), out.shape[-1:])
                       for x in (p.warmup, p.heating))
    for i in range(out.shape[-1]):
        term = decay * warmup[i]
        if heated is not None:
            term += heated * heating[i]
        out[..., i] += term
    return out
