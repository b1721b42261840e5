"""Coloured noise in the noise model: a bias random walk and flicker (issue 32).

A unit's bias wanders: a random walk K W(t) (W a unit Brownian motion; K in units / sqrt(s),
IEEE 952's rate random walk) and flicker of bias instability B (its Allan deviation's floor B
sqrt(2 ln 2 / pi); docs/noise.md). Both are in a calibration file's noise figures, measured on a
long rest by `station noise` (`RotaryData.random_walk`, `RotaryData.bias_instability`). They
move every window mean of a session: the static means wander across positions, the spin-up and
spin-down means stand off the session's one bias, the bins of a position drift. Against white
noise alone the gap statistics of such a unit fail and the effects that move static means
(drifts, jumps) look significant; with the terms in the noise model they are judged against the
real noise, by generalised least squares.

Both have stationary increments, described by their variogram gamma(tau) = E[(b(t + tau) -
b(t))^2] / 2:

    random walk  K^2 |tau| / 2          flicker  (B^2 / pi) ln |tau| + const

(the flicker's from its PSD B^2 / (2 pi f): it gives the Allan variance (2 ln 2 / pi) B^2 of
docs/noise.md, and its constant, set by the sampling, drops out below). For window means that
are contrasts (weights c summing to zero), Cov(c . b, d . b) = - sum_jk c_j d_k E[gamma(U_j -
V_k)], U_j uniform on window j's time span: `mean_variogram` integrates E|U - V| and
E ln|U - V| exactly from their second antiderivatives |z|^3 / 6 and z^2 ln|z| / 2 - 3 z^2 / 4
(two equal windows of length L: L / 3 and ln L - 3 / 2). A mean of N samples differs from the
uniform mean over their span by about 1 / (6 N fs) s in a walk's variance, and the sampled
flicker's by at most 0.04 % for N >= 64 (docs/noise.md's table): below anything a session shows.

- Static means S_j (n positions) net of one level, and the bins of a position net of their own
  level: generalised least squares with a free level is the chi2 of the error contrasts
  (Harville 1974), Q^T x for Q an orthonormal basis of the vectors orthogonal to 1, whose
  covariance the variograms give whole (`level_free_whitening`); with white noise alone, the
  weighted sum of squares of the centred values.
- Spin-up and spin-down means (the `transients`): the residual of ramp window X_j is its mean
  less the session's bias (the mean over all samples, G) less the twin's level there, f_j times
  the fitted reading's share of R_j - S_j (rotating less static mean, Eq. 18): the calibration
  fits v_j to the m readings of position j, a projection of about rho = min(1, d / m) of their
  noise (as `station.diagnose.gap` takes it for the white noise), so its coloured part has
  covariance rho Omega (the same position) or rho^2 Omega (two positions' independent fits),
  and rho Omega with the ramp's own (`transients_covariance`).
- The local features of a position (`trend`'s slopes, `harmonics`' waves: contrasts within a
  window): their covariance from their weights summed per bin against the bins' variograms
  (`local_whitened`; a walk or flicker hardly moves within 0.1 s).
- Free-static sessions (station.diagnose.static): the poses' means, whose model has a free
  bias per channel, with `level_covariance`; within a pose the bins stay white.
- The readings M_j = R_j - S_j: the variance of the contrast (`reading_variance`); different
  positions' windows do not overlap, and over the gaps a walk's increments are independent,
  flicker's nearly so (left out).
- The rail pile-up's expected counts (station.diagnose.rails) are those of the twin moved by
  what each position's static window stands off it (`RotaryData.rail_offsets`): the rail is the
  session's extreme count, found at the peak of one position's signal, and the few samples
  reading it depend on that position's level to a fraction of the noise (the bench's walking
  units: 2 of 25 effect-free sessions said `rails` unexplained without it, none with it).
  Within a position the walk moves the level by K sqrt(10 s), a few per cent of the noise: left
  out.
"""

import numpy as np

D = 3
"""Components of the stimulus v_j fitted per position (the level's share rho = min(1, D / m))."""
TERMS = ("random_walk", "bias_instability")
"""The coloured terms, as `RotaryData` and a calibration file's noise figures name them."""


def _walk_antiderivative(z):
    return np.abs(z) ** 3 / 6.0


def _flicker_antiderivative(z):
    z2 = z * z
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(z2 > 0, 0.5 * z2 * np.log(np.abs(z)) - 0.75 * z2, 0.0)


UNIT_VARIOGRAM = {"random_walk": (_walk_antiderivative, 0.5),
                  "bias_instability": (_flicker_antiderivative, 1.0 / np.pi)}
"""Term -> (second antiderivative of |tau| or ln|tau|, the variogram's factor per unit K^2 or
B^2)."""


def mean_variogram(a: np.ndarray, b: np.ndarray, term: str) -> np.ndarray:
    """(p, q) E[gamma(U - V)] of one unit term (`UNIT_VARIOGRAM`) for U uniform on each
    interval of a (p, 2) and V on each of b (q, 2), seconds (module notes)."""
    antiderivative, factor = UNIT_VARIOGRAM[term]
    a0, a1 = a[:, 0, None], a[:, 1, None]
    b0, b1 = b[None, :, 0], b[None, :, 1]
    total = (antiderivative(a1 - b0) - antiderivative(a1 - b1) - antiderivative(a0 - b0)
             + antiderivative(a0 - b1))
    return factor * total / ((a1 - a0) * (b1 - b0))


def level_covariance(spans: np.ndarray, term: str) -> np.ndarray:
    """(c, c) a covariance of one unit term's means over the windows `spans` (c, 2) for a model
    with a free level: the variogram's contrasts and a level of the session's size, L / 2 for
    the walk and ln(L) / pi for flicker, L the span of all the windows (the triangular kernel
    (L - |tau|) / 2 and the logarithmic kernel ln(L / |tau|) are positive definite on a stretch
    of length L: what the level adds is the free level's, which the model fits)."""
    length = spans[:, 1].max() - spans[:, 0].min()
    level = length / 2 if term == "random_walk" else np.log(length) / np.pi
    return level - mean_variogram(spans, spans, term)


def present(data) -> list:
    """[(term, (m,) its variance scale K^2 or B^2)] of the coloured terms in the noise model."""
    return [(t, np.asarray(getattr(data, t), float) ** 2) for t in TERMS
            if getattr(data, t) is not None]


def intervals(data, start, stop) -> np.ndarray:
    """(n, 2) session-time spans of the samples [start, stop) of each position (start, stop:
    ints or (n,) arrays), half a sample either side, from the session's first sample."""
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


def sensor_covariances(white, shapes: list) -> list:
    """Per sensor i the (c, c) covariance diag(white[i]) + sum_t scale_t[i] shape_t: its white
    noise (a variance per value, or one for all) and the coloured terms' covariances per unit
    K^2 or B^2, shapes [(scale_t (m,), shape_t (c, c))]."""
    size = len(shapes[0][1])
    return [np.diag(np.broadcast_to(w, (size,))) + sum(scale[i] * g for scale, g in shapes)
            for i, w in enumerate(white)]


def level_free_whitening(white: np.ndarray, spans: np.ndarray, terms: list,
                         covariances=()) -> list:
    """Per sensor (c, c) W with W x the values x (c,) at the windows `spans` (c, 2) whitened net
    of a free level (its last entry 0): white noise of variance white[i] per value, the
    coloured terms [(term, scale (m,))] (module notes) and further covariances [(scale (m,),
    (c, c) per unit scale)]; sum (W x)^2 is their generalised least-squares chi2."""
    c = len(spans)
    q = np.linalg.qr(np.ones((c, 1)), mode="complete")[0][:, 1:]  # orthonormal, orthogonal to 1
    shapes = [(scale, -(q.T @ mean_variogram(spans, spans, term) @ q)) for term, scale in terms]
    shapes += [(scale, q.T @ g @ q) for scale, g in covariances]
    out = []
    for cov in sensor_covariances(white, shapes):
        whitening = np.zeros((c, c))
        whitening[:-1] = np.linalg.solve(np.linalg.cholesky(cov), q.T)
        out.append(whitening)
    return out


def static_factors(data) -> list:
    """Per sensor the `level_free_whitening` of the static means under the white noise of a
    static window and the coloured terms."""
    s0, s1 = data.windows["static"]
    return level_free_whitening(data.sigma**2 / (s1 - s0) + data.kept, intervals(data, s0, s1),
                                present(data))


def bin_spans(data) -> np.ndarray:
    """(K, 2) the time spans of a position's bins (`RotaryData.bins`) from its first sample."""
    edges = np.arange(data.shape[1] // data.bin) * data.bin / data.fs
    return np.stack([edges, edges + data.bin / data.fs], 1)


def bin_factors(data) -> list:
    """Per sensor the `level_free_whitening` of a position's bin means (the within-position part
    of the deviance, station.diagnose.linear), the same for every position (one grid of samples
    per position): within a position a walk or flicker is a slow wander that the effects' shapes
    there (a tone at the table rate, a ramp) would otherwise take up. Each bin keeps its
    quantisation error (`RotaryData.bin_variance`) and each window's level one more, common to
    its bins (`window_levels`: the error of a steady signal, which the level of the rotating
    window against the static one would otherwise average down over its bins)."""
    return level_free_whitening(data.bin_variance, bin_spans(data), present(data),
                                [(data.kept, window_levels(data))])


def window_levels(data) -> np.ndarray:
    """(K, K) the covariance of a position's bin means that one unit error per window common to
    its samples gives (static, spin-up, the rotating window to the spin-down, spin-down): the
    bins' shares of each window, B B^T."""
    kb = data.shape[1] // data.bin
    first = np.arange(kb) * data.bin
    ends = [data.windows["static"], data.windows["spinup"],
            (data.windows["rotating"][0], data.windows["spindown"][0]), data.windows["spindown"]]
    share = np.stack([np.clip(np.minimum(first + data.bin, z) - np.maximum(first, a), 0, None)
                      for a, z in ends], 1) / data.bin
    return share @ share.T


def local_whitened(data, weights: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(q, m) a position's local features f (q, m) (station.diagnose.gap.local_rows: weights
    (q, k) over its samples, unit white variance; each a contrast) whitened per sensor by their
    covariance under white noise, the coloured terms and the quantisation error each bin keeps
    (`RotaryData.bin_variance`). A slow wander and that error are read on the bins: the weights
    summed within each bin, against the bins' variograms (`RotaryData.coloured_bins_
    variograms`) and the kept variance."""
    q, m = f.shape
    kb = data.shape[1] // data.bin
    binned = weights[:, : kb * data.bin].reshape(q, kb, data.bin).sum(2)
    shapes = [(scale / data.sigma**2, -binned @ gamma @ binned.T)
              for scale, gamma in data.coloured_bins_variograms]
    shapes.append((data.kept / data.sigma**2, binned @ binned.T))
    out = np.empty_like(f)
    for i, cov in enumerate(sensor_covariances(np.ones(m), shapes)):
        out[:, i] = np.linalg.solve(np.linalg.cholesky(cov), f[:, i])
    return out


def reading_variance(data) -> np.ndarray:
    """(m, n) the coloured terms' variance of each Eq. (18) reading M_j = R_j - S_j (rotating
    less static mean)."""
    r0 = data.windows["rotating"][0]
    rot, static = intervals(data, r0, data.rot_stop), intervals(data, *data.windows["static"])
    out = np.zeros((data.shape[2], data.shape[0]))
    for term, scale in present(data):

        def paired(x, y, term=term):  # E gamma between the windows of one position
            return np.diagonal(mean_variogram(x, y, term))

        variance = 2 * paired(rot, static) - paired(rot, rot) - paired(static, static)
        out += scale[:, None] * variance[None, :]
    return out


def fraction(data, a: int, z: int) -> np.ndarray:
    """(n,) the mean commanded rate over the samples [a, z) of each position over the steady
    rate: the share of the position's steady reading the twin has there."""
    return np.broadcast_to(data.rate, data.angle.shape)[:, a:z].mean(1) / data.c


def transients_whitened(data, raw: np.ndarray, white: np.ndarray) -> np.ndarray:
    """(n, 2, m) the spin-up and spin-down mean residuals raw (n, 2, m), white-noise variances
    `white` (n, 2, m), whitened per sensor by their covariance under white noise, the coloured
    terms (`transients_covariance`) and the static level's quantisation error: the static
    signal is the same at every position (the bias; the Earth rate is far below a coarse step),
    so the error its mean keeps is common to all positions, taken into the fitted bias and seen
    by every ramp against it (`RotaryData.kept`, each ramp's own in `white`)."""
    n, _, m = raw.shape
    shapes = [(scale, transients_covariance(data, term)) for term, scale in present(data)]
    shapes.append((data.kept, np.ones((2 * n, 2 * n))))
    out = np.empty_like(raw)
    for i, cov in enumerate(sensor_covariances(white.reshape(2 * n, m).T, shapes)):
        out[:, :, i] = np.linalg.solve(np.linalg.cholesky(cov),
                                       raw[:, :, i].ravel()).reshape(n, 2)
    return out


def transients_covariance(data, term: str) -> np.ndarray:
    """(2n, 2n) one unit coloured term's covariance of the spin-up and spin-down mean residuals,
    ordered (position, ramp) (module notes): every one a contrast, - sum c_j d_k E gamma."""
    n, _, m = data.shape
    rho = min(1.0, D / m)
    ramps = np.stack([intervals(data, *data.windows[w]) for w in ("spinup", "spindown")],
                     1).reshape(2 * n, 2)
    whole = intervals(data, 0, data.shape[1])
    r0 = data.windows["rotating"][0]
    level = np.concatenate([intervals(data, r0, data.rot_stop),
                            intervals(data, *data.windows["static"])])
    sign = np.concatenate([np.ones(n), -np.ones(n)])  # R_j - S_j

    def cov(x, y):  # covariance of window means, up to terms that cancel in contrasts
        return -mean_variogram(x, y, term)

    # X = ramp mean - G (G the mean over all positions' samples); Dl = R - S of its position
    x_g = cov(ramps, whole).mean(1)
    x_x = cov(ramps, ramps) + cov(whole, whole).mean() - x_g[:, None] - x_g[None, :]
    own = np.repeat(np.arange(n), 2)  # the position of each ramp
    d_x = cov(level, ramps) - cov(level, whole).mean(1)[:, None]
    d_x = (sign[:, None] * d_x).reshape(2, n, 2 * n).sum(0)[own]  # Cov(Dl_own(a), X_b)
    d_l = sign[:, None] * cov(level, level) * sign[None, :]
    d_d = d_l.reshape(2, n, 2, n).sum((0, 2))[np.ix_(own, own)]
    share = np.where(own[:, None] == own[None, :], rho, rho**2)
    f = np.stack([fraction(data, *data.windows[w]) for w in ("spinup", "spindown")], 1).ravel()
    return (x_x - rho * (f[:, None] * d_x + (f[:, None] * d_x).T)
            + share * np.outer(f, f) * d_d)
