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

`with_repeatability(cal, sources)`: one NEW session's calibration with those taus added to its own
1-sigma (`station solve --repeatability COMBINED`), the figure valid for that session as a unit
re-seated and switched on again; `fit.repeatability_included` says from which files. Several
combined files, one per unit of one model (a lot whose repeatability is alike), pool each class's
tau^2 weighted by its dof: the tau of a model rests on many more dof than one unit's (a triad's
biases from two sessions: 3), so it needs far less widening.
"""

import dataclasses
import hashlib

import numpy as np

from station.calfiles.calfile import Calibration, loads, read_text
from station.errors import CalibrationFileError
from station.solve import repeatability
from station.solve.uncertainty import axis_angles

CLASSES = ("a", "bias", "scale_factors", "axis_angles")


def _check_alike(cals, names) -> None:
    """Refuse calibrations that are not of one unit's same sensors, units, frame and magnitude."""
    if len(cals) < 2:
        raise CalibrationFileError("combining needs the calibration files of at least 2 "
                                   "sessions of the unit; give two or more")
    for cal, name in zip(cals, names, strict=True):
        if INCLUDED in cal.fit:  # its 1-sigma holds a tau already: counted twice
            raise CalibrationFileError(
                f"{name} was solved with the repeatability of {included_files(cal.fit)} "
                "(station solve --repeatability): its 1-sigma holds the spread between sessions "
                "already; combine the files solved without --repeatability")
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
    mean_sd = np.concatenate([pooled_a.mean_sigma.ravel(), pooled_b.mean_sigma])
    return _plus_between(rho * np.outer(mean_sd, mean_sd),
                         [(p.sigma, p.tau, p.widening) for p in (pooled_a, pooled_b)])


def _plus_between(cov, classes) -> np.ndarray | None:
    """cov of (a row-major, b) plus each class's between-session variance tau^2 on its diagonal
    (not on entries whose next-session sigma is 0: fixed by the frame), times each class's
    widening; classes: [(next-session sigma, tau, widening)] of a, then of b. None stays None."""
    if cov is None:
        return None
    tau2 = np.concatenate([np.where(np.ravel(sigma) > 0, tau**2, 0.0)
                           for sigma, tau, _ in classes])
    widen = np.concatenate([np.full(np.size(sigma), w) for sigma, _, w in classes])
    return (cov + np.diag(tau2)) * np.outer(widen, widen)


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
        pooled[name] = dataclasses.replace(
            flat, mean=flat.mean.reshape(x.shape[1:]),
            mean_sigma=flat.mean_sigma.reshape(x.shape[1:]), sigma=flat.sigma.reshape(x.shape[1:]))
    a = pooled["a"].mean
    fits = [c.fit for c in cals]
    suspect = [f"{n}: {'; '.join(c.fit.get('status_reasons', [])) or 'suspect'}"
               for c, n in zip(cals, names, strict=True) if c.fit.get("status") == "suspect"]
    fit = {"method": "combined", "sessions": len(cals),
           "chi2": float(sum(f["chi2"] for f in fits)), "dof": int(sum(f["dof"] for f in fits)),
           "positions": int(sum(f["positions"] for f in fits)),
           "bias_source": "pooled over the sessions (station combine)",
           "status": "suspect" if suspect else "good", "status_reasons": suspect,
           "repeatability": {k: {"tau": p.tau, "dof": p.dof, "q": p.q,
                                 "tau_point": p.tau_point, "tau_upper": p.tau_upper,
                                 "sessions": p.sessions, "mean_sigma": p.mean_sigma.tolist()}
                             for k, p in pooled.items()}}
    cal = Calibration(
        unit_serial=first.unit_serial, sensors=first.sensors, units=first.units, a=a,
        a_sigma=pooled["a"].sigma, bias=pooled["bias"].mean, bias_sigma=pooled["bias"].sigma,
        scale_factors=np.linalg.norm(a, axis=0),
        scale_factors_sigma=pooled["scale_factors"].sigma, axis_angles=axis_angles(a),
        axis_angles_sigma=pooled["axis_angles"].sigma, frame=first.frame,
        magnitude=first.magnitude, scale_known=first.scale_known, fit=fit,
        counts_per_unit=first.counts_per_unit, stimulus=first.stimulus,
        session={"combined": [{"file": n, "created": c.created, "session": c.session}
                              for c, n in zip(cals, names, strict=True)]},
        covariance=_covariance(_correlation([c.covariance for c in cals]), pooled["a"],
                               pooled["bias"]))
    return loads(cal.dumps(), "the combined calibration")  # the checks of a load


INCLUDED = "repeatability_included"
"""The key of a session's `fit` that says its 1-sigma figures include a combined file's
between-session terms (`with_repeatability`): the file, its sha256, each class's tau, dof and
widening, and the session's own 1-sigma of the biases and scale factors."""


def with_repeatability(cal: Calibration, sources: list) -> Calibration:
    """One session's calibration `cal` with every 1-sigma the figure for the unit re-seated and
    switched on again. `sources`: [(combined, name, sha256)], files of `station combine` (named
    `name`, of digest `sha256`) of this unit or of units of its model; each class's
    between-session tau^2, pooled over them weighted by dof (`pooled_terms`), is added to the
    session's own variance and widened for the dof tau was estimated on
    (`station.solve.repeatability.next_session_sigma`); the covariance gains tau^2 on the
    diagonal of a and b alike. Refused (CalibrationFileError): a combined file of another layout
    (number of sensors, axes, quantity, stream, frame), without a repeatability section or with a
    tau that is not a finite number >= 0, and a calibration that already includes one."""
    if INCLUDED in cal.fit:
        raise CalibrationFileError(
            f"the calibration already includes the repeatability of {included_files(cal.fit)}; "
            "solve the session again without it first")
    digests = [sha256 for _, _, sha256 in sources]
    if len(set(digests)) != len(digests):
        raise CalibrationFileError(
            "the same combined file is given twice: its sessions would count twice in tau; give "
            "each combined file once")
    terms = pooled_terms([(combined, name) for combined, name, _ in sources])
    for combined, name, _ in sources:
        _check_layout(cal, combined, name)
    own = {"a": cal.a_sigma, "bias": cal.bias_sigma, "scale_factors": cal.scale_factors_sigma,
           "axis_angles": cal.axis_angles_sigma}
    new = {}
    for key, sigma in own.items():
        tau, dof = terms[key]
        wider, widen = repeatability.next_session_sigma(sigma.ravel(), tau**2, dof)
        new[key] = (wider.reshape(sigma.shape), tau, widen)
    fit = {**cal.fit, INCLUDED: {
        "files": [{"file": name, "sha256": sha256, "unit_serial": combined.unit_serial,
                   "sessions": combined.fit.get("sessions")} for combined, name, sha256 in sources],
        "tau": {k: v[1] for k, v in new.items()}, "dof": {k: terms[k][1] for k in new},
        "widening": {k: v[2] for k, v in new.items()},
        "session_sigma": {"bias": cal.bias_sigma.tolist(),
                          "scale_factors": cal.scale_factors_sigma.tolist()}}}
    out = dataclasses.replace(
        cal, a_sigma=new["a"][0], bias_sigma=new["bias"][0],
        scale_factors_sigma=new["scale_factors"][0], axis_angles_sigma=new["axis_angles"][0],
        covariance=_plus_between(cal.covariance, [new["a"], new["bias"]]), fit=fit)
    return loads(out.dumps(), "the calibration with the repeatability")  # the checks of a load


def with_repeatability_files(cal: Calibration, paths) -> Calibration:
    """`with_repeatability` of the combined calibration files at `paths` (each read once: its
    sha256 is that of the bytes loaded)."""
    sources = []
    for path in paths:
        text, raw = read_text(path)
        sources.append((loads(text, str(path)), str(path), hashlib.sha256(raw).hexdigest()))
    return with_repeatability(cal, sources)


def included_files(fit: dict) -> str:
    """The combined files a calibration's 1-sigma includes (`fit.repeatability_included`), named
    for a message; the one `file` of calibrations written before several could be pooled."""
    record = fit.get(INCLUDED) or {}
    files = record.get("files")
    names = [f.get("file") for f in files if isinstance(f, dict)] if isinstance(files, list) \
        else [record.get("file")]
    return ", ".join(repr(n) for n in names)


def pooled_terms(sources) -> dict:
    """{class: (tau, dof)} pooled over the combined files `sources` [(combined, name)]: tau^2 the
    dof-weighted mean of theirs (the pooled variance of units alike), dof their sum."""
    terms = [_terms(combined, name) for combined, name in sources]
    out = {}
    for key in CLASSES:
        dof = sum(t[key][1] for t in terms)
        tau2 = sum(t[key][1] * t[key][0] ** 2 for t in terms) / dof if dof else 0.0
        out[key] = (float(np.sqrt(tau2)), dof)
    return out


def _terms(combined: Calibration, name: str) -> dict:
    """{class: (tau, dof)} of a combined file's `fit.repeatability`, checked."""
    section = combined.fit.get("repeatability")
    if not isinstance(section, dict) or not all(isinstance(section.get(k), dict)
                                                for k in CLASSES):
        raise CalibrationFileError(
            f"{name} has no repeatability section (fit.repeatability with {', '.join(CLASSES)}): "
            "it is not a file of `station combine`; give the combined file of two or more "
            "sessions of the unit (station combine A.cal.json B.cal.json --out X.cal.json)")
    terms = {}
    for key in CLASSES:
        tau, dof = section[key].get("tau"), section[key].get("dof")
        if type(tau) not in (int, float) or not np.isfinite(tau) or tau < 0:
            raise CalibrationFileError(
                f"{name}: the between-session tau of {key} is {tau!r}, not a finite number >= 0; "
                "the file is damaged or was edited: combine the sessions again (station combine)")
        if type(dof) is not int or dof < 0 or (tau > 0 and dof == 0):
            raise CalibrationFileError(
                f"{name}: the degrees of freedom of {key}'s tau are {dof!r}, not a whole number "
                ">= 1; the file is damaged or was edited: combine the sessions again")
        terms[key] = (float(tau), dof)
    return terms


def _check_layout(cal: Calibration, combined: Calibration, name: str) -> None:
    """Refuse a combined file of another layout than the session's: number of sensors m, axes d,
    quantity (units), stream and frame (its tau of a is that frame's)."""
    streams = {(c.get("session") or {}).get("stream") for c in
               (combined.session or {}).get("combined", [{}]) if isinstance(c, dict)}
    mine = (cal.session or {}).get("stream")
    for what, theirs, ours in (("sensors (m)", len(combined.sensors), len(cal.sensors)),
                               ("axes (d)", combined.a.shape[0], cal.a.shape[0]),
                               ("quantity", combined.units[0], cal.units[0]),
                               ("stream", ", ".join(sorted(map(str, streams))), str(mine)),
                               ("frame", combined.frame, cal.frame)):
        if theirs != ours:
            raise CalibrationFileError(
                f"{name} is of {what} {theirs!r} but this session's calibration has {ours!r}: "
                "its repeatability is another layout's; give the combined file of sessions "
                "solved like this one (same stream, sensors and frame)")
