"""The diagnosis as JSON, as text and as an HTML report with a plot of the gap shrinking."""

import numpy as np

from station.diagnose import outliers
from station.diagnose.goodness import log_sf
from station.diagnose.model import parameters
from station.diagnose.select import WHY
from station.diagnose.static import StaticData, untestable
from station.diagnose.static_report import white_noise_verdict
from station.files.jsonable import jsonable
from station.report import html


def calibration_summary(cal) -> dict:
    """Scale factors, a (canonical frame) and the fit of a CalibrationResult."""
    return {
        "frame": cal.frame,
        "a": cal.a,
        "a_sigma": cal.a_sigma,
        "scale_factors": cal.scale_factors,
        "scale_factors_sigma": cal.scale_factors_sigma,
        "chi2": cal.chi2,
        "dof": cal.dof,
    }


def step_dict(step, evidence=None) -> dict:
    """One step of a diagnosis (station.diagnose.select.Step) for the JSON document; `evidence`
    replaces the step's own (e.g. with quasi-likelihood p-values added)."""
    return {
        "model": ["nominal", *step.model.names],
        "gap": step.gap,
        "deviance": step.model.deviance,
        "parameters": {k: parameters(f) for k, f in step.model.fitted.items()},
        "notes": {k: f.notes for k, f in step.model.fitted.items() if f.notes},
        "evidence": step.evidence if evidence is None else evidence,
        "chosen": step.chosen,
    }


def to_dict(diagnosis, data, source: str = "", noise_source: str | None = None) -> dict:
    """The JSON document of a diagnosis; `effects` is the ordered list of named effects;
    noise_source: the calibration file whose bias random walk is in the noise model."""
    steps = [step_dict(step) for step in diagnosis.steps]
    n, k, m = data.shape
    spikes = data.outlier_test(diagnosis.alpha)
    said = outliers.message(spikes, [f"sensor {i}" for i in range(m)],
                            "its position's steady model in the table rate")
    grid = data.quantisation_report()
    coarse = [grid["message"] + "; an effect within a window smaller than the step (a slope, a "
              "tone) is hidden by it: record with finer counts to see one"] if grid["message"] \
        else []
    return jsonable({
        "session": source,
        "protocol": "rotary",
        "positions": n,
        "sensors": m,
        "samples_per_position": k,
        "fs": data.fs,
        "noise_sigma": data.sigma,
        "noise_model": noise_model(data, noise_source),
        "alpha": diagnosis.alpha,
        **verdict(diagnosis),
        "outliers": spikes,
        "quantisation": grid,
        "findings": ([said] if spikes["detected"] else []) + coarse,
        "remarks": [] if spikes["detected"] else [said],
        "steps": steps,
        "calibration_before": calibration_summary(diagnosis.steps[0].model.calibration),
        "calibration_after": calibration_summary(diagnosis.calibration),
        "spectrum": diagnosis.spectrum,
    })


def noise_model(data, source: str | None) -> dict:
    """The noise the gaps are judged against: each sensor's white noise per sample (from the
    static windows) and, from a calibration file's noise figures, its bias random walk K (units
    / sqrt(s)) and flicker's bias instability B (units) where the file resolves them
    (station.diagnose.coloured)."""
    names = {"random_walk": "bias random walk", "bias_instability": "flicker"}
    found = [names[t] for t in names if getattr(data, t) is not None]
    said = f"noise model: {' and '.join(['white noise', *found])}"
    if found:
        said += f" (from {source})"
    else:
        said += ("; give the unit's noise figures (--noise CAL.cal.json) to judge the gaps "
                 "against its bias random walk and flicker")
    return {"white_sigma": data.sigma, "random_walk": data.random_walk,
            "bias_instability": data.bias_instability, "source": source if found else None,
            "message": said}


def verdict(diagnosis) -> dict:
    """The named effects with the share of their own gap each closes, the unexplained gaps with
    their signatures, the candidates that resemble the gap with implausible parameters or are
    not named for another reason (`not_named`), the final goodness-of-fit test and the held-out
    check of the correction (station.diagnose.select.Diagnosis)."""
    return {"effects": diagnosis.effects, "closes": diagnosis.closes,
            "unexplained": diagnosis.unexplained, "ambiguous": diagnosis.ambiguous,
            "resembles": diagnosis.resembles,
            "not_named": list(diagnosis.not_named), "fit_test": diagnosis.fit_test,
            "correction": diagnosis.correction}


def closes_line(name: str, closes: dict | None) -> str:
    """"bias_drift closes 97 % of its gap (static 99 %, trend 80 %); 3 % unexplained", or how
    that its own statistics were within the noise before it; "PARTIAL" while one of them fails."""
    if not closes or closes["fraction"] is None:
        return f"{name}: its own gap statistics were within the noise before it"
    f = closes["fraction"]
    by = ", ".join(f"{k} {100 * v:.0f} %" for k, v in closes["by_statistic"].items())
    mark = "PARTIAL: " if closes.get("partial") else ""
    return (f"{mark}{name} closes {100 * f:.0f} % of its gap ({by}); {100 * (1 - f):.0f} % "
            "unexplained")


def ambiguous_line(group: dict) -> str:
    """"AMBIGUOUS: a or b (log10 p ...): indistinguishable on this session ...; record X"."""
    p = ", ".join(f"{k} {v:.1f}" for k, v in group["log10_p"].items())
    why = group.get("why", WHY)
    return (f"AMBIGUOUS: {' or '.join(group['effects'])} (log10 p {p}): indistinguishable on "
            f"this session ({why}); corrected with neither. To tell them apart, record "
            f"{group['told_apart_by']}")


def text(doc: dict) -> str:
    """A short human-readable summary."""
    lines = [f"effects: {', '.join(doc['effects']) or 'none'} (alpha {doc['alpha']})",
             *(closes_line(k, doc.get("closes", {}).get(k)) for k in doc["effects"]),
             *map(ambiguous_line, doc.get("ambiguous", [])), *doc.get("findings", [])]
    lines += [f"not named: {closes_line(p['effect'], p['closes'])} (log10 p "
              f"{p['log10_p']:.1f}): {p['reason']}" for p in doc.get("not_named", [])]
    for u in doc.get("unexplained", []):
        lines.append(f"UNEXPLAINED: {u['statistic']} gap {u['gap']:.3g} on {u['dof']} dof "
                     f"(log10 p {u['log10_p']:.1f}, threshold "
                     f"{doc['fit_test']['threshold_log10_p']:.2f}): {_signature_line(u)}")
    paired = {k for group in doc.get("ambiguous", []) for k in group["effects"]}
    lines += [f"not an effect: {k}: {e['within_noise']}" for step in doc["steps"][:1]
              for k, e in step["evidence"].items() if e.get("within_noise") and k not in paired]
    for r in doc.get("resembles", []):
        if r.get("not_named"):
            continue
        lines.append(f"resembles {r['effect']} (log10 p {r['log10_p']:.1f}), parameters "
                     f"implausible: {r['reason']}")
    c = doc.get("correction")
    if c:
        lines.append(f"correction {'applied' if c['applied'] else 'NOT applied'}: held-out "
                     f"chi2 {c['held_out_chi2_before']:.1f} uncorrected -> "
                     f"{c['held_out_chi2_after']:.1f} corrected ({c['positions']} positions)"
                     + (f"; withheld: {c['withheld']}" if c.get("withheld") else ""))
    for step in doc["steps"]:
        gap = " ".join(f"{k}={v:.3g}" for k, v in step["gap"].items())
        lines.append(f"model {' + '.join(step['model'])}: gap {gap}")
        for name, e in sorted(step["evidence"].items(), key=lambda x: x[1]["log10_p"]):
            mark = "*" if e["significant"] else " "
            lines.append(f"  {mark} {name:19s} LR {e['lr']:10.1f}  dof {e['dof']:3d}  "
                         f"log10 p {e['log10_p']:9.1f}")
        lines.append(f"  -> {step['chosen']}")
    for name, key, value, sigma, unit in parameter_rows(doc):
        lines.append(f"{name} {key} = {value} +- {sigma} {unit}".rstrip())
    lines.extend(doc.get("remarks", []))
    if "noise_model" in doc:
        lines.append(doc["noise_model"]["message"])
    return "\n".join(lines)


def parameter_rows(doc: dict) -> list:
    """(effect, parameter, value, 1 sigma, unit) of the final model's fitted parameters, values
    as numbers: an array's elements in order, a matrix's rows separated by ";"."""
    return [(name, key, numbers(p["value"]), numbers(p["sigma"]), p.get("unit", ""))
            for name, params in doc["steps"][-1]["parameters"].items()
            for key, p in params.items()]


def numbers(value) -> str:
    """A JSON number, list or list of lists as "1.2e-05", "1 2 3" or "1 2; 3 4"."""
    if isinstance(value, list):
        return ("; " if value and isinstance(value[0], list) else " ").join(
            numbers(v) for v in value)
    return "nan" if value is None else f"{value:.4g}"


def _signature_line(u: dict) -> str:
    """One line of an unexplained gap's signature."""
    s = u["signature"]
    if "peaks" in s:
        return "; ".join(f"{p['power']:.2f} x noise at {p['frequency']:g} x the table rate "
                         f"({p['sense'].replace('_', ' ')})" for p in s["peaks"][:3])
    if "by_channel" in s:
        return (f"worst channel {int(np.argmax(s['by_channel']))}, interval "
                f"{int(np.argmax(s['by_interval']))}; correlation with time "
                f"{s['correlation_with_time']:.2f}; gravity direction R2 "
                f"{s['gravity_direction_r2']:.2f} (noise {s['gravity_direction_r2_noise']:.2f})")
    if "by_sensor" not in s:
        return s.get("note", "")
    comp = max(s["by_component"].items(), key=lambda x: x[1])
    return (f"worst sensor {int(np.argmax(s['by_sensor']))}, position "
            f"{int(np.argmax(s['by_position']))}, component {comp[0]} ({comp[1]:.2g}); "
            f"correlation with the table-axis projection "
            f"{s['correlation_with_table_axis_projection']:.2f}, time "
            f"{s['correlation_with_time']:.2f}, rate sign {s['correlation_with_rate_sign']:.2f}; "
            f"table-angle R2 {s['table_angle_harmonic_r2']:.2f}")


def gap_plot(doc: dict) -> html.Plot:
    """Each gap statistic against the model steps (log scale, 1 = explained)."""
    from matplotlib.figure import Figure  # here: the CLI imports this module, not matplotlib

    labels = ["+".join(s["model"][1:]) or "nominal" for s in doc["steps"]]
    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    for stat in doc["steps"][0]["gap"]:
        ax.plot(range(len(labels)), [max(s["gap"][stat], 1e-3) for s in doc["steps"]],
                marker="o", label=stat)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_yscale("log")
    ax.set_xticks(range(len(labels)), labels, rotation=15, fontsize=8)
    ax.set_ylabel("gap (1 = explained by the noise)")
    ax.set_title("Gap between the session and its twin")
    ax.legend(fontsize=7)
    return html.Plot("gap", "Gap per model step", "Each gap statistic of the session against "
                     "its twin, per model step (1 = explained by the noise).", html.png(fig))


def unexplained_plots(doc: dict) -> list:
    """One figure per unexplained gap statistic: its mean square feature by sensor (channel) and
    by position (interval); and the residual spectrum when the session has one."""
    from matplotlib.figure import Figure

    plots = []
    for u in doc.get("unexplained", []):
        s = u["signature"]
        sensors, parts = s.get("by_sensor", s.get("by_channel")), s.get("by_position",
                                                                         s.get("by_interval"))
        if sensors is None:
            continue
        fig = Figure(figsize=(7, 3))
        left, right = fig.subplots(1, 2)
        left.bar(range(len(sensors)), sensors)
        right.bar(range(len(parts)), parts)
        for ax, what in ((left, "sensor (channel)"), (right, "position (interval)")):
            ax.axhline(1.0, color="k", lw=0.8, ls="--")
            ax.set_xlabel(what)
        left.set_ylabel("mean square (1 = noise)")
        fig.suptitle(f"Unexplained: {u['statistic']}")
        plots.append(html.Plot(f"unexplained-{u['statistic']}", f"Unexplained {u['statistic']}",
                               "Where the unexplained gap sits: by sensor and by position "
                               "(1 = white noise).", html.png(fig)))
    spec = doc.get("spectrum")
    if spec and doc.get("unexplained"):
        fig = Figure(figsize=(7, 3.5))
        ax = fig.subplots()
        for sense in ("with_table", "against_table", "axial"):
            ax.plot(spec["frequency"], spec[sense], label=sense.replace("_", " "))
        ax.axhline(1.0, color="k", lw=0.8, ls="--")
        ax.set_xlabel("frequency / table rate")
        ax.set_ylabel("power / white noise")
        ax.legend(fontsize=7)
        plots.append(html.Plot("spectrum", "Residual spectrum", "Residual of the rotating "
                               "windows at multiples of the table rate, turning with or against "
                               "the table, and along its axis (1 = white noise).", html.png(fig)))
    return plots


def html_report(doc: dict, plots=()) -> str:
    """The self-contained page (station.report.html): the named effects, the gap plot (and
    `plots`), one section per model step with its gap and evidence tables, the text summary."""
    e = html.e
    steps = []
    for step in doc["steps"]:
        tables = html.table([(k, f"{v:.3g}") for k, v in step["gap"].items()],
                            ("statistic", "gap"))
        if step["evidence"]:
            tables += html.table(
                [(k, f"{v['lr']:.1f}", v["dof"], f"{v['log10_p']:.1f}", v["significant"])
                 for k, v in step["evidence"].items()],
                ("candidate", "LR", "dof", "log10 p", "significant"))
        steps.append(html.section(
            f"step-{len(steps)}", f"Model: {' + '.join(step['model'])}",
            f"{tables}<p>chosen: <b>{e(step['chosen'])}</b></p>"))
    effects = f"<p>Named effects: <b>{e(', '.join(doc['effects']) or 'none')}</b></p>"
    effects += "".join(f"<p>{e(closes_line(k, doc.get('closes', {}).get(k)))}</p>"
                       for k in doc["effects"])
    effects += "".join(f"<p><b>Not named:</b> {e(closes_line(p['effect'], p['closes']))}: "
                       f"{e(p['reason'])}</p>" for p in doc.get("not_named", []))
    effects += "".join(f"<p><b>{e(f)}</b></p>" for f in (
        *map(ambiguous_line, doc.get("ambiguous", [])), *doc.get("findings", [])))
    if doc.get("unexplained"):
        effects += ("<p><b>Unexplained:</b> " + e(", ".join(u["statistic"]
                                                          for u in doc["unexplained"])) + "</p>")
    if "noise_model" in doc:
        effects += f"<p>{e(doc['noise_model']['message'])}</p>"
    rows = parameter_rows(doc)
    if rows:
        effects += html.section("parameters", "Fitted parameters of the final model", html.table(
            rows, ("effect", "parameter", "value", "1 sigma", "unit")))
    figures = "".join(html.figure(p) for p in (gap_plot(doc), *unexplained_plots(doc), *plots))
    summary = html.section("summary", "Summary", f"<pre>{e(text(doc))}</pre>")
    return html.page(f"Diagnosis of {doc['session']}", str(doc["session"]),
                     effects + figures + "".join(steps) + summary)


# ------------------------------------------------------------------------- free-static sessions


def _evidence_with_quasi(evidence: dict, dispersion: float) -> dict:
    """The evidence entries plus log10 p of LR / dispersion (quasi-likelihood, dispersion >= 1)."""
    phi = max(dispersion, 1.0)
    return {k: {**e, "log10_p_quasi": log_sf(e["lr"] / (e["null_scale"] * phi), e["null_dof"])
                / np.log(10)} for k, e in evidence.items()}


def static_to_dict(diagnosis, data: StaticData, source: str = "",
                   noise_source: str | None = None) -> dict:
    """The JSON document of a free-static diagnosis (same layout as the rotary one)."""
    steps = [step_dict(step, _evidence_with_quasi(step.evidence, step.gap["within"]))
             for step in diagnosis.steps]
    white = white_noise_verdict(data, diagnosis.steps[-1], diagnosis.alpha)
    names = channel_names(data)
    spikes = data.outlier_test(diagnosis.alpha)
    said = outliers.message(spikes, names)
    grid = data.quantisation(names, [data.units[i] if i < len(data.units) else ""
                                     for i in range(data.c)])
    lengths = (data.intervals[:, 1] - data.intervals[:, 0]) / data.fs
    not_testable = untestable(data, diagnosis.steps[0].model.base)
    remarks = [white["message"], *([] if spikes["detected"] else [said]), *data.notes] + [
        f"not testable in a static session: {k} ({v})" for k, v in not_testable.items()]
    return jsonable({
        "session": source,
        "protocol": "free_static",
        "intervals": len(data.intervals),
        "interval_s": {"min": lengths.min(), "median": float(np.median(lengths)),
                       "max": lengths.max()},
        "bins": len(data.bins),
        "accelerometer_channels": data.m,
        "gyro_channels": data.c - data.m,
        "units": list(data.units),
        "fs": data.fs,
        "gravity": data.gravity,
        "noise_sigma": data.sigma,
        "noise_model": noise_model(data, noise_source),
        "alpha": diagnosis.alpha,
        **verdict(diagnosis),
        "not_testable": not_testable,
        "white_noise": white,
        "outliers": spikes,
        "quantisation": grid,
        "findings": [*([said] if spikes["detected"] else []), *filter(None, [grid["message"]]),
                     *diagnosis.caveats],
        "steps": steps,
        "calibration_before": _summary(diagnosis.steps[0].model.calibration),
        "calibration_after": _summary(diagnosis.calibration),
        "remarks": remarks,
    })


def channel_names(data: StaticData) -> list:
    """acc1.. for the accelerometer channels, gyro1.. for the gyro's."""
    return [f"acc{i + 1}" for i in range(data.m)] + [f"gyro{i + 1}" for i in range(data.c - data.m)]


def _summary(cal):
    """calibration_summary, or None without a calibration (poses not spread enough)."""
    return None if cal is None else calibration_summary(cal)


def whiteness_plot(doc: dict) -> html.Plot:
    """The block-mean scatter ratio against the block length (1 = white noise)."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(7, 3.5))
    ax = fig.subplots()
    for group, ratios in doc["white_noise"]["ratio_by_block_s"].items():
        ax.plot([float(s) for s in ratios], list(ratios.values()), marker="o", label=group)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("block length, s")
    ax.set_ylabel("scatter / white noise")
    ax.set_title("Scatter of block means within the still intervals")
    ax.legend(fontsize=7)
    return html.Plot("white-noise", "Block-mean scatter against block length", "Scatter of the "
                     "block means within the still intervals over the white-noise expectation "
                     "(1 = white noise).", html.png(fig))


def static_html_report(doc: dict) -> str:
    """The rotary report's page plus the white-noise plot."""
    return html_report(doc, plots=(whiteness_plot(doc),))
