"""The signature of an unexplained gap, so that an engineer can name the effect.

For a gap statistic that fails the final goodness-of-fit test (station.diagnose.goodness), its
normalised residual features F (n positions, q components, m sensors; station.diagnose.gap) are
broken down (each mean of F^2 is 1 under white noise):
- by sensor and by position, and by component (harmonic, window, ramp);
- against the sensor axes' projection on the table axis, (a_i . u_j)^2 / |a_i|^2 (on a level
  table also the gravity direction): the correlation over (position, sensor);
- when in the session: correlation of the per-position gap with the position's start time,
  with the sign of its rate, and its first harmonic in the table angle at the start of turning.
Plus, once per session, the spectrum of the rotating windows' residual: per position the
residual rate in the unit frame (least squares through a) less its mean over the window (the
level is the `averaged` statistic's), its table-plane part as the complex
p + i q and its axial part, Fourier coefficients at f x the table angle;
|C(f)|^2 over its white-noise expectation, averaged over positions (1 = noise), on the grid
of `frequencies`. Positive f turns
with the table in the unit's frame (axis wobble: +1), negative against it (a rate fixed in
space, the Earth's: -1); between the table-rate harmonics it shows coning or vibration at other
frequencies.
"""

import numpy as np
from scipy.stats import chi2

from station.diagnose import gap
from station.diagnose.goodness import log_sf

HIGHEST = 4.0
"""Highest multiple of the table rate at which the residual spectrum is read."""


def frequencies(data) -> np.ndarray:
    """Multiples of the table rate at which the residual spectrum is read: steps of a quarter
    of the resolution 1 / R (R the fewest whole revolutions of a position; a tone between two
    points loses at most 5 % of its power) from one step up to HIGHEST."""
    r0 = data.windows["rotating"][0]
    rows = np.arange(data.shape[0])
    turns = np.abs(data.angle[rows, data.rot_stop - 1] - data.angle[rows, r0]) / (2 * np.pi)
    step = 0.25 / max(round(float(turns.min())), 1)
    return np.arange(1, round(HIGHEST / step) + 1) * step
COMPONENTS = {"static": ["static mean"], "trend": ["static window", "rotating window"],
              "harmonics": [f"{h:g}x table rate {q}" for h in gap.HARMONICS
                            for q in ("cos", "sin")],
              "transients": ["spin-up", "spin-down"], "averaged": ["M"]}


def _corr(x: np.ndarray, y: np.ndarray) -> float:
    """Pearson correlation of two arrays (0 when one is constant)."""
    x, y = np.ravel(x) - np.mean(x), np.ravel(y) - np.mean(y)
    den = np.sqrt(np.sum(x**2) * np.sum(y**2))
    return float(np.sum(x * y) / den) if den > 0 else 0.0


def _angle_harmonic(values: np.ndarray, angle: np.ndarray) -> float:
    """Fraction of the variance of values (n,) explained by cos, sin of the angle (n,)."""
    x = np.stack([np.ones_like(angle), np.cos(angle), np.sin(angle)], 1)
    fit = x @ np.linalg.lstsq(x, values, rcond=None)[0]
    total = np.sum((values - values.mean()) ** 2)
    return float(1 - np.sum((values - fit) ** 2) / total) if total > 0 else 0.0


def describe(data, model, statistic: str) -> dict:
    """The signature of one gap statistic of a fitted model (see the module docstring)."""
    if statistic == "rails":
        return {"note": "pile-up at the output rails: the outputs reach a rail the twin does not "
                "expect (a clip, a range or count-size change)"}
    f = (gap.averaged_features(data, model) if statistic == "averaged"
         else gap.features(data, model)[statistic])
    power = f**2
    per = power.mean(1)  # (n, m)
    u = model.ctx.orientation[:, :, 2]  # (n, 3)
    a = model.ctx.a
    projection = (u @ a) ** 2 / np.sum(a**2, 0)
    r0 = data.windows["rotating"][0]
    rate = np.broadcast_to(data.rate, data.angle.shape)
    return {
        "by_sensor": power.mean((0, 1)),
        "by_position": power.mean((1, 2)),
        "by_component": dict(zip(COMPONENTS[statistic], power.mean((0, 2)), strict=True)),
        "correlation_with_table_axis_projection": _corr(per, projection),
        "correlation_with_time": _corr(per.mean(1), data.t0),
        "correlation_with_rate_sign": _corr(per.mean(1), np.sign(rate[:, r0:].mean(1))),
        "table_angle_harmonic_r2": _angle_harmonic(per.mean(1), data.angle[:, r0]),
    }


def spectrum(data, model) -> dict:
    """{"frequency": f, "with_table", "against_table", "axial"}: residual power over white
    noise at f x the table rate, averaged over positions (see the module docstring)."""
    return residual_spectrum(data, model.ctx, model.twin)


def residual_spectrum(data, ctx, twin) -> dict:
    """`spectrum` of the residuals of a twin (station.diagnose.prediction.Twin) of context
    `ctx`."""
    a = ctx.a
    if a.shape[0] != 3:
        return {}
    w = 1.0 / (data.sigma**2 + data.bin * data.kept)  # a bin's variance spread over its samples
    cov = np.linalg.inv((a * w) @ a.T)
    grid = frequencies(data)
    points = [_position_spectrum(data, ctx, rj, j, w, cov, grid)
              for rows in data.chunks()
              for rj, j in zip(twin.residual(rows), data.positions(rows), strict=True)]
    return {"frequency": grid, **{key: np.mean([p[key] for p in points], 0)
                                  for key in ("with_table", "against_table", "axial")}}


def _position_spectrum(data, ctx, rj: np.ndarray, j: int, w: np.ndarray, cov: np.ndarray,
                       grid: np.ndarray) -> dict:
    """{"with_table", "against_table", "axial"}: the spectrum points of position j from its
    residuals rj (k, m), weights w (m,) and the unit-frame rate covariance cov (`spectrum`)."""
    r0 = data.windows["rotating"][0]
    sl = slice(r0, data.rot_stop[j])
    omega = (rj[sl] * w) @ ctx.a.T @ cov  # (K, 3) residual rate in the unit frame
    omega -= omega.mean(0)  # the level is the `averaged` statistic's
    p, q, u = ctx.orientation[j].T
    plane = omega @ p + 1j * omega @ q
    theta = data.angle[j, sl] - data.angle[j, r0]
    k = theta.size
    phase = np.exp(-1j * np.outer(grid, theta))  # (F, K)
    noise_plane = (p @ cov @ p + q @ cov @ q) / k
    return {"with_table": np.abs(phase @ plane) ** 2 / k**2 / noise_plane,
            "against_table": np.abs(phase.conj() @ plane) ** 2 / k**2 / noise_plane,
            "axial": np.abs(phase @ (omega @ u)) ** 2 / k**2 / ((u @ cov @ u) / k)}


def _points(spec: dict) -> int:
    """Points of the spectrum: frequencies x (with, against the table, axial)."""
    return 3 * len(spec["frequency"])


def test(spec: dict, positions: int) -> dict:
    """The spectrum as one goodness-of-fit statistic (station.diagnose.goodness): its largest
    point, whose mean over n positions is chi2(2n) / 2n under white noise, with the Bonferroni
    factor of the points (log10 p capped at 0)."""
    top = max(float(np.max(spec[s])) for s in ("with_table", "against_table", "axial"))
    dof = 2 * positions
    log_p = np.log10(_points(spec)) + log_sf(top * dof, dof) / np.log(10)
    return {"gap": top, "dof": dof, "log10_p": min(float(log_p), 0.0)}


TABLE_TONES = (("with_table", 1.0), ("against_table", 1.0))
"""The spectrum points where a rigid table's own errors put their tone, once per revolution:
a tilt of the spin axis turning with the table (axis wobble, +1) and a rate fixed in space
(the Earth's, -1 in the unit's frame). Chosen from the physics before the data are seen, they
are tested on their own (`tone_test`) besides the whole grid (`test`)."""


def tones(spec: dict) -> list:
    """[{"sense", "frequency", "power"}] of the once-per-revolution points (TABLE_TONES),
    strongest first: the signature of a failed `table_rate_tone`."""
    grid = np.asarray(spec["frequency"])
    found = [{"sense": sense, "frequency": float(grid[i]), "power": float(spec[sense][i])}
             for sense, f in TABLE_TONES for i in [int(np.argmin(np.abs(grid - f)))]]
    return sorted(found, key=lambda x: -x["power"])


def tone_test(spec: dict, positions: int) -> dict:
    """The once-per-revolution points (TABLE_TONES) as one goodness-of-fit statistic: the
    larger point, each chi2(2n) / 2n over n positions under white noise, Bonferroni over the
    two (log10 p capped at 0). A weighted Bonferroni of the spectrum: the family-wise level
    holds whatever the split (Holm 1979), and a tone at the table rate is not diluted by the
    3 x 76 points of the whole grid (a coning of 0.004 deg on 3 sensors: a point near 1.9)."""
    top = tones(spec)[0]["power"]
    dof = 2 * positions
    log_p = np.log10(len(TABLE_TONES)) + log_sf(top * dof, dof) / np.log(10)
    return {"gap": top, "dof": dof, "log10_p": min(float(log_p), 0.0)}


def peaks(spec: dict, positions: int, alpha: float) -> list:
    """[{"sense", "frequency", "power"}] of the spectrum points above white noise, strongest
    first: each point's mean over n positions is chi2(2n) / 2n under white noise; the level is
    its 1 - alpha / (points) quantile (Bonferroni)."""
    senses = ("with_table", "against_table", "axial")
    level = chi2.isf(alpha / _points(spec), 2 * positions) / (2 * positions)
    found = [{"sense": sense, "frequency": float(f), "power": float(p)} for sense in senses
             for f, p in zip(spec.get("frequency", ()), spec.get(sense, ()), strict=True)
             if p > level]
    return sorted(found, key=lambda x: -x["power"])
