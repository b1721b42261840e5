"""Effect `latency`: per-channel sample-time skew.

Parameters
----------
delay : scalar or (m,), s
    Channel i reports the signal of time t - delay_i at its sample time t.

Signature: while the table accelerates at alpha, channel i lags by alpha delay_i (a_i . u): the
residual is negative on spin-up and positive on spin-down (antisymmetric); steady windows are
untouched.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Latency:
    """Per-channel delay in seconds."""

    delay: float | tuple = 0.0


def apply(s: np.ndarray, t: np.ndarray, p: Latency) -> np.ndarray:
    """Signals s (n, k, m) sampled at times t (k,) -> the same signals delayed per channel.

    Linear interpolation between samples; before the first sample the first value is held.
    """
    n, _, m = s.shape
    delay = np.broadcast_to(np.asarray(p.delay, float), (m,))
    out = np.empty_like(s)
    for i in range(m):
        ti = t - delay[i]
        for j in range(n):
            out[j, :, i] = np.interp(ti, t, s[j, :, i])
    return out
