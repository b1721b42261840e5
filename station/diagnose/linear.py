"""Weighted least squares of residual time series on effect signatures, on binned samples.

An effect's signature is the change it makes to the twin's noise-free series per unit of a
parameter. Series are averaged over bins of `RotaryData.bin` samples (white noise of standard
deviation sigma_i per sample leaves sigma_i / sqrt(bin) per bin). Two parts enter the chi2:
- within positions: bins centred on their position's mean (Eq. 18 gives each position its own
  bias): trends, tones, transients, the rotating level against the static one;
- across positions: the static-window means centred on one bias per sensor (static means
  against orientation: warm-up, Earth rate), weighted by their own noise sigma_i / sqrt(N_s).
The static means share their noise with the first part's static bins, a small double count
that the selection's significance level absorbs. Parameters are separate per sensor, per position or
global, which keeps each normal-equation block small.
"""

from dataclasses import dataclass

import numpy as np

BLOCKS = {"sensor": "m", "position": "n", "global": ""}


def centred_bins(data, x: np.ndarray) -> np.ndarray:
    """Bin means of x (n, k, m) minus their mean over each position: (n, K, m)."""
    b = data.bins(x)
    return b - b.mean(1, keepdims=True)


def centred_static(data, x: np.ndarray) -> np.ndarray:
    """Static-window means of x (n, k, m) minus their mean over the positions: (n, m)."""
    s0, s1 = data.windows["static"]
    b = x[:, s0:s1].mean(1)
    return b - b.mean(0)


def signature_parts(data, make) -> tuple:
    """(centred_bins (n, K, m'), static-window means (n, m', not centred)) of a series (a
    signature, a residual) made a chunk of positions at a time (`RotaryData.chunks`) by
    make(rows) -> (len(rows), k, m') for the positions `rows` (a slice), so that no series of
    the session's size is held: both parts are per position, the same numbers as from the whole
    series."""
    s0, s1 = data.windows["static"]
    bins, means = [], []
    for rows in data.chunks():
        x = make(rows)
        bins.append(centred_bins(data, x))
        means.append(x[:, s0:s1].mean(1))
        del x  # before the next chunk is made
    return np.concatenate(bins), np.concatenate(means)


def centred_signature(data, make) -> tuple:
    """(centred_bins, centred_static) of the series make(rows) (`signature_parts`): what
    `centred` gives of the whole series."""
    bins, means = signature_parts(data, make)
    return bins, means - means.mean(0)


def weights(data, sigma: np.ndarray) -> tuple:
    """(m,) weights of a bin and of a static mean (each its variance: the white noise's over its
    samples and the quantisation error it keeps, `RotaryData.kept`; a bin's as
    `RotaryData.bin_variance`)."""
    s0, s1 = data.windows["static"]
    return 1 / (sigma**2 / data.bin + data.kept), 1 / (sigma**2 / (s1 - s0) + data.kept)


def chi2(data, r: tuple, sigma: np.ndarray) -> float:
    """chi2 of residuals given as their centred parts r = (bins (n, K, m), static means (n, m)):
    within positions plus static means across positions; with coloured noise in the noise
    model (`RotaryData.coloured`: a bias random walk, flicker) or a sensor quantised coarser than
    its noise (`RotaryData.correlated`) both by generalised least squares
    (station.diagnose.coloured; the effects' fits keep the white weights: their chi2 decrease
    under the walk can only be smaller than its own optimum's, a conservative likelihood
    ratio)."""
    w, ws = weights(data, sigma)
    if not data.correlated:
        return float(np.sum(r[0] ** 2 * w) + np.sum(r[1] ** 2 * ws))
    bins = sum(np.sum((r[0][..., i] @ f.T) ** 2) for i, f in enumerate(data.bin_whitening))
    return float(bins + np.sum(data.static_whitened(r[1]) ** 2))


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


def centred(data, x: np.ndarray) -> tuple:
    """(centred_bins, centred_static) of x."""
    return centred_bins(data, x), centred_static(data, x)


def fit_binned(r: tuple, basis: list, w: tuple, by: str) -> LinearFit:
    """Least-squares coefficients of the signatures `basis` explaining the residuals r, one
    coefficient set per sensor, per position or global (`by`), on centred parts: r = (bins
    (n, K, m), static (n, m)), each signature the same with m or 1 sensors, w = (bin weights,
    static weights) (m,)."""
    out = BLOCKS[by]
    p = len(basis)
    h, g = 0.0, 0.0
    for part, sub in ((0, "nk"), (1, "n")):
        rp = r[part]
        x = np.stack([np.broadcast_to(b[part], rp.shape) for b in basis], -1)
        h = h + np.einsum(f"{sub}mp,{sub}mq,m->{out}pq", x, x, w[part]).reshape(-1, p, p)
        g = g + np.einsum(f"{sub}mp,{sub}m,m->{out}p", x, rp, w[part]).reshape(-1, p)
    cov = np.linalg.pinv(h)
    return LinearFit(np.einsum("bpq,bq->bp", cov, g), cov, h, g)


def sensed_signatures(ctx, twin, apply, units) -> tuple:
    """([centred (bins, static means) of each unit term], peak |s| (m,)): the output's change
    apply(s, unit) - s for the simulator's own effect function `apply` at each of the unit
    coefficients `units` (scale_nonlinearity's s^2, scale_asymmetry's |s|, the polynomial's
    powers), made in one pass a chunk of positions at a time from the twin's sensed signal s."""
    peaks = []

    def signature(rows: slice) -> np.ndarray:
        s = twin.sensed(rows)
        peaks.append(np.abs(s).max((0, 1)))
        out = np.concatenate([apply(s, unit) for unit in units], axis=-1)
        out -= np.concatenate([s] * len(units), axis=-1)
        return out

    bins, means = centred_signature(ctx.data, signature)
    m = bins.shape[-1] // len(units)
    return ([(bins[..., i * m:(i + 1) * m], means[:, i * m:(i + 1) * m])
             for i in range(len(units))], np.max(peaks, 0))


def sensed_term(ctx, twin, r: tuple, apply, unit) -> tuple:
    """(fit, peak |s| (m,)) of one per-sensor term of the sensed signal (`sensed_signatures`),
    fitted per sensor to the residuals' centred parts r (`fit_binned`)."""
    (term,), peak = sensed_signatures(ctx, twin, apply, [unit])
    return fit_binned(r, [term], weights(ctx.data, ctx.sigma), "sensor"), peak


def phase_fit(data, r: tuple, tone, sigma: np.ndarray) -> tuple:
    """A tone of one amplitude and a free phase per position, fitted to the residuals' centred
    parts r (`fit_binned`). tone(phase_deg, rows) -> (len(rows),
    k, m) its signature at unit amplitude and that phase for the positions `rows` (a slice); each
    of the two quadrature signatures (0 and 90 degrees) is reduced to its centred bins and static
    means a few positions at a time (`signature_parts`): the tone of any phases is combined from
    them (a per-position factor commutes with the bins' centring within a position, not with the
    static means' across positions, which are centred after). Returns (free, phase, lf,
    static): the per-position fit of the quadrature pair (its h gives the null law), the phases
    (n,) in radians, the global fit of the amplitude on the tone of those phases, and that
    tone's static-window means (n, m)."""
    w = weights(data, sigma)
    quadrature = [signature_parts(data, lambda rows, deg=deg: tone(deg, rows))
                  for deg in (0.0, 90.0)]
    free = fit_binned(r, [(b, m - m.mean(0)) for b, m in quadrature], w, "position")
    phase = np.arctan2(free.theta[:, 1], free.theta[:, 0])
    c, s = np.cos(phase), np.sin(phase)
    (b0, m0), (b90, m90) = quadrature
    bins = c[:, None, None] * b0 + s[:, None, None] * b90
    means = c[:, None] * m0 + s[:, None] * m90
    return free, phase, fit_binned(r, [(bins, means - means.mean(0))], w, "global"), means
