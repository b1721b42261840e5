"""The gap between the measured session and its twin, one number per statistic.

Each statistic is a mean of squared normalised residual features, so that 1 means "explained
to within the white noise" (sigma from the static windows):
- `averaged`: Eq. (18) readings M against the twin's M, chi2 / dof of the calibration.
- `static`: the per-position biases against one bias per sensor (static means against
  orientation: the Earth rate, warm-up, bias walk).
- `trend`: slopes within the static and the rotating windows.
- `harmonics`: Fourier coefficients of the rotating windows (whole revolutions) at 1, 2 and 3
  times the table rate and half-way between (0.5, 1.5, 2.5).
- `transients`: mean residuals over spin-up and over spin-down.
- `rails`: the rail pile-up deviance (station.diagnose.rails) per sensor and sign that holds the
  rail (about 1 when the twin expects what is seen, thousands for an unmodelled clip).
"""

import numpy as np

from station.diagnose import rails

HARMONICS = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0)
STATISTICS = ("averaged", "static", "trend", "harmonics", "transients", "rails")


def _slopes(r, t, sigma):
    """(n, m) slopes of r (n, k, m) against t (k,) in units of their standard error."""
    tc = t - t.mean()
    return np.einsum("k,nkm->nm", tc, r) / (sigma * np.sqrt(np.sum(tc**2)))


def statistics(data, model) -> dict:
    """{statistic: normalised gap} of a fitted model (station.diagnose.model.Model)."""
    sig = data.sigma
    r = data.y - model.prediction.z
    out = {"averaged": float(model.calibration.chi2 / max(model.calibration.dof, 1))}

    s0, s1 = data.windows["static"]
    b = r[:, s0:s1].mean(1)  # (n, m) static means net of the model
    w = (s1 - s0) / sig**2
    out["static"] = float(np.sum((b - b.mean(0)) ** 2 * w) / (b.size - b.shape[1]))

    r0 = data.windows["rotating"][0]
    slopes = [_slopes(r[:, s0:s1], data.t[s0:s1], sig)]
    coef = []
    for j in range(data.shape[0]):
        sl = slice(r0, data.rot_stop[j])
        rj, theta = r[j, sl], data.angle[j, sl] - data.angle[j, r0]
        slopes.append(_slopes(rj[None], data.t[sl], sig)[0][None])
        basis = np.concatenate([[np.cos(h * theta), np.sin(h * theta)] for h in HARMONICS])
        coef.append((basis @ rj) * np.sqrt(2 / theta.size) / sig)
    out["trend"] = float(np.mean(np.concatenate([s.ravel() for s in slopes]) ** 2))
    out["harmonics"] = float(np.mean(np.square(coef)))

    trans = [r[:, a:z].mean(1) * np.sqrt(z - a) / sig
             for a, z in (data.windows["spinup"], data.windows["spindown"])]
    out["transients"] = float(np.mean(np.square(trans)))

    n_obs = rails.observed(data)
    n_exp = rails.expected(data, model.prediction.mu, sig, clipped="saturation" in model.fitted)
    held = max(int(np.sum(n_obs > 0)), 1)
    out["rails"] = rails.deviance(n_obs, n_exp) / held
    return out
