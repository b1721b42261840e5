"""One calibration file from several sessions of the same unit, with its repeatability.

`combine(cals)` pools K >= 2 calibration files of one unit (same sensors, units, frame and
magnitude; e.g. three recordings with the unit re-seated and switched on again) into one
calibration whose every 1-sigma is the figure for the NEXT session: the pooled mean's uncertainty
plus the between-session spread that one session cannot see (`station.solve.repeatability`).
Classes pooled: the entries of a (in the files' common frame), the biases, the scale factors and
the axis angles. The values of the invariants are those of the pooled a, so the file stays
consistent; the joint covariance keeps the sessions' average correlation structure, scaled to the
pooled sigmas. `fit.repeatability` holds each class's tau, dof and Q; `session.combined` the
sources.
"""

import numpy as np

from station.errors import CalibrationFileError
from station.files.calfile import Calibration, loads
from station.solve import repeatability
from station.solve.uncertainty import axis_angles

CLASSES = ("a", "bias", "scale_factors", "axis_angles")


def _check_alike(cals, names) -> None:
    """Refuse calibrations that are not of one unit's same sensors, units, frame and magnitude."""
    if len(cals) < 2:
        raise CalibrationFileError("combining needs the calibration files of at least 2 "
                                   "sessions of the unit; give two or more")
    first = cals[0]
    for cal, name in zip(cals[1:], names[1:], strict=True):
        for what, mine, theirs in (("unit", cal.unit_serial, first.unit_serial),
                                   ("sensors", cal.sensors, first.sensors),
                                   ("units", cal.units, first.units),
                                   ("frame", cal.frame, first.frame),
                                   ("scale_known", cal.scale_known, first.scale_known)):
            if mine != theirs:
                raise CalibrationFileError(
                    f"{name} has {what} {mine!r} but {names[0]} has {theirs!r}; combine the "
                    "files of one unit, solved with the same sensors, units and frame (station "
                    "solve --nominal for a common physical frame)")
        if not np.isclose(cal.magnitude, first.magnitude, rtol=1e-9):
            raise CalibrationFileError(
                f"{name} was solved with magnitude {cal.magnitude} but {names[0]} with "
                f"{first.magnitude}; solve the sessions again with the same --magnitude")


def _correlation(covs) -> np.ndarray | None:
    """The correlation matrix of the sessions' average covariance (None if any is unknown)."""
    if any(c is None for c in covs):
        return None
    mean = np.mean(covs, axis=0)
    sd = np.sqrt(np.diag(mean))
    safe = np.where(sd > 0, sd, 1.0)
    rho = mean / np.outer(safe, safe)
    np.fill_diagonal(rho, np.where(sd > 0, 1.0, 0.0))
    return rho


def _covariance(rho, pooled_a, pooled_b) -> np.ndarray | None:
    """Joint covariance of (a row-major, b): the average correlation scaled to the pooled means'
    sigmas, plus the between-session variance of each class, times each class's widening; its
    diagonal is the pooled sigmas squared."""
    if rho is None:
        return None
    parts = [(pooled_a.mean_sigma.ravel(), pooled_a), (pooled_b.mean_sigma, pooled_b)]
    mean_sd = np.concatenate([sd for sd, _ in parts])
    tau2 = np.concatenate([np.where(p.sigma.ravel() > 0, p.tau**2, 0.0) for _, p in parts])
    widen = np.concatenate([np.full(sd.size, p.widening) for sd, p in parts])
    cov = rho * np.outer(mean_sd, mean_sd) + np.diag(tau2)
    return cov * np.outer(widen, widen)


def combine(cals, names) -> Calibration:
    """The calibration for the next session of the unit, from its sessions' files `cals` (named
    `names` in messages and in `session.combined`)."""
    _check_alike(cals, names)
    first = cals[0]
    stack = {"a": ([c.a for c in cals], [c.a_sigma for c in cals]),
             "bias": ([c.bias for c in cals], [c.bias_sigma for c in cals]),
             "scale_factors": ([c.scale_factors for c in cals],
                               [c.scale_factors_sigma for c in cals]),
             "axis_angles": ([c.axis_angles for c in cals], [c.axis_angles_sigma for c in cals])}
    pooled = {}
    for name, (x, s) in stack.items():
        x, s = np.array(x), np.array(s)
        flat = repeatability.pool(x.reshape(len(cals), -1), s.reshape(len(cals), -1))
        pooled[name] = repeatability.Pooled(
            mean=flat.mean.reshape(x.shape[1:]), mean_sigma=flat.mean_sigma.reshape(x.shape[1:]),
            sigma=flat.sigma.reshape(x.shape[1:]), tau=flat.tau, dof=flat.dof, q=flat.q,
            widening=flat.widening)
    a = pooled["a"].mean
    fits = [c.fit for c in cals]
    suspect = [f"{n}: {'; '.join(c.fit.get('status_reasons', [])) or 'suspect'}"
               for c, n in zip(cals, names, strict=True) if c.fit.get("status") == "suspect"]
    fit = {"method": "combined", "sessions": len(cals),
           "chi2": float(sum(f["chi2"] for f in fits)), "dof": int(sum(f["dof"] for f in fits)),
           "positions": int(sum(f["positions"] for f in fits)),
           "bias_source": "pooled over the sessions (station combine)",
           "status": "suspect" if suspect else "good", "status_reasons": suspect,
           "repeatability": {k: {"tau": p.tau, "dof": p.dof, "q": p.q}
                             for k, p in pooled.items()}}
    cal = Calibration(
        unit_serial=first.unit_serial, sensors=first.sensors, units=first.units, a=a,
        a_sigma=pooled["a"].sigma, bias=pooled["bias"].mean, bias_sigma=pooled["bias"].sigma,
        scale_factors=np.linalg.norm(a, axis=0),
        scale_factors_sigma=pooled["scale_factors"].sigma, axis_angles=axis_angles(a),
        axis_angles_sigma=pooled["axis_angles"].sigma, frame=first.frame,
        magnitude=first.magnitude, scale_known=first.scale_known, fit=fit,
        counts_per_unit=first.counts_per_unit,
        session={"combined": [{"file": n, "created": c.created, "session": c.session}
                              for c, n in zip(cals, names, strict=True)]},
        covariance=_covariance(_correlation([c.covariance for c in cals]), pooled["a"],
                               pooled["bias"]))
    return loads(cal.dumps(), "the combined calibration")  # the checks of a load
