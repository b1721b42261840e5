"""Extension `temperature`: the biases follow the unit's recorded temperature.

Model: offset_i(t) = bias_i (T(t) - t_ref), T the session's recorded temperature (its own
channel, K) at the samples, smoothed by a running mean of `SMOOTH_SECONDS` within each position
(the channel is quantised, 1/326.8 K on InvenSense parts, with about 0.02 K of noise per sample:
the mean leaves millikelvin, against excursions of kelvins). The offsets are linear in the bias_i
(per sensor, m parameters, LR ~ chi2(m) without the effect); t_ref (the session's mean
temperature) only moves the biases. Signature against the per-position bias of Eq. (18): the
static means across positions follow T, the trends within positions follow its slope. Unlike
`bias_drift` (a function of session time and the table rate), it follows T wherever T goes, so a
temperature that rises and falls again, or that is flat while the biases drift, tells the two
apart.

Offered only when the session records a temperature (`RotaryData.temperature`) whose smoothed
range over the session reaches `MIN_EXCURSION` (`available`). The scale factors' tempcos
(`station.model.effects.temperature`'s scale, scale2) and its hysteresis are not fitted.
"""

import numpy as np
from scipy.ndimage import uniform_filter1d

from station.diagnose import linear
from station.diagnose.effects import Fitted
from station.model.effects.temperature import Temperature, bias_offsets

GAPS = ("static", "trend")
"""Gap statistics (station.diagnose.gap) that hold this effect's signature: it is not named
while one of them stays unexplained (station.diagnose.select.settle)."""
STAGE = "added"
SMOOTH_SECONDS = 1.0
"""s: running mean of the recorded temperature (quantisation and sensor noise)."""
MIN_EXCURSION = 0.2
"""K: smallest range of the smoothed temperature over the session for the candidate to be
offered (ten times the sensor's noise per sample; below it there is nothing to regress on)."""


def smoothed(data, rows: slice = slice(None)) -> np.ndarray | None:
    """(p, k) the recorded temperature at the positions `rows`, K, smoothed within each
    position; None without one."""
    if data.temperature is None:
        return None
    size = max(1, round(SMOOTH_SECONDS * data.fs))
    return uniform_filter1d(np.asarray(data.temperature[rows], float), size, axis=1,
                            mode="nearest")


def available(data) -> bool:
    """True when the session records a temperature that moves by MIN_EXCURSION or more."""
    t = smoothed(data)
    return t is not None and float(t.max() - t.min()) >= MIN_EXCURSION


def fit(ctx, twin, r) -> Fitted:
    """bias (m,) in output units per K, by weighted least squares per sensor."""
    t = smoothed(ctx.data)
    t_ref = float(t.mean())
    lf = linear.fit_binned(r, [linear.centred(ctx.data, (t - t_ref)[..., None])],
                           linear.weights(ctx.data, ctx.sigma), "sensor")
    return Fitted(
        "temperature",
        {"bias": lf.theta[:, 0], "t_ref": t_ref, "excursion": float(t.max() - t.min())},
        {"bias": np.sqrt(lf.cov[:, 0, 0]), "t_ref": np.nan, "excursion": np.nan},
        dof=lf.theta.shape[0],
        reduction=lf.reduction(),
        units={"bias": "output units per K", "t_ref": "K", "excursion": "K"},
        notes="bias tempcos against the recorded temperature (smoothed); t_ref is the session "
        "mean; scale tempcos and hysteresis are not fitted",
    )


def params(fitted: Fitted) -> Temperature:
    """The simulator's parameters of the fitted tempcos (station.model.effects.temperature)."""
    return Temperature(bias=tuple(fitted.value("bias")), t_ref=float(fitted.values["t_ref"]))


def apply(ctx, fitted: Fitted, rows: slice) -> np.ndarray:
    """(p, k, m) bias offsets at the recorded temperature at the positions `rows`
    (station.model.effects.temperature)."""
    p = params(fitted)
    return bias_offsets(smoothed(ctx.data, rows) - p.t_ref, p)
