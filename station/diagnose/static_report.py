"""Free-static diagnosis: session loading, gap statistics and the white-noise check (their JSON /
text / HTML form: station.report.diagnosis, shared with the rotary path).

Gap statistics (1 = explained by white noise of the sigma measured within the bins):
- `between`: accelerometer interval means against the model, chi2 / dof of the calibration
  (absent when the poses do not determine the calibration);
- `gyro`: gyro interval means against the model (one bias, plus the Earth rate when fitted);
- `within`: bin means around their interval's mean (the scatter of sub-interval means);
- `trend`: slopes of the bin residuals within each interval, in units of their standard error;
- `rails`: rail pile-up deviance per channel side that holds the extreme value.
"""

import itertools

import numpy as np

from station.diagnose.goodness import log_sf
from station.diagnose.static import SCALES_S, StaticData, from_arrays, specific_force
from station.errors import CalibrationInputError
from station.model.constants import STANDARD_GRAVITY
from station.session import COUNTS


def statistics(data: StaticData, model) -> dict:
    """{statistic: normalised gap} of a fitted model (station.diagnose.static.Model)."""
    m, c, p, nb = data.m, data.c, len(data.intervals), len(data.bins)
    free = model.base.cal is None  # one mean per distinct pose
    r = data.whiten(data.z - model.prediction)  # whitened bin residuals
    _, n = data.interval_means
    root = np.sqrt(data.lengths)
    big = np.stack([np.bincount(data.bin_interval, root * r[:, i], p) for i in range(c)], 1)
    big /= np.sqrt(n)[:, None]  # whitened interval-mean residuals
    nominal = m * (model.base.pose.max() + 1) if free else 3 * m - 3 + m + 2 * p
    dof = p * m - nominal  # none when every interval has its own mean
    out = {"between": float(np.sum(big[:, :m] ** 2) / dof)} if dof > 0 else {}
    if data.gyro:
        out["gyro"] = float(np.sum(big[:, m:] ** 2) / max(p * (c - m) - (c - m), 1))
    out["within"] = float((np.sum(r**2) - np.sum(big**2)) / max((nb - p) * c, 1))
    out["trend"] = _trend(data, r)
    out["rails"] = model.rails / max(2 * int(np.sum(~data.coarse)), 1)
    return out


def dofs(data: StaticData, model) -> dict:
    """{statistic: degrees of freedom} of `statistics`: under white noise gap x dof ~
    chi2(dof) (station.diagnose.goodness)."""
    m, c, p, nb = data.m, data.c, len(data.intervals), len(data.bins)
    free = model.base.cal is None
    nominal = m * (model.base.pose.max() + 1) if free else 3 * m - 3 + m + 2 * p
    slopes = int(np.sum(np.bincount(data.bin_interval, minlength=p) >= 2)) * c
    out = {"between": p * m - nominal, "within": max((nb - p) * c, 1), "trend": slopes,
           "rails": 2 * int(np.sum(~data.coarse))}
    if data.gyro:
        out["gyro"] = max(p * (c - m) - (c - m), 1)
    return out


def signature(data: StaticData, model, statistic: str) -> dict:
    """The signature of an unexplained gap statistic (station.diagnose.signature's for
    free-static sessions): its mean square feature by channel and by interval, the correlation
    of the per-interval part with time, and how much of the interval means' residual the
    gravity direction explains (R^2 of a fit on [1, up_j] per channel, mean over the
    statistic's channels; about 3 / (P - 1) for noise)."""
    if statistic == "rails":
        return {"note": "pile-up at the output rails that the twin does not expect"}
    p, m = len(data.intervals), data.m
    r = data.whiten(data.z - model.prediction)
    _, n = data.interval_means
    big = np.stack([np.bincount(data.bin_interval, np.sqrt(data.lengths) * r[:, i], p)
                    for i in range(data.c)], 1) / np.sqrt(n)[:, None]
    if statistic in ("between", "gyro"):
        per = big**2
    else:
        per = np.stack([np.bincount(data.bin_interval, r[:, i] ** 2, p) for i in range(data.c)],
                       1) / np.maximum(np.bincount(data.bin_interval, minlength=p), 1)[:, None]
    channels = slice(m, data.c) if statistic == "gyro" else (
        slice(0, m) if statistic == "between" else slice(0, data.c))
    f = specific_force(data, model.base)
    up = np.column_stack([np.ones(p), f / np.linalg.norm(f, axis=1, keepdims=True)])
    y = big[:, channels]
    fit = up @ np.linalg.lstsq(up, y, rcond=None)[0]
    total = np.sum((y - y.mean(0)) ** 2, 0)
    r2 = 1 - np.sum((y - fit) ** 2, 0) / np.where(total > 0, total, 1)
    times = data.t[data.intervals[:, 0]]
    by_interval = per[:, channels].mean(1)
    return {"by_channel": per.mean(0), "by_interval": by_interval,
            "correlation_with_time": float(np.corrcoef(by_interval, times)[0, 1]),
            "gravity_direction_r2": float(r2.mean()), "gravity_direction_r2_noise": 3 / (p - 1)}


def _trend(data: StaticData, r: np.ndarray) -> float:
    """Mean square of the within-interval slopes of the whitened bin residuals r (B, c), each in
    units of its standard error (weighted least squares on the bin times)."""
    tb = data.binmean(data.t)
    w = data.lengths.astype(float)
    z = []
    for j in range(len(data.intervals)):
        k = data.bin_interval == j
        if k.sum() < 2:
            continue
        dt = tb[k] - np.sum(w[k] * tb[k]) / w[k].sum()
        z.append((np.sqrt(w[k]) * dt) @ r[k] / np.sqrt(np.sum(w[k] * dt**2)))
    return float(np.mean(np.square(z))) if z else float("nan")


def whiteness(data: StaticData, model) -> dict:
    """Scatter of block means within the still intervals against white noise, per block length:
    sum (block mean - interval mean)^2 L / sigma^2 / (blocks - 1), pooled over intervals and over
    the channels of each stream; 1 for white noise, growing with L for a random walk or flicker
    (an Allan-variance-like ratio, normalised by the sigma used in every chi2)."""
    x = data.x[data.still] - np.repeat(model.prediction, data.lengths, axis=0)
    edges = np.concatenate([[0], np.cumsum(data.intervals[:, 1] - data.intervals[:, 0])])
    groups = {"accelerometer": slice(0, data.m)}
    if data.gyro:
        groups["gyro"] = slice(data.m, data.c)
    out = {g: {} for g in groups}
    for scale in SCALES_S:
        size = max(round(scale * data.fs), 1)
        num, dof = np.zeros(data.c), 0
        for a, z in itertools.pairwise(edges):
            k = (z - a) // size
            if k < 2:
                continue
            blocks = x[a:a + k * size].reshape(k, size, -1).mean(1)
            num += np.sum((blocks - blocks.mean(0)) ** 2, 0) * size / data.sigma**2
            dof += k - 1
        if dof:
            for g, sl in groups.items():
                out[g][f"{scale:g}"] = float(num[sl].mean() / dof)
    return out


def white_noise_verdict(data: StaticData, step, alpha: float) -> dict:
    """Does white noise explain the scatter within the intervals? The `within` gap against its
    chi2 law, and the ratios by block length."""
    dof = max((len(data.bins) - len(data.intervals)) * data.c, 1)
    within = step.gap["within"]
    log_p = log_sf(within * dof, dof) / np.log(10)
    ratios = whiteness(data, step.model)
    holds = bool(log_p > np.log10(alpha))
    worst = max(((g, s, v) for g, r in ratios.items() for s, v in r.items()), key=lambda x: x[2])
    message = (
        f"white noise holds: bin scatter {within:.2f} x the white-noise expectation "
        f"(log10 p = {log_p:.1f})" if holds else
        f"WHITE NOISE FAILS: the bin means scatter "
        f"{within:.2f} x the white-noise expectation (log10 p = {log_p:.1f}); block means of "
        f"{worst[1]} s ({worst[0]}) {worst[2]:.1f} x: coloured noise / bias random walk. The LRs "
        "are inflated and the p-values optimistic; log10_p_quasi divides each LR by the "
        "dispersion (the `within` gap)")
    return {"within": within, "dof": dof, "log10_p": log_p, "holds": holds,
            "ratio_by_block_s": ratios, "message": message}


# ------------------------------------------------------------------------- session and command


def load(path, still=None, **detector) -> StaticData:
    """StaticData of a session: its accelerometer channels (unit m/s^2, one stream) and, when there
    are any, its 3 gyro channels (rad/s; the same or another stream on the same time base): an
    imported recording or a free-static session. Gravity: metadata `gravity`, else standard.
    `still`, `detector`: the detector's settings (`from_arrays`)."""
    from station.session import Session

    with Session.open(path) as s:
        accel, gyro = (_channels(s.specs, unit) for unit in ("m/s^2", "rad/s"))
        if len(accel) != 1 or len(gyro) > 1:
            raise CalibrationInputError(
                f"{path} has accelerometer channels in streams {sorted(accel)} and gyro channels "
                f"in {sorted(gyro)}; one accelerometer stream (m/s^2) and at most one gyro "
                "stream (rad/s) are needed.",
                "Import the accelerometer (and gyro) of one unit into the session.")
        (acc_name, acc_cols), = accel.items()
        acc = s.stream(acc_name)
        gyr = None
        if gyro:
            (gyro_name, gyro_cols), = gyro.items()
            gyr = s.stream(gyro_name).to_si()[:, gyro_cols]
        gravity = s.metadata.get("gravity")
        reading = [(n, s.reading_units(n)[cols[0]]) for n, cols in [*accel.items(), *gyro.items()]]
    notes = [] if gravity else [(f"gravity not in the session: {STANDARD_GRAVITY} m/s^2 assumed "
                                "(only the common scale depends on it)")]
    raw = [n for n, unit in reading if unit == COUNTS]
    if raw:
        notes.append(f"streams {raw} hold raw counts: values and parameters are in counts")
    if gyr is not None and gyr.shape[1] != 3:
        raise CalibrationInputError(f"gyro stream {gyro_name!r} has {gyr.shape[1]} gyro channels.",
                                    "Give a 3-axis gyro stream, or none.")
    units = [f"{name}: {unit}" for name, unit in reading]
    return from_arrays(acc.to_si()[:, acc_cols], acc.spec.rate_hz, gyro=gyr,
                       gravity=float(gravity or STANDARD_GRAVITY), units=units, notes=notes,
                       still=still, **detector)


def _channels(specs: dict, unit: str) -> dict:
    """{stream name: indices of its channels in `unit`} for the streams that have any."""
    found = {name: [i for i, u in enumerate(spec.units) if u == unit]
             for name, spec in specs.items()}
    return {name: cols for name, cols in found.items() if cols}
