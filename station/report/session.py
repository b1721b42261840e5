"""The session report: one self-contained HTML file per session, for the calibration engineer.

`build(path)` reads a session file (docs/session-format.md) and returns a `Report`: a summary, the
warnings in plain words and the figures (PNG). `Report.write(out)` writes the HTML, every figure
embedded as a base64 `data:` image so the file stands alone, and the same figures as PNG files
next to it (`<stem>-<figure>.png`).

The figures:
- residuals   : normalised residuals r_ij / sigma_ij per sensor and position (the model
                z = a^T v + b of docs/conventions.md against the noise level of each reading), and
                their histogram against the distribution the fit predicts;
- axes        : the sensitive axes a_i / |a_i| in the result's frame, 3-D and in projections;
- coverage    : directions of the stimuli v_j on the sphere (with -v_j: magnitude data see v v^T);
- table       : measured table rate against the setpoint, and its error in the rotating windows;
- stream      : samples received per second against the nominal rate, sequence gaps, arrival
                latency of each sample (host time - sampling instant);
- uncertainty : scale factors, biases and axis angles with their 1-sigma uncertainties;
- allan       : per stream with static data, the Allan deviation of each channel with its
                confidence band and the fitted IEEE 952 terms, beside their table
                (station/report/noise.py).

The calibration is the stored `results/<name>` (the newest by default). A session without stored
results (e.g. a recording that was interrupted) is reduced and solved for the report as `station
replay` does (`station.replay.solve_recorded`); the report says so. Every text from the file is
escaped: the file is untrusted.
"""

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from scipy import stats

from station.errors import CalibrationInputError, InputError
from station.files.jsonable import jsonable
from station.protocols import KINDS
from station.reduce.rotary import position_spins, position_windows
from station.reduce.timeline import sample_times, segment_breaks
from station.replay import ReplaySettings, calibrated_stream, reduce_recorded, solve_recorded
from station.report import html, noise, verdict
from station.session import Session
from station.session.units import unit_serial
from station.solve.quality import CHI2_P, check_fit, outlier_words
from station.solve.verdict import recorded_tolerances

WEAK_EXCITATION = 0.25
"""Smallest accepted ratio of the weakest to the strongest eigenvalue of sum_j v_j v_j^T."""
EMPTY_CAP_DEG = 60.0
"""Largest accepted angular radius of a region of the sphere with no stimulus direction (+-v_j)."""


@dataclass
class Report:
    """What the report shows: `summary` (JSON-able), `warnings` (sentences), `plots`, and HTML
    fragments (`sections`, already escaped) between the summary and the figures."""

    path: str
    summary: dict
    warnings: list = field(default_factory=list)
    plots: list = field(default_factory=list)
    sections: list = field(default_factory=list)

    def write(self, out) -> list:
        """Write the HTML file `out` and one PNG per figure next to it; the paths written."""
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        written = []
        for plot in self.plots:
            png = out.with_name(f"{out.stem}-{plot.name}.png")
            png.write_bytes(plot.png)
            written.append(png)
        out.write_text(self.html(), encoding="utf-8")
        return [out, *written]

    def html(self) -> str:
        """The whole report as one HTML document (station.report.html.page)."""
        warn = ("".join(f"<li>{html.e(w)}</li>" for w in self.warnings) if self.warnings
                else "<li class=ok>No warning: the data and the model agree.</li>")
        return html.page(f"Calibration report - {self.summary.get('unit_serial', '?')}",
                         self.path,
                         html.section("warnings", "Warnings", f"<ul>{warn}</ul>")
                         + html.section("summary", "Summary", html.table(self.summary_rows()))
                         + "".join(self.sections) + "".join(html.figure(p) for p in self.plots))

    def summary_rows(self) -> list:
        """(label, value) rows of the summary table."""
        labels = {
            "unit_serial": "unit", "protocol": "protocol", "created": "session created",
            "software_version": "recorded with station", "closed_cleanly": "closed cleanly",
            "device": "IMU", "sensors": "sensors m", "rate_hz": "sample rate (Hz)",
            "positions": "positions completed", "positions_planned": "positions planned",
            "samples": "samples recorded", "duration_s": "recording (s of session clock)",
            "expected_eps": "expected eps before the session (Eq. 19, CRLB)",
            "result": "calibration", "method": "method", "frame": "frame of a",
            "magnitude": "stimulus magnitude c", "chi2_per_dof": "chi2 / dof", "dof": "dof",
            "noise_median": "median noise of a reading", "excitation_ratio":
            "weakest / strongest excitation", "largest_empty_cap_deg":
            "largest direction without a position (deg)", "still_poses": "still poses found",
            "rejected_candidates": "still candidates rejected", "verdict": "verdict"}
        return [(label, _fmt(self.summary[key])) for key, label in labels.items()
                if key in self.summary]


# ------------------------------------------------------------------------------------ building


def build(path, result: str | None = None, stream: str | None = None) -> Report:
    """The report of the session file `path`, with the calibration `results/<result>` (default:
    the newest stored one, else computed for a rotary session). `stream`: one unit's stream of a
    session with several units on one table (its serial, stored results, health and noise);
    None: every stream, the first unit's calibration."""
    with Session.open(path) as session:
        report = Report(str(path), _session_summary(session, stream))
        if not session.closed_cleanly:
            report.warnings.append(
                "The session file was not closed cleanly (the recording is still running or was "
                "killed): the report shows the data flushed so far.")
        events = session.events()
        hand = getattr(KINDS.get(session.protocol), "still", False)
        _protocol_warnings(report, events, session.metadata)
        _fixture_poses(report, session.metadata)
        calibration = _calibration(session, result, report, stream)
        streams = list(session.specs) if stream is None else [stream]
        for name in streams:
            _stream_health(report, name, session.stream(name, columns=("seq", "host_time")),
                           events)
        _table_stability(report, session.table(), events, session.metadata)
        noise.add_to_report(report, session, streams)
        verdict.add_to_report(report, session, stream, report.summary.get("unit_serial"),
                              recorded_tolerances(session.metadata, path) is not None)
    if calibration is not None:
        cal, channels, units = calibration
        _fit(report, cal, channels, hand)
        _geometry(report, cal)
        _axes_plot(report, cal, channels)
        _uncertainty(report, cal, channels, units)
    report.summary = jsonable(report.summary)
    report.summary["warnings"] = report.warnings
    return report


def _session_summary(session, stream: str | None) -> dict:
    """What the file says about itself, before any analysis (about the unit on `stream`)."""
    meta = session.metadata
    planned = meta.get("axes")
    serial = None if stream is None else unit_serial(meta, session.specs, stream, session.path)
    return {
        "unit_serial": serial or session.unit_serial,
        **({} if serial is None else {"stream": stream}), "protocol": session.protocol,
        "created": session.created, "software_version": session.software_version,
        "closed_cleanly": session.closed_cleanly,
        **({"positions_planned": len(planned)} if isinstance(planned, list) else {}),
    }


def _fixture_poses(report, metadata) -> None:
    """The planned fixture poses of a rotary session (`station.protocols.planned`): a section
    with each position's words and picture, and the expected eps told before the session."""
    poses = metadata.get("fixture_poses")
    if not isinstance(poses, list):
        return
    plan = metadata.get("plan")
    if isinstance(plan, dict) and isinstance(plan.get("expected_eps"), int | float):
        report.summary["expected_eps"] = float(plan["expected_eps"])
    rows = [(j + 1, str(p.get("words", "?")) if isinstance(p, dict) else "?",
             f"<pre>{html.e(str(p.get('picture', '')))}</pre>" if isinstance(p, dict) else "")
            for j, p in enumerate(poses)]
    rows = [(html.e(str(j)), html.e(words), pic) for j, words, pic in rows]
    report.sections.append(html.section(
        "fixture", "Fixture poses (planned)",
        "<p>Face letters of the mounting cube; the first face named is down on the table (or on "
        "the wedge's slope), the second toward the technician (docs/protocols.md).</p>"
        + html.table(rows, ("position", "pose", "picture"), escape_cells=False)))


def _protocol_warnings(report, events, metadata) -> None:
    """Positions completed, aborts, faults and redos (a flagged window recorded again), from the
    event list."""
    done = sorted({e.position for e in events if e.kind == "position_done"})
    report.summary["positions"] = len(done)
    planned = report.summary.get("positions_planned")
    if planned is not None and len(done) < planned:
        report.warnings.append(f"Only {len(done)} of the {planned} planned positions were "
                               "completed; resume the session to record the others.")
    redos = {id(e) for e in events if e.kind == "position_start" and e.detail.get("redo")}
    if redos:  # flagged windows recorded again (station.protocols.redo)
        report.summary["redos"] = len(redos)
    notable = [e for e in events if e.kind in ("session_resumed", "pause", "resume", "fault",
                                               "note", "abort") or id(e) in redos]
    for e in notable:
        if e.kind in ("abort", "fault"):
            where = "" if e.position is None else f" at position {e.position + 1}"
            why = e.detail.get("error") or e.detail.get("text") or ""
            report.warnings.append(f"The protocol recorded a {e.kind}{where}: {why}".rstrip(": "))
    if notable:
        rows = [(f"{e.time:.1f}", "redo" if id(e) in redos else e.kind,
                 "" if e.position is None else str(e.position + 1), _short(e.detail))
                for e in notable]
        report.sections.append(html.section("events", "Notable events", html.table(
            rows, ("time (s)", "event", "position", "detail"))))


def _calibration(session, name, report, stream: str | None):
    """(CalibrationResult, channel names, units) to report, or None with a warning saying why;
    `stream`: only that stream's results (None: any)."""
    chosen = {r.name: r for r in map(session.results, session.result_names)
              if stream is None or r.stream == stream}
    if name is not None and name not in chosen:
        raise InputError(f"{session.path} has no results named {name!r}"
                         f"{'' if stream is None else f' of stream {stream}'}; it has "
                         f"{', '.join(chosen) or 'none'} (omit --result to use the newest)")
    kind = KINDS.get(session.protocol)
    if chosen:
        stored = chosen[name] if name else max(chosen.values(), key=lambda r: r.order)
        spec = session.specs[stored.stream]
        report.summary["result"] = f"results/{stored.name} ({stored.created})"
        if stored.calibration is None:
            report.warnings.append(f"results/{stored.name} holds readings but no calibration.")
            return None
        if kind is not None and kind.still:
            _stored_poses(report, session, stored)
        rows = stored.channels or range(len(spec.channels))
        units = session.reading_units(stored.stream)
        return stored.calibration, [spec.channels[i] for i in rows], [units[i] for i in rows]
    if kind is None or not kind.has("reduce"):
        report.warnings.append("The session holds no calibration result; solve it and store "
                               "the result to see the fit in this report.")
        return None
    try:
        settings = ReplaySettings(stream=stream)
        stream = calibrated_stream(session, settings)
        readings, cal = solve_recorded(session, settings, command="the report")
    except CalibrationInputError as exc:
        report.warnings.append(f"No calibration could be computed from this session: {exc}")
        return None
    report.summary["result"] = "computed for this report (no stored result)"
    _poses(report, readings)
    spec = session.specs[stream]
    rows = kind.entry("channels")(session, stream) if kind.has("channels") else \
        range(len(spec.channels))
    units = session.reading_units(stream)
    return cal, [spec.channels[i] for i in rows], [units[i] for i in rows]


def _stored_poses(report, session, stored) -> None:
    """The still poses of stored results, detected again with the settings stored with them (a
    replay's or a solve's; the defaults for a recording's own results)."""
    known = {f.name for f in dataclasses.fields(ReplaySettings)}
    given = {k: v for k, v in (stored.settings or {}).items() if k in known}
    try:
        settings = ReplaySettings(**{**given, "stream": stored.stream})
        _poses(report, reduce_recorded(session, settings, "the report"))
    except (InputError, TypeError) as exc:
        report.warnings.append(f"The still poses of results/{stored.name} could not be detected "
                               f"again: {exc}")


def _poses(report, readings) -> None:
    """The still poses found by the detector and every candidate it rejected, with the reason
    (readings that kept their detection: iron, free-static, imported recordings)."""
    still = getattr(readings, "detection", None)
    if still is None:
        return
    t = readings.times - readings.times[0]
    rows = [(j + 1, f"{t[a]:.2f}", f"{t[b - 1]:.2f}", f"{t[b - 1] - t[a]:.2f}",
             f"{t[a] - t[a - settling]:.2f}", "pose")
            for j, ((a, b), settling) in enumerate(zip(still.intervals, still.settling,
                                                       strict=True))]
    rows += [("-", f"{t[a]:.2f}", f"{t[b - 1]:.2f}", f"{t[b - 1] - t[a]:.2f}", "-",
              f"rejected: {why}") for a, b, why in still.rejected]
    rows.sort(key=lambda row: float(row[1]))
    report.summary.update(still_poses=len(still.intervals), rejected_candidates=len(
        still.rejected))
    if still.rejected:
        report.warnings.append(f"{len(still.rejected)} still candidate(s) were rejected: see "
                               "Still poses (a declared --rest, --threshold or --min-still may "
                               "keep them).")
    report.sections.append(html.section("poses", "Still poses", (
        f"<p>{len(still.intervals)} still poses found and {len(still.rejected)} candidates (no "
        "motion for at least a window) rejected, seconds from the first sample; settling: the "
        "quieting motion cut from the start of the pose. Noise level per channel: "
        f"{html.e(', '.join(f'{x:.3g}' for x in still.noise))}.</p>")
        + html.table(rows, ["pose", "start (s)", "end (s)", "length (s)", "settling (s)",
                            "verdict"])))


# --------------------------------------------------------------------------------- the fit


def _fit(report, cal, channels, hand: bool = False) -> None:
    """chi2/dof, outliers (station.solve.quality; `hand`: poses placed by hand, judged with their
    per-pose error term) and the residual figure."""
    m, n = cal.residuals.shape
    z = cal.normalised_residuals
    check = check_fit(cal, channels, pose_term=hand)
    report.summary.update(method=cal.method, frame=cal.frame, magnitude=cal.magnitude,
                          chi2_per_dof=check.chi2_per_dof, dof=cal.dof,
                          noise_median=float(np.median(cal.sigma)), fit_status=check.status)
    if cal.sigma_estimated:
        report.warnings.append("The noise level of the readings was estimated from the residuals, "
                               "so chi2/dof is 1 by construction and cannot test the model.")
    elif check.notes:
        report.warnings.extend(note[0].upper() + note[1:] + "." for note in check.notes)
    elif check.p_high is not None and check.p_high < CHI2_P / 2:
        report.warnings.append(
            "The residuals are larger than the noise level: the model does not explain the data "
            "(an effect the model lacks, a position disturbed during its window, readings timed "
            f"wrongly, or noise underestimated); chi2/dof = {check.chi2_per_dof:.2f}, expected "
            f"1 +- {math.sqrt(2 / cal.dof):.2f}.")
    elif check.p_high is not None and 1 - check.p_high < CHI2_P / 2:
        report.warnings.append(
            "The residuals are smaller than the noise level: the noise of the readings is "
            f"overestimated; chi2/dof = {check.chi2_per_dof:.2f}, expected 1 +- "
            f"{math.sqrt(2 / cal.dof):.2f}.")
    limit, outliers = check.limit, check.outliers
    if outliers:
        report.warnings.append(f"Residual outliers beyond {limit:.1f} sigma: "
                               f"{outlier_words(outliers, channels)}. "
                               "Check those positions (mounting, disturbance) "
                               "or record them again.")
    report.summary["outliers"] = len(outliers)
    report.plots.append(html.Plot("residuals", "Residuals against the noise level", (
        f"Left: r_ij / sigma_ij for each sensor (row) and position (column); the model predicts "
        f"values of about +-1, cells beyond +-{limit:.1f} are outliers (marked). Right: histogram "
        f"of all {m * n} normalised residuals against the normal law the fit predicts (variance "
        f"dof / (m n) = {cal.dof}/{m * n}, the fit absorbs the rest)."), _residual_png(
            z, channels, limit, cal.dof)))


def _residual_png(z, channels, limit, dof) -> bytes:
    m, n = z.shape
    fig = Figure(figsize=(11, 0.28 * m + 2.2))
    grid = fig.add_gridspec(1, 2, width_ratios=(2.2, 1))
    ax = fig.add_subplot(grid[0])
    bound = max(4.0, limit)
    im = ax.imshow(z, cmap="RdBu_r", vmin=-bound, vmax=bound, aspect="auto",
                   extent=(0.5, n + 0.5, m + 0.5, 0.5))
    rows, cols = np.nonzero(np.abs(z) > limit)
    ax.plot(cols + 1, rows + 1, "kx", ms=8, label="outlier")
    ax.set_yticks(np.arange(1, m + 1), channels)
    ax.set_xlabel("position j")
    ax.set_ylabel("sensor")
    fig.colorbar(im, ax=ax, label="r / sigma")
    hist = fig.add_subplot(grid[1])
    hist.hist(z.ravel(), bins=max(10, int(np.sqrt(z.size))), density=True, color="#7a9cc6")
    sd = math.sqrt(dof / z.size) if dof > 0 else 1.0
    x = np.linspace(-bound, bound, 200)
    hist.plot(x, stats.norm.pdf(x, scale=sd), "k-", label=f"N(0, {sd:.2f}^2)")
    hist.set_xlabel("r / sigma")
    hist.set_ylabel("density")
    hist.legend(loc="upper right", fontsize=8)
    return html.png(fig)


# -------------------------------------------------------------------------------- geometry


def _geometry(report, cal) -> None:
    """Excitation of each direction by the stimuli, the emptiest region, the coverage figure."""
    v = cal.v
    d, n = v.shape
    w, vecs = np.linalg.eigh(v @ v.T)
    ratio = float(w[0] / w[-1]) if w[-1] > 0 else 0.0
    u = v / np.linalg.norm(v, axis=0)
    cap_deg, emptiest = _largest_empty_cap(u) if d == 3 else (math.nan, None)
    report.summary.update(excitation_ratio=ratio, largest_empty_cap_deg=cap_deg)
    weak = vecs[:, 0]
    if ratio < WEAK_EXCITATION:
        report.warnings.append(
            f"Weak geometry: the positions excite direction ({_vec(weak)}) only {ratio:.0%} as "
            "much as the strongest direction (condition of the design sum v v^T = "
            f"{1 / max(ratio, 1e-300):.3g}); add positions with the stimulus along it.")
    if d == 3 and cap_deg > EMPTY_CAP_DEG:
        report.warnings.append(f"No position within {cap_deg:.0f} deg of direction "
                               f"({_vec(emptiest)}) or its opposite; a position there would "
                               "spread the orientations better.")
    if d == 3:
        report.plots.append(html.Plot("coverage", "Coverage of the orientations", (
            f"Stimulus directions v_j / |v_j| of the {n} positions in the frame of a (dots, "
            "numbered) and their opposites (rings: the readings determine a through v v^T, so "
            f"+-v carry the same information). Largest empty region: {cap_deg:.0f} deg around "
            f"the star. Weakest / strongest excitation {ratio:.2f} (1 = evenly spread)."),
            _coverage_png(u, emptiest)))


def _largest_empty_cap(u, points: int = 4000) -> tuple:
    """Angular radius (deg) of the largest cap holding no direction +-u_j, and its centre
    (searched on a Fibonacci grid of `points` directions)."""
    i = np.arange(points) + 0.5
    zg = 1 - 2 * i / points
    phi = np.pi * (1 + np.sqrt(5)) * i
    grid = np.column_stack([np.sqrt(1 - zg**2) * np.cos(phi), np.sqrt(1 - zg**2) * np.sin(phi), zg])
    nearest = np.max(np.abs(grid @ u), axis=1)  # cos of the angle to the nearest +-u_j
    k = int(np.argmin(nearest))
    return float(np.degrees(np.arccos(np.clip(nearest[k], -1, 1)))), grid[k]


def _coverage_png(u, emptiest) -> bytes:
    fig = Figure(figsize=(10, 5.2))
    ax = fig.add_subplot(projection="mollweide")
    for sign, style in ((1, {"c": "#1f5fa8", "s": 30}),
                        (-1, {"facecolors": "none", "edgecolors": "#1f5fa8", "s": 30})):
        lon, lat = _lonlat(sign * u)
        ax.scatter(lon, lat, **style)
        if sign == 1:
            for j, (x, y) in enumerate(zip(lon, lat, strict=True)):
                ax.annotate(str(j + 1), (x, y), xytext=(4, 3), textcoords="offset points",
                            fontsize=7)
    lon, lat = _lonlat(emptiest[:, None])
    ax.scatter(lon, lat, marker="*", s=160, c="#d1495b", label="emptiest direction")
    ax.grid(True, alpha=0.4)
    ax.set_title("longitude atan2(y, x), latitude asin(z)", fontsize=9)
    ax.legend(loc="lower right", fontsize=8)
    return html.png(fig)


def _lonlat(u) -> tuple:
    return np.arctan2(u[1], u[0]), np.arcsin(np.clip(u[2], -1, 1))


def _axes_plot(report, cal, channels) -> None:
    """The sensitive axes, 3-D and projected on the coordinate planes."""
    if cal.d != 3:
        return
    frame = ("canonical frame of Eq. (19): sensor 1 along x, sensor 2 in the x-y plane"
             if cal.frame == "canonical" else "frame aligned to the nominal layout")
    report.plots.append(html.Plot("axes", "Sensitive axes", (
        f"Unit sensitive vectors a_i / |a_i| in the {frame}; 3-D view and projections on the "
        "x-y, x-z and y-z planes (unit circle dotted). Axes pointing the same way share one label; "
        f"an axis within {np.degrees(np.arcsin(SHORT_PROJECTION)):.0f} deg of a plane's normal "
        "is left unlabelled in that projection."),
        html.png(axes_figure(cal.a / np.linalg.norm(cal.a, axis=0), channels))))


SHORT_PROJECTION = 0.25
"""Projected length below which an axis is not labelled in a projection (it points at the
viewer: its label would sit on the origin, on top of every other such label)."""
LABEL_SEPARATION = 0.2
"""Distance (in units of the unit circle) within which arrow tips share one label."""


def axes_figure(unit, channels) -> Figure:
    """The figure of `_axes_plot` for unit vectors `unit` (3, m) named `channels`."""
    fig = Figure(figsize=(11, 8.5))
    ax3 = fig.add_subplot(2, 2, 1, projection="3d")
    for i in range(unit.shape[1]):
        ax3.quiver(0, 0, 0, *unit[:, i], color=f"C{i % 10}", arrow_length_ratio=0.08)
    for tip, names in _label_groups(unit, channels):
        ax3.text(*(1.12 * tip), names, fontsize=8, ha="center", va="center")
    for lim in (ax3.set_xlim, ax3.set_ylim, ax3.set_zlim):
        lim(-1, 1)
    ax3.set_xlabel("x")
    ax3.set_ylabel("y")
    ax3.set_zlabel("z")
    for k, (p, q) in enumerate(((0, 1), (0, 2), (1, 2))):
        ax = fig.add_subplot(2, 2, k + 2)
        ax.add_patch(_circle())
        flat = unit[[p, q]]
        for i in range(unit.shape[1]):
            ax.annotate("", tuple(flat[:, i]), (0, 0),
                        arrowprops={"arrowstyle": "->", "color": f"C{i % 10}"})
        long = np.linalg.norm(flat, axis=0) >= SHORT_PROJECTION
        for tip, names in _label_groups(flat[:, long], np.asarray(channels)[long]):
            _outward_label(ax, tip, names)
        ax.set_xlim(-1.6, 1.6)
        ax.set_ylim(-1.6, 1.6)
        ax.set_aspect("equal")
        ax.set_xlabel("xyz"[p])
        ax.set_ylabel("xyz"[q])
    return fig


def _label_groups(tips, names) -> list:
    """[(mean tip, "g1, g4, g10")]: the arrow tips (d, m) within `LABEL_SEPARATION` of a group's
    first tip share its label, so that labels of axes pointing the same way do not overprint."""
    groups = []
    for i in range(tips.shape[1]):
        for group in groups:
            if np.linalg.norm(tips[:, group[0]] - tips[:, i]) < LABEL_SEPARATION:
                group.append(i)
                break
        else:
            groups.append([i])
    return [(tips[:, g].mean(axis=1), ", ".join(str(names[i]) for i in g)) for g in groups]


def _outward_label(ax, tip, text: str) -> None:
    """`text` just beyond the arrow tip `tip` (2,), aligned away from the origin."""
    direction = tip / np.linalg.norm(tip)
    ha = "left" if direction[0] > 0.5 else "right" if direction[0] < -0.5 else "center"
    va = "bottom" if direction[1] > 0.5 else "top" if direction[1] < -0.5 else "center"
    ax.annotate(text, tuple(tip + 0.06 * direction), fontsize=8, ha=ha, va=va)


def _circle():
    from matplotlib.patches import Circle

    return Circle((0, 0), 1, fill=False, ls=":", color="#888")


# ----------------------------------------------------------------------------- uncertainty


def _uncertainty(report, cal, channels, units) -> None:
    """Table and figure of every parameter's estimate and 1-sigma uncertainty."""
    m = cal.m
    k, sk = cal.scale_factors, cal.scale_factors_sigma
    rows = []
    for i in range(m):
        row = [channels[i], f"{k[i]:.6f}", f"{sk[i]:.2g}"]
        if cal.bias is not None:
            row += [f"{cal.bias[i]:.4g}", f"{cal.bias_sigma[i]:.2g}" if cal.bias_sigma is not None
                    else "given", units[i]]
        rows.append(row)
    head = ("sensor", "scale factor |a_i|", "1 sigma") + (
        ("bias b_i", "1 sigma", "unit") if cal.bias is not None else ())
    angle = np.degrees(cal.axis_angles)
    angle_sd = np.degrees(cal.axis_angles_sigma)
    matrix = [[html.e(channels[i])]
              + [f"{angle[i, j]:.3f} &plusmn; {angle_sd[i, j]:.1e}" if j > i else ""
                 for j in range(m)] for i in range(m)]
    scale = "" if cal.scale_known else (" Scale factors are known only up to one common factor "
                                        "(magnitude unknown, Remark 2).")
    report.sections.append(html.section(
        "parameters", "Parameters and their uncertainty",
        f"<p>One standard deviation from the Fisher information of the fit.{scale}</p>"
        + html.table(rows, head) + "<h3>Angles between sensitive axes (deg, &plusmn; 1 sigma)</h3>"
        + html.table(matrix, ("",) + tuple(channels), escape_cells=False)))
    fig = Figure(figsize=(11, 3.8))
    panels = 3 if cal.bias is not None else 2
    ax = fig.add_subplot(1, panels, 1)
    x = np.arange(1, m + 1)
    ax.errorbar(x, (k - np.median(k)) * 1e3, yerr=sk * 1e3, fmt="o", capsize=3)
    ax.set_xticks(x, channels, rotation=90, fontsize=7)
    ax.set_ylabel("scale factor - median (x 1e-3)")
    if cal.bias is not None:
        ax = fig.add_subplot(1, panels, 2)
        sb = cal.bias_sigma if cal.bias_sigma is not None else np.zeros(m)
        ax.errorbar(x, cal.bias, yerr=sb, fmt="o", capsize=3, color="C1")
        ax.set_xticks(x, channels, rotation=90, fontsize=7)
        ax.set_ylabel(f"bias ({units[0]})")
    ax = fig.add_subplot(1, panels, panels)
    shown = np.where(np.eye(m, dtype=bool), np.nan, angle_sd * 3600)
    im = ax.imshow(shown, cmap="viridis")
    ax.set_xticks(np.arange(m), channels, rotation=90, fontsize=7)
    ax.set_yticks(np.arange(m), channels, fontsize=7)
    fig.colorbar(im, ax=ax, label="1 sigma of angle (arcsec)")
    drawn = "Scale factors (minus their median) and biases" if cal.bias is not None else \
        "Scale factors (minus their median; the biases were not estimated in this fit)"
    report.plots.append(html.Plot("uncertainty", "Uncertainty of each parameter", (
        f"{drawn} with 1-sigma error bars; 1-sigma uncertainty of the angle between each pair of "
        "sensitive axes."), html.png(fig)))


# ------------------------------------------------------------------------- recorded streams


def _stream_health(report, name, data, events) -> None:
    """Sample counts, sequence gaps, arrival latency, link counters if recorded."""
    rate = data.spec.rate_hz
    k = len(data.seq)
    health = {"stream": name, "samples": k, "rate_hz": rate}
    if name == "imu" or "device" not in report.summary:
        report.summary.update(device=data.spec.device or "?", sensors=len(data.spec.channels),
                              rate_hz=rate, samples=k)
    if k < 2:
        report.warnings.append(f"Stream {name!r} holds {k} sample(s): nothing to analyse.")
        return
    breaks = np.sort(segment_breaks(events))
    same_segment = np.diff(np.searchsorted(breaks, data.host_time, side="right")) == 0
    step = np.diff(data.seq)
    gaps = (step > 1) & same_segment  # a resumed recording may number its samples anew
    missing = int(np.sum(step[gaps] - 1))
    backwards = int(np.sum((step <= 0) & same_segment))
    t = sample_times(data.seq, data.host_time, rate, breaks)
    latency = data.host_time - t  # NaN: held back while the station was down (sample_times)
    span = float(np.nanmax(t) - np.nanmin(t))
    health.update(duration_s=span, gaps=int(gaps.sum()), missing=missing,
                  out_of_order=backwards, held_back=int(np.isnan(t).sum()),
                  latency_median_ms=float(np.nanmedian(latency) * 1e3),
                  latency_max_ms=float(np.nanmax(latency) * 1e3),
                  longest_silence_s=float(np.max(np.diff(data.host_time))))
    if name == "imu":
        report.summary["duration_s"] = span
    link = _link_counters(events)
    if missing or backwards:
        report.warnings.append(
            f"Stream {name!r} lost {missing} sample(s) in {int(gaps.sum())} gap(s)"
            + (f" and has {backwards} repeated or out-of-order sequence number(s)" if backwards
               else "") + "; check the link (cable, baud rate, bus load).")
    for key, value in link.items():
        if key in ("crc_failures", "bad_lines", "resyncs", "incomplete", "errors", "short") \
                and isinstance(value, int | float) and value > 0:
            report.warnings.append(f"The link counted {value} {key.replace('_', ' ')}.")
    rows = [(key.replace("_", " "), _fmt(value)) for key, value in health.items()]
    rows += [(f"link: {key.replace('_', ' ')}", _fmt(value)) for key, value in link.items()]
    note = "" if link else ("<p>The driver's link counters (CRC failures, resyncs) are not "
                            "recorded in this session file.</p>")
    report.sections.append(html.section(f"stream-{name}", f"Stream health: {name}",
                                        html.table(rows) + note))
    report.plots.append(html.Plot(f"stream-{name}", f"Stream health: {name}", (
        f"Top: samples received per second of the session clock against the nominal {rate:g} Hz "
        "(the last bin may be partial), "
        "sequence gaps marked in red. Bottom: arrival latency of each sample (host time minus "
        "its sampling instant from the sequence number)."), _stream_png(data, t, latency, gaps)))


def _link_counters(events) -> dict:
    """The newest `link` object recorded in an event's detail (e.g. a `note` at the end of the
    recording: {"text": ..., "link": vars(driver.stats)}), else {}."""
    for e in reversed(events):
        link = e.detail.get("link")
        if isinstance(link, dict):
            return {str(k): v for k, v in link.items() if isinstance(v, int | float | str)}
    return {}


def _stream_png(data, t, latency, gaps) -> bytes:
    fig = Figure(figsize=(11, 5))
    top, bottom = fig.subplots(2, 1, sharex=True)
    start, end = float(data.host_time[0]), float(data.host_time[-1])
    width = max(1.0, (end - start) / 150)  # arrivals come in blocks: bins of many blocks
    edges = start + width * np.arange(math.ceil((end - start) / width) + 1)
    if len(edges) >= 2:
        counts, _ = np.histogram(data.host_time, edges)
        top.step(edges[:-1], counts / width, where="post", lw=0.8,
                 label=f"received (bins of {width:.2g} s)")
    top.axhline(data.spec.rate_hz, color="k", ls="--", lw=0.8, label="nominal")
    for x in t[1:][gaps]:
        top.axvline(x, color="#d1495b", lw=0.8)
    top.set_ylabel("samples / s")
    top.legend(loc="lower right", fontsize=8)
    every = max(1, len(t) // 20000)
    bottom.plot(t[::every], latency[::every] * 1e3, ",", color="#444")
    bottom.set_ylabel("arrival latency (ms)")
    bottom.set_xlabel("session clock (s)")
    return html.png(fig)


def _table_stability(report, table, events, metadata) -> None:
    """Measured rate against the setpoint; error inside the rotating windows (a two-axis
    session's spins of the position axis left out: the table states are the rate axis')."""
    if len(table.time) < 2:
        return
    spins = position_spins(events)
    windows = {j: w for j, w in position_windows(events).items() if j not in spins}
    settings = metadata.get("settings") if isinstance(metadata.get("settings"), dict) else {}
    tolerance = settings.get("tolerance")
    rows, spans = [], []
    for j, w in windows.items():
        t0, t1 = w["rotating"]
        inside = (table.time >= t0) & (table.time <= t1)
        if inside.any():
            err = table.rate[inside] - table.rate_setpoint[inside]
            rows.append((str(j + 1), f"{np.mean(table.rate[inside]):.5f}",
                         f"{np.mean(err) * 1e3:+.3f}", f"{np.std(err) * 1e3:.3f}",
                         f"{np.max(np.abs(err)) * 1e3:.3f}"))
            spans.append((j, t0, t1, float(np.max(np.abs(err)))))
    if isinstance(tolerance, int | float):
        off = [str(j + 1) for j, _, _, worst in spans if worst > tolerance]
        if off:
            report.warnings.append(f"The table rate left its tolerance (+-{tolerance:g} rad/s) in "
                                   f"the rotating window of position(s) {', '.join(off)}.")
    if rows:
        report.sections.append(html.section(
            "table-rate", "Table rate in the rotating windows", html.table(
                rows, ("position", "mean rate (rad/s)", "mean error (mrad/s)",
                       "sd (mrad/s)", "max |error| (mrad/s)"))))
    report.plots.append(html.Plot("table", "Table rate stability", (
        "Top: measured table rate and setpoint (rotating windows shaded). Bottom: measured minus "
        "commanded rate inside the rotating windows"
        + (f", tolerance +-{tolerance:g} rad/s dashed." if isinstance(tolerance, int | float)
           else ".")), _table_png(table, spans, tolerance)))


def _table_png(table, spans, tolerance) -> bytes:
    fig = Figure(figsize=(11, 5))
    top, bottom = fig.subplots(2, 1, sharex=True)
    top.plot(table.time, table.rate, lw=0.8, label="measured")
    top.plot(table.time, table.rate_setpoint, lw=0.8, ls="--", label="setpoint")
    for _, t0, t1, _ in spans:
        top.axvspan(t0, t1, color="#cfe3f3", lw=0)
    top.set_ylabel("rate (rad/s)")
    top.legend(loc="upper right", fontsize=8)
    for _, t0, t1, _ in spans:
        inside = (table.time >= t0) & (table.time <= t1)
        bottom.plot(table.time[inside], (table.rate - table.rate_setpoint)[inside] * 1e3,
                    ".-", ms=2, lw=0.6, color="C0")
    if isinstance(tolerance, int | float):
        for s in (-1, 1):
            bottom.axhline(s * tolerance * 1e3, color="#d1495b", ls="--", lw=0.8)
    bottom.set_ylabel("rate error (mrad/s)")
    bottom.set_xlabel("session clock (s)")
    return html.png(fig)


# ----------------------------------------------------------------------------------- helpers


def _fmt(value) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _vec(u) -> str:
    return ", ".join(f"{x:+.2f}" for x in u)


def _short(detail: dict, limit: int = 200) -> str:
    text = ", ".join(f"{k}: {v}" for k, v in detail.items())
    return text if len(text) <= limit else text[:limit - 3] + "..."
