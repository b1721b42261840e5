"""A bias random walk in the noise model: the covariance it gives the window means (issue 32).

A channel whose bias walks, b(t) = K W(t) with W a unit Brownian motion (K in units / sqrt(s):
IEEE 952's rate random walk, the `random_walk` of a calibration file's noise figures, measured on
a long rest by `station noise`), moves every window mean of the session: the static means
wander across positions, and the spin-up and spin-down means stand off the session's one bias.
Against white noise alone the gap statistics of a walking unit fail and the effects that move
static means (drifts, jumps) look significant; with the walk in the noise model they are judged
against the real noise, by generalised least squares.

The mean of W over the time interval A = [a0, a1] and over B = [b0, b1] (a window of samples,
half a sample either side) have, from W's start,

    Cov(mean_A W, mean_B W) = E[min(U, V)],   U ~ uniform on A, V ~ uniform on B,

the integral over x > 0 of P(U > x) P(V > x): a product of two ramps, piecewise quadratic between
the four ends, integrated exactly by Simpson's rule on each piece (`mean_covariance`; A = B = [0,
L] gives L / 3). Every statistic below is a contrast (its window weights sum to zero), so the
walk's start drops out.

- Static means S_j (n positions), net of one level: covariance V = diag(white) + K^2 Omega_SS,
  the level by generalised least squares: the means whitened by V's Cholesky factor, net of
  the level's direction (`static_factors`, `whitened`), whose sum of squares is the chi2 (white
  noise alone: the weighted sum of squares of the centred means).
- Spin-up and spin-down means (the `transients`): the residual of ramp window X_j is its walk
  mean less the session's bias (the mean over all samples, G) less the twin's level there,
  f_j times the fitted reading's share of R_j - S_j (rotating less static mean, Eq. 18): the
  calibration fits v_j to the m readings of position j, a projection of about rho = min(1, d /
  m) of their noise (as `station.diagnose.gap` takes it for the white noise), so its walk part
  has covariance rho Omega (the same position) or rho^2 Omega (two positions' independent
  fits), and rho Omega with the ramp's own walk (`transients_covariance`).
- The bins of each position, net of their own level (the deviance's within-position part):
  white noise of a bin and the walk over the position's grid, the same for every position,
  whitened with a free level (`bin_factors`): within a position a walk is a slow wander that
  the effects' shapes there (a tone at the table rate, a ramp) would otherwise take up.
Flicker is not modelled here: its share of a few-second window mean is small beside the white
noise and the walk at the figures a MEMS gyro's datasheet gives (the bench's case), and its
covariance over hours has no closed form as simple; a calibration file's bias instability is
reported, not used.
"""

import numpy as np

D = 3
"""Components of the stimulus v_j fitted per position (the level's share rho = min(1, D / m))."""


def mean_covariance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(p, q) covariance of the means of a unit Brownian motion started at 0 over the intervals
    a (p, 2) and b (q, 2) (times >= 0): E[min(U, V)] (module notes)."""
    a0, a1 = a[:, 0, None], a[:, 1, None]
    b0, b1 = b[None, :, 0], b[None, :, 1]
    lo, end = np.minimum(a0, b0), np.minimum(a1, b1)
    mid = np.minimum(np.maximum(a0, b0), end)

    def both(x):
        return (np.clip((a1 - x) / (a1 - a0), 0.0, 1.0)
                * np.clip((b1 - x) / (b1 - b0), 0.0, 1.0))

    def simpson(x0, x1):
        return (x1 - x0) / 6.0 * (both(x0) + 4.0 * both(0.5 * (x0 + x1)) + both(x1))

    return lo + simpson(lo, mid) + simpson(mid, end)


def intervals(data, start, stop) -> np.ndarray:
    """(n, 2) session-time intervals of the samples [start, stop) of each position (start,
    stop: ints or (n,) arrays), half a sample either side, from the session's first sample."""
    n = data.shape[0]
    start, stop = np.broadcast_to(start, (n,)), np.broadcast_to(stop, (n,))
    first, last = [], []
    for rows in data.chunks():
        times = data.session_times(rows)
        idx = np.arange(len(times))
        first.append(times[idx, start[rows]])
        last.append(times[idx, stop[rows] - 1])
    origin = data.session_times(slice(0, 1))[0, 0] - 0.5 / data.fs
    return np.stack([np.concatenate(first) - origin, np.concatenate(last) - origin + 1 / data.fs],
                    1)


def static_covariance(data) -> np.ndarray:
    """(n, n) Omega_SS: the walk's covariance of the static means per unit K^2."""
    s0, s1 = data.windows["static"]
    s = intervals(data, s0, s1)
    return mean_covariance(s, s)


def whitening(cov: np.ndarray, level: bool) -> tuple:
    """(L^-1, u) of a covariance (c, c), L its Cholesky factor: L^-1 x is x whitened, and with
    `level` u is L^-1 1 made a unit vector (the direction a free level takes), else None."""
    inverse = np.linalg.inv(np.linalg.cholesky(cov))
    if not level:
        return inverse, None
    u = inverse.sum(1)
    return inverse, u / np.linalg.norm(u)


def whitened(factor: tuple, x: np.ndarray) -> np.ndarray:
    """(c,) L^-1 x net of the free level's direction u (`whitening`): its sum of squares is the
    generalised least-squares chi2 of x with the level fitted."""
    inverse, u = factor
    z = inverse @ x
    return z if u is None else z - u * (u @ z)


def bin_factors(data) -> list:
    """Per sensor the whitening matrix (K, K) of a position's bin means net of their own level
    (the within-position part of the deviance, station.diagnose.linear): (I - u u^T) L^-1
    (`whitening`), under the white noise of a bin and the walk; the same for every position
    (one grid of samples per position)."""
    kb = data.shape[1] // data.bin
    edges = np.arange(kb) * data.bin / data.fs
    omega = mean_covariance(*[np.stack([edges, edges + data.bin / data.fs], 1)] * 2)
    eye = np.eye(kb)
    out = []
    for w, k in zip(data.sigma**2 / data.bin, data.random_walk, strict=True):
        inverse, u = whitening(w * eye + k**2 * omega, True)
        out.append(inverse - np.outer(u, u @ inverse))
    return out


def reading_variance(data) -> np.ndarray:
    """(n,) the walk's variance per unit K^2 of each Eq. (18) reading M_j = R_j - S_j (rotating
    less static mean; independent between positions: their windows do not overlap)."""
    r0 = data.windows["rotating"][0]
    rot, static = intervals(data, r0, data.rot_stop), intervals(data, *data.windows["static"])
    return (np.diag(mean_covariance(rot, rot)) + np.diag(mean_covariance(static, static))
            - 2 * np.diag(mean_covariance(rot, static)))


def static_factors(data) -> list:
    """Per sensor the `whitening` (with a free level) of the static means under the white noise
    of a static window and the walk `data.random_walk` (m,) (module notes)."""
    s0, s1 = data.windows["static"]
    white = data.sigma**2 / (s1 - s0) + data.kept
    omega = static_covariance(data)
    eye = np.eye(len(omega))
    return [whitening(w * eye + k**2 * omega, True)
            for w, k in zip(white, data.random_walk, strict=True)]


def fraction(data, a: int, z: int) -> np.ndarray:
    """(n,) the mean commanded rate over the samples [a, z) of each position over the steady
    rate: the share of the position's steady reading the twin has there."""
    return np.broadcast_to(data.rate, data.angle.shape)[:, a:z].mean(1) / data.c


def transients_whitened(data, raw: np.ndarray, white: np.ndarray) -> np.ndarray:
    """(n, 2, m) the spin-up and spin-down mean residuals raw (n, 2, m), white-noise variances
    `white` (n, 2, m), whitened per sensor by their covariance under white noise and the walk
    `data.random_walk` (`transients_covariance`)."""
    n = raw.shape[0]
    walk = transients_covariance(data)
    out = np.empty_like(raw)
    for i, k in enumerate(data.random_walk):
        cov = np.diag(white[:, :, i].ravel()) + k**2 * walk
        out[:, :, i] = whitened(whitening(cov, False), raw[:, :, i].ravel()).reshape(n, 2)
    return out


def transients_covariance(data) -> np.ndarray:
    """(2n, 2n) the walk's covariance per unit K^2 of the spin-up and spin-down mean residuals,
    ordered (position, ramp) (module notes)."""
    n, _, m = data.shape
    rho = min(1.0, D / m)
    ramps = np.stack([intervals(data, *data.windows[w]) for w in ("spinup", "spindown")],
                     1).reshape(2 * n, 2)
    whole = intervals(data, 0, data.shape[1])
    r0 = data.windows["rotating"][0]
    level = np.concatenate([intervals(data, r0, data.rot_stop),
                            intervals(data, *data.windows["static"])])
    sign = np.concatenate([np.ones(n), -np.ones(n)])  # R_j - S_j
    # X = ramp mean - G (G the mean over all positions' samples); Dl = R - S of its position
    x_x = mean_covariance(ramps, ramps)
    x_g = mean_covariance(ramps, whole).mean(1)
    x_x += mean_covariance(whole, whole).mean() - x_g[:, None] - x_g[None, :]
    own = np.repeat(np.arange(n), 2)  # the position of each ramp
    d_x = mean_covariance(level, ramps) - mean_covariance(level, whole).mean(1)[:, None]
    d_x = (sign[:, None] * d_x).reshape(2, n, 2 * n).sum(0)[own]  # Cov(Dl_own(a), X_b)
    d_l = sign[:, None] * mean_covariance(level, level) * sign[None, :]
    d_d = d_l.reshape(2, n, 2, n).sum((0, 2))[np.ix_(own, own)]
    share = np.where(own[:, None] == own[None, :], rho, rho**2)
    f = np.stack([fraction(data, *data.windows[w]) for w in ("spinup", "spindown")], 1).ravel()
    return (x_x - rho * (f[:, None] * d_x + (f[:, None] * d_x).T)
            + share * np.outer(f, f) * d_d)
