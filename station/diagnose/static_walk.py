"""Could a free-static drift be the unit's bias random walk? (issue 32: coloured noise)

Without the unit's noise figures (a calibration file's Allan fit, `station diagnose --noise`) a
free-static session judges its poses against white noise, and a bias random walk of realistic
size reads as a warm-up drift (bench/diagnose_static.py `none_walk`: `bias_drift` named in 10 of
10 sessions). The session cannot settle it: the accelerometer shows a walk in one radial number
a pose (the pose's direction takes the rest), so a drift's parameters fit a walk's slow part and
the roughness left between 20 poses is a few numbers. Measured (`beside_walk`, seeds 100-109):
the bench's library warm-up (about 10 x its limit against white noise) reads log10 p -0.5 to
-2.7 against a free walk, walks alone 0.2 to -1.8: the same range. A strong warm-up
(`warmup_180s`) reads -4.2 to -7.9. So a named drift keeps its name (the white-noise reading of
the session) and, where a free walk explains it as well, the diagnosis says it may be the walk
and does not correct the calibration for it (`caveat`).

The test: the drift in the poses' mean residuals y of the model without it, linearised at that
model's fit:

    y = X beta + D gamma + e,   e ~ N(0, diag(var) + sum_s K_s^2 W_s)

X the model's columns (derivatives of the poses' predicted means by its parameters: the
calibration, each pose's direction, the biases, the other extensions), D the drift's (its
warm-up at the fitted time constant and its slope on each channel of one stream), var the white
variances of the pose means (`StaticData.mean_sigma`), one K per stream (the accelerometer's
channels, the gyro's) and W_s its unit walk on that stream's channels: Cov(mean_p, mean_q) =
E min(s, u) over the two intervals' spans, the earlier interval's mid-time for p != q and
a_p + L_p / 3 on the diagonal (start a_p, length L_p; the origin is taken by the free bias).
The likelihood ratio of D on the error contrasts, each K^2 by REML with and without D, is about
chi2(2 c_s + 1) without a drift (station.diagnose.walk.joint_log10_p). Each stream's drift is
tested alone, the smallest p times the streams: a warm-up of the accelerometer is not diluted
by the gyro's 6 columns (`warmup_180s` read -2.4 to -7.4 tested jointly; walks alone 0.0 to -2.9).
"""

import numpy as np

from station.diagnose import walk
from station.diagnose.static import Layout, StaticData, channel_unit, drift_basis, predict

STEP = 1.49e-8
"""Relative step of the forward differences that linearise the model (at least 1 x STEP)."""


def beside_walk(data: StaticData, current, tau: float) -> tuple:
    """(log10 p, (c,) K per channel of the walk without the drift) of a drift with time
    constant tau beside the model `current` (station.diagnose.static.Model, without the drift)
    against a bias random walk per stream (module notes): each stream's drift columns tested
    alone, the smallest p times the streams (Bonferroni)."""
    p = len(data.intervals)
    y = (data.interval_means[0] - data.interval_mean(current.prediction)).T.ravel()
    var = (data.mean_sigma(data.interval_means[1]) ** 2).T.ravel()
    shapes = data.interval_mean(np.stack(drift_basis(data, tau), 1))  # (P, 2)
    x = columns(data, current).reshape(data.c * p, -1)
    streams = [np.arange(data.c) < data.m, np.arange(data.c) >= data.m][:1 + data.gyro]
    unit = unit_walk(data)
    walks = [np.kron(np.diag(s.astype(float)), unit) for s in streams]
    blocks = [np.kron(np.eye(data.c)[:, s], shapes) for s in streams]  # its channels' drift
    log10_p, k2 = walk.joint_log10_p(y, x, blocks, walks, var, 1)
    return (min(log10_p) + np.log10(len(log10_p)),
            np.sqrt(np.where(streams[0], k2[0], k2[-1])))


def caveat(data: StaticData, diagnosis, level: float) -> str:
    """"" or, for a named `bias_drift` that a free bias random walk explains as well (`beside_walk`
    not below log10 `level`), what to say; only without the unit's noise figures (with them the
    figures' walk, or its absence where the rest resolved none, is the judge)."""
    steps = diagnosis.steps
    added = [i for i in range(1, len(steps)) if "bias_drift" in steps[i].model.fitted
             and "bias_drift" not in steps[i - 1].model.fitted]  # empty unless it is named
    if data.coloured or not added:
        return ""
    i = added[-1]
    log10_p, k = beside_walk(data, steps[i - 1].model, steps[i].model.tau)
    if log10_p < np.log10(level):
        return ""
    units = [channel_unit(data, c).split(": ")[-1] for c in (0, data.c - 1)]
    ks = [f"{k[j]:.2g} {u}/sqrt(s) on the {name}" if np.isfinite(k[j])
          else f"none seen on the {name}"
          for j, u, name in zip((0, -1), units, ("accelerometer", "gyro"), strict=True)
          ][:1 + data.gyro]
    return (f"bias_drift may be the unit's bias random walk: a free walk ({', '.join(ks)}) "
            f"explains it as well (log10 p {log10_p:.1f} of the drift beside it); a session "
            "of a few poses cannot tell them apart. Give the unit's noise figures (--noise "
            "CAL.cal.json, from a rest recording) to judge the drift against its own walk")


def unit_walk(data: StaticData) -> np.ndarray:
    """(P, P) covariance of the still intervals' means under a unit bias random walk (module
    notes; the intervals' spans from their first to last sample)."""
    start = data.t[data.intervals[:, 0]]
    length = data.t[data.intervals[:, 1] - 1] - start
    out = np.minimum.outer(start + length / 2, start + length / 2)
    np.fill_diagonal(out, start + length / 3)
    return out - start[0]


def columns(data: StaticData, current) -> np.ndarray:
    """(c, P, parameters) derivatives of the poses' predicted means by the parameters of
    `current` (forward differences at its fit)."""
    names = current.names
    layout = Layout.of(data, current.base, names)
    theta = np.concatenate([current.params[k] for k in layout.slices])
    basis = drift_basis(data, current.tau) if np.isfinite(current.tau) else None

    def means(th):
        return data.interval_mean(predict(data, current.base, names, layout.unpack(th), basis))

    f0 = means(theta)
    out = np.empty((data.c, len(data.intervals), theta.size))
    for k in range(theta.size):
        t = theta.copy()
        h = STEP * max(1.0, abs(t[k]))
        t[k] += h
        out[:, :, k] = ((means(t) - f0) / h).T
    return out
