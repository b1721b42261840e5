"""The diagnosis as JSON, as text and as an HTML report with a plot of the gap shrinking."""

import base64
import html
import io

import numpy as np

from station.diagnose.model import parameters
from station.diagnose.select import log_sf
from station.diagnose.static import StaticData, untestable
from station.diagnose.static_report import white_noise_verdict


def jsonable(obj):
    """JSON-ready copy: arrays to lists, numpy scalars to numbers, NaN and inf to None."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [jsonable(v) for v in np.asarray(obj, dtype=object).tolist()] if isinstance(
            obj, np.ndarray) else [jsonable(v) for v in obj]
    if isinstance(obj, (np.generic, float)):
        x = obj.item() if isinstance(obj, np.generic) else obj
        return None if isinstance(x, float) and not np.isfinite(x) else x
    return obj


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


def to_dict(diagnosis, data, source: str = "") -> dict:
    """The JSON document of a diagnosis; `effects` is the ordered list of named effects."""
    steps = [step_dict(step) for step in diagnosis.steps]
    n, k, m = data.shape
    return jsonable({
        "session": source,
        "protocol": "rotary",
        "positions": n,
        "sensors": m,
        "samples_per_position": k,
        "fs": data.fs,
        "noise_sigma": data.sigma,
        "alpha": diagnosis.alpha,
        "effects": diagnosis.effects,
        "steps": steps,
        "calibration_before": calibration_summary(diagnosis.steps[0].model.calibration),
        "calibration_after": calibration_summary(diagnosis.final.calibration),
    })


def text(doc: dict) -> str:
    """A short human-readable summary."""
    lines = [f"effects: {', '.join(doc['effects']) or 'none'} (alpha {doc['alpha']})"]
    for step in doc["steps"]:
        gap = " ".join(f"{k}={v:.3g}" for k, v in step["gap"].items())
        lines.append(f"model {' + '.join(step['model'])}: gap {gap}")
        for name, e in sorted(step["evidence"].items(), key=lambda x: x[1]["log10_p"]):
            mark = "*" if e["significant"] else " "
            lines.append(f"  {mark} {name:19s} LR {e['lr']:10.1f}  dof {e['dof']:3d}  "
                         f"log10 p {e['log10_p']:9.1f}")
        lines.append(f"  -> {step['chosen']}")
    for name, params in doc["steps"][-1]["parameters"].items():
        shown = {k: v["value"] for k, v in params.items() if not isinstance(v["value"], list)}
        lines.append(f"{name}: {shown}")
    lines.extend(doc.get("remarks", []))
    return "\n".join(lines)


def plot_png(doc: dict) -> bytes:
    """PNG of each gap statistic against the model steps (log scale, 1 = explained)."""
    plt = pyplot()

    labels = ["+".join(s["model"][1:]) or "nominal" for s in doc["steps"]]
    fig, ax = plt.subplots(figsize=(7, 4))
    for stat in doc["steps"][0]["gap"]:
        ax.plot(range(len(labels)), [max(s["gap"][stat], 1e-3) for s in doc["steps"]],
                marker="o", label=stat)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_yscale("log")
    ax.set_xticks(range(len(labels)), labels, rotation=15, fontsize=8)
    ax.set_ylabel("gap (1 = explained by the noise)")
    ax.set_title("Gap between the session and its twin")
    ax.legend(fontsize=7)
    return png(fig)


def pyplot():
    """matplotlib.pyplot on the Agg backend, imported when a plot is drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def png(fig) -> bytes:
    """The figure as PNG bytes (laid out tight), closed."""
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    pyplot().close(fig)
    return buf.getvalue()


def html_report(doc: dict, extra: str = "") -> str:
    """A self-contained HTML page: summary, plot (and `extra` HTML), evidence tables,
    parameters."""
    png = base64.b64encode(plot_png(doc)).decode()
    rows = []
    for step in doc["steps"]:
        rows.append(f"<h3>Model: {html.escape(' + '.join(step['model']))}</h3>")
        rows.append("<table border=1><tr><th>statistic</th><th>gap</th></tr>" + "".join(
            f"<tr><td>{k}</td><td>{v:.3g}</td></tr>" for k, v in step["gap"].items()) + "</table>")
        if step["evidence"]:
            rows.append("<table border=1><tr><th>candidate</th><th>LR</th><th>dof</th>"
                        "<th>log10 p</th><th>significant</th></tr>" + "".join(
                            f"<tr><td>{k}</td><td>{e['lr']:.1f}</td><td>{e['dof']}</td>"
                            f"<td>{e['log10_p']:.1f}</td><td>{e['significant']}</td></tr>"
                            for k, e in step["evidence"].items()) + "</table>")
        rows.append(f"<p>chosen: <b>{html.escape(step['chosen'])}</b></p>")
    return (
        "<!doctype html><html><head><meta charset='utf-8'><title>station diagnose</title></head>"
        f"<body><h1>Diagnosis of {html.escape(str(doc['session']))}</h1>"
        f"<p>Named effects: <b>{html.escape(', '.join(doc['effects']) or 'none')}</b></p>"
        f"<img src='data:image/png;base64,{png}' alt='gap per step'>{extra}"
        f"{''.join(rows)}<h2>Summary</h2><pre>{html.escape(text(doc))}</pre></body></html>"
    )


# ------------------------------------------------------------------------- free-static sessions


def _evidence_with_quasi(evidence: dict, dispersion: float) -> dict:
    """The evidence entries plus log10 p of LR / dispersion (quasi-likelihood, dispersion >= 1)."""
    phi = max(dispersion, 1.0)
    return {k: {**e, "log10_p_quasi": log_sf(e["lr"] / (e["null_scale"] * phi), e["null_dof"])
                / np.log(10)} for k, e in evidence.items()}


def static_to_dict(diagnosis, data: StaticData, source: str = "") -> dict:
    """The JSON document of a free-static diagnosis (same layout as the rotary one)."""
    steps = [step_dict(step, _evidence_with_quasi(step.evidence, step.gap["within"]))
             for step in diagnosis.steps]
    white = white_noise_verdict(data, diagnosis.steps[-1], diagnosis.alpha)
    lengths = (data.intervals[:, 1] - data.intervals[:, 0]) / data.fs
    not_testable = untestable(data, diagnosis.steps[0].model.base)
    remarks = [white["message"], *data.notes] + [
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
        "alpha": diagnosis.alpha,
        "effects": diagnosis.effects,
        "not_testable": not_testable,
        "white_noise": white,
        "steps": steps,
        "calibration_before": _summary(diagnosis.steps[0].model.calibration),
        "calibration_after": _summary(diagnosis.final.calibration),
        "remarks": remarks,
    })


def _summary(cal):
    """calibration_summary, or None without a calibration (poses not spread enough)."""
    return None if cal is None else calibration_summary(cal)


def whiteness_png(doc: dict) -> bytes:
    """PNG of the block-mean scatter ratio against the block length (1 = white noise)."""
    plt = pyplot()

    fig, ax = plt.subplots(figsize=(7, 3.5))
    for group, ratios in doc["white_noise"]["ratio_by_block_s"].items():
        ax.plot([float(s) for s in ratios], list(ratios.values()), marker="o", label=group)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("block length, s")
    ax.set_ylabel("scatter / white noise")
    ax.set_title("Scatter of block means within the still intervals")
    ax.legend(fontsize=7)
    return png(fig)


def static_html_report(doc: dict) -> str:
    """The rotary report's page plus the white-noise plot."""
    png = base64.b64encode(whiteness_png(doc)).decode()
    return html_report(doc, extra=f"<img src='data:image/png;base64,{png}' "
                                         "alt='block-mean scatter against block length'>")
