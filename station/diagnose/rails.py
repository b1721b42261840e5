"""Pile-up at the output rails: observed against expected sample counts at the extreme count.

The rail R is the largest |count| in the session. For each sensor and sign, N samples read
exactly +-R; the twin expects E = sum over samples of the probability of reading +-R: for an
unclipped Gaussian output of mean mu and standard deviation sigma, the mass of the quantisation
bin at R; for an output clipped at the rail, the whole tail beyond R - 1/2 count. The Poisson
deviance 2 (N log(N/E) - (N - E)) summed over sensors and signs is the rail part of the model's
deviance; a clipped output pile-up gives thousands, a free one at most about 1 per side
that holds the maximum.
"""

import numpy as np
from scipy.special import ndtr


def observed(data) -> np.ndarray:
    """(2, m) samples reading +R and -R (R: `RotaryData.rail`; counted a chunk of positions at a
    time); 0 on a sensor quantised coarser than its noise (`RotaryData.coarse`), whose outputs
    read a few values each: the twin's means do not place them within a step, so a reading at
    the rail is quantisation as much as a clip (its `expected` is 0 too)."""
    r = data.rail
    counted = sum(np.stack([(data.counts[rows] == r).sum((0, 1)),
                            (data.counts[rows] == -r).sum((0, 1))]) for rows in data.chunks())
    return np.where(data.coarse, 0, counted)


def expected(data, z: np.ndarray, sigma: np.ndarray, clipped: bool,
             offsets: np.ndarray | None = None) -> np.ndarray:
    """(2, m) expected samples at +R and -R for expected outputs z (n, k, m), noise sigma (m,),
    each position's outputs moved by `offsets` (n, m) when given; 0 on a coarse sensor
    (`observed`)."""
    r = data.rail
    m = z.shape[2]
    sc = np.broadcast_to(sigma / data.lsb, (m,))
    out = np.zeros((2, m))
    for i in np.flatnonzero(~data.coarse):
        mu = z[..., i] / data.lsb[i]  # counts
        if offsets is not None:
            mu = mu + offsets[:, None, i] / data.lsb[i]
        for side, sign in enumerate((1.0, -1.0)):
            # standardised distance to the inner edge of the rail's bin; beyond 12 the mass is 0
            lo = (r - 0.5 - sign * mu) / sc[i]
            out[side, i] = pile_up(lo[lo < 12], 1 / sc[i], clipped).sum()
    return out


def pile_up(lo, width, clipped: bool):
    """Probability of reading the rail for a Gaussian output whose distance to the inner edge
    of the rail's quantisation bin is lo standard deviations (bin width `width` of them): the
    whole tail when the output is clipped, the bin's mass when it is free."""
    tail = ndtr(-lo)
    return tail if clipped else tail - ndtr(-lo - width)


def deviance(n_obs: np.ndarray, n_exp: np.ndarray) -> float:
    """Poisson deviance of observed against expected counts.

    A side that holds the session's extreme sample holds it by construction: its expectation is
    at least 1 (the rail is found, not given).
    """
    e = np.where(n_obs > 0, np.maximum(n_exp, 1.0), np.maximum(n_exp, 1e-300))
    with np.errstate(divide="ignore", invalid="ignore"):
        term = np.where(n_obs > 0, n_obs * np.log(n_obs / e), 0.0)
    return float(2 * np.sum(term - (n_obs - e)))
