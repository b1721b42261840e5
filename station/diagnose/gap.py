"""The gap between the measured session and its twin, one number per statistic.

Each statistic is a mean of squared normalised residual features, so that 1 means "explained
to within the white noise" (sigma from the static windows):
- `averaged`: Eq. (18) readings M against the twin's M, chi2 / dof of the calibration.
- `static`: the per-position biases against one bias per sensor (static means against
  orientation: the Earth rate, warm-up, bias walk).
- `trend`: slopes within the static and the rotating windows.
- `harmonics`: Fourier coefficients of the rotating windows (whole revolutions) at 1, 2 and 3
  times the table rate and half-way between (0.5, 1.5, 2.5), on a basis made orthonormal and
  free of the window's level (`harmonic_basis`): over few revolutions the half-way waves overlap
  each other and the level, and the level carries the fitted M's static noise (the `averaged`
  statistic's), so the raw coefficients are neither independent nor white.
- `transients`: mean residuals over spin-up and over spin-down, each over its null sd (white
  noise plus the share of the noise of M_j that the fitted level carries into the ramp).
With coloured noise in the noise model (`RotaryData.coloured`: a bias random walk, flicker),
`static` and `transients` are whitened by their covariance under it (station.diagnose.coloured):
still N(0, 1) features under the model and that noise.
- `rails`: the rail pile-up deviance (station.diagnose.rails) per sensor and sign that holds the
  rail (about 1 when the twin expects what is seen, thousands for an unmodelled clip).

Under white noise, statistic x dof is about chi2(dof) (`dofs`): the final goodness-of-fit test
(station.diagnose.goodness) reads the gaps against that law.
"""

import numpy as np

from station.diagnose import coloured, rails

HARMONICS = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0)
STATISTICS = ("averaged", "static", "trend", "harmonics", "transients", "rails")


def harmonic_basis(theta: np.ndarray) -> np.ndarray:
    """(2 len(HARMONICS), K) orthonormal rows spanning cos(h theta), sin(h theta) net of the
    constant, in that order (Gram-Schmidt by QR: row i is the part of wave i that the constant
    and the waves before it do not hold). White noise of unit variance projects onto them as
    independent N(0, 1) coefficients whatever the span of theta; a wave the others already hold
    (sin(theta / 2) over one turn is mostly the level) keeps only its own remainder."""
    waves = np.concatenate([[np.cos(h * theta), np.sin(h * theta)] for h in HARMONICS])
    q, _ = np.linalg.qr(np.vstack([np.ones_like(theta), waves]).T)
    return q[:, 1:].T


def features(data, model) -> dict:
    """{statistic: (n, q, m) normalised residual features (N(0, 1) under white noise)} of the
    statistics built from features (all but `averaged`'s calibration chi2 and `rails`):
    static (n, 1, m), trend (n, 2, m: static and rotating window), harmonics (n, 2 x
    len(HARMONICS), m), transients (n, 2, m: spin-up, spin-down). The residuals are made a
    chunk of positions at a time (station.diagnose.prediction.Twin)."""
    sig = data.sigma
    s0, s1 = data.windows["static"]
    twin, chunks = model.twin, []
    for rows in data.chunks():
        r = twin.residual(rows)
        chunks.append((r[:, s0:s1].mean(1), _local(data, r, rows, sig),
                       [r[:, a:z].mean(1) for a, z in (data.windows["spinup"],
                                                        data.windows["spindown"])]))
    b, local, ramps = (list(x) for x in zip(*chunks, strict=True))
    b, local = np.concatenate(b), np.concatenate(local)  # (n, m), (n, 2 + 2 H, m)
    n = b.shape[0]
    static = data.static_whitened(b) * np.sqrt(n / max(n - 1, 1))
    raw = np.stack([np.concatenate([c[i] for c in ramps]) for i in range(2)], 1)  # (n, 2, m)
    white = np.stack([sig**2 / (z - a) * (1 + _level_noise(data, a, z)) + data.kept
                      for a, z in (data.windows["spinup"], data.windows["spindown"])], 1)
    trans = (coloured.transients_whitened(data, raw, white) if data.correlated
             else raw / np.sqrt(white))
    return {"static": static[:, None], "trend": local[:, :2], "harmonics": local[:, 2:],
            "transients": trans}


def local_rows(data, j: int) -> np.ndarray:
    """(2 + 2 len(HARMONICS), k) the weights over position j's samples of its local features, each
    of unit variance under white noise of unit variance: the slopes within the static and the
    whole-revolution rotating window (the time centred, over its norm) and the harmonic
    coefficients of the rotating window (`harmonic_basis`)."""
    out = np.zeros((2 + 2 * len(HARMONICS), data.shape[1]))
    r0, r1 = data.windows["rotating"][0], data.rot_stop[j]
    for row, (a, z) in enumerate((data.windows["static"], (r0, r1))):
        tc = data.t[a:z] - data.t[a:z].mean()
        out[row, a:z] = tc / np.sqrt(np.sum(tc**2))
    out[2:, r0:r1] = harmonic_basis(data.angle[j, r0:r1] - data.angle[j, r0])
    return out


def _local(data, r: np.ndarray, rows: slice, sig: np.ndarray) -> np.ndarray:
    """(p, 2 + 2 len(HARMONICS), m) the local features (`local_rows`) of the residuals r
    (p, k, m) of the positions `rows`, over the white noise sig (m,); with coloured noise in the
    model or a sensor quantised coarser than its noise whitened by their covariance under them
    (station.diagnose.coloured.local_whitened)."""
    out, whiten = [], data.correlated
    for rj, j in zip(r, data.positions(rows), strict=True):
        weights = local_rows(data, j)
        f = weights @ rj / sig
        out.append(coloured.local_whitened(data, weights, f) if whiten else f)
    return np.array(out)


def _level_noise(data, a: int, z: int) -> np.ndarray:
    """(n, m) variance a ramp window [a, z)'s mean residual gets from the twin's steady level,
    in units of its white-noise variance: the calibration fits each position's level to the
    measured M_j (v_j: d parameters from m readings, a share of about d / m of its noise e_j,
    at most all of it), and the ramp window sees that level times the mean rate fraction f
    over the window: f^2 (z - a) sigma_M^2 / sigma^2 x min(1, d / m)."""
    frac = coloured.fraction(data, a, z)
    share = min(1.0, coloured.D / data.shape[2])
    return frac[:, None] ** 2 * (z - a) * (data.sigma_m.T / data.sigma) ** 2 * share


def averaged_features(data, model) -> np.ndarray:
    """(n, 1, m) Eq. (18) reduction of the twin's residual series over the standard error of M:
    where the readings M miss the twin, per position and sensor (the `averaged` statistic's
    pattern; its value is the calibration's own chi2 / dof)."""
    twin = model.twin
    m = np.concatenate([data.reduce(twin.residual(rows), rows).M for rows in data.chunks()], 1)
    return (m / data.sigma_m).T[:, None]


def statistics(data, model) -> dict:
    """{statistic: normalised gap} of a fitted model (station.diagnose.model.Model)."""
    out = {"averaged": float(model.calibration.chi2 / max(model.calibration.dof, 1))}
    feats = features(data, model)
    out.update({k: float(np.mean(f**2)) for k, f in feats.items()})
    out["rails"] = _rails(data, model)[0]
    return out


def _rails(data, model) -> tuple[float, int]:
    """(rail deviance per held side, sides holding the rail (at least 1))."""
    n_obs = rails.observed(data)
    twin, clipped = model.twin, "saturation" in model.fitted
    n_exp = sum(rails.expected(data, part.mu, data.sigma, clipped,
                               data.rail_offsets(part.mu, rows)) for rows, part in twin.parts())
    held = max(int(np.sum(n_obs > 0)), 1)
    return rails.deviance(n_obs, n_exp) / held, held


def dofs(data, model) -> dict:
    """{statistic: degrees of freedom}: under white noise, gap x dof ~ chi2(dof)."""
    n, _, m = data.shape
    return {"averaged": max(model.calibration.dof, 1), "static": (n - 1) * m,
            "trend": 2 * n * m, "harmonics": 2 * len(HARMONICS) * n * m,
            "transients": 2 * n * m, "rails": _rails(data, model)[1]}
