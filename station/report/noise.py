"""The noise of a session's static data for people: the Allan deviation plot, the table of the
IEEE 952 terms, and the section of the session report (`station.reduce.noise`).

The plot is log-log: each channel's overlapping Allan deviation with its 68.3 % confidence band
(`allantools.confidence_interval` on the estimates' equivalent degrees of freedom), the fitted
model, and the fitted terms' own lines: slope -1/2 (N / sqrt(tau)), 0 (the floor
B sqrt(2 ln 2 / pi)) and +1/2 (K sqrt(tau / 3)), drawn for the median channel of each unit among
those whose table calls the term resolved (a term the table calls "not resolved" everywhere has no
line), named with their values in the legend.
"""

import math

import allantools
import numpy as np
from matplotlib.figure import Figure

from station.calfiles.calfile import noise_units
from station.errors import CalibrationInputError
from station.reduce.noise import SessionNoise, session_noise
from station.report import html
from station.solve.noise import FLOOR, TERMS

BAND = 0.6826894921370859
"""Confidence level of the bands drawn: 1 sigma of a normal law."""
WORDS = {"white": "white noise N", "bias_instability": "bias instability B",
         "random_walk": "random walk K"}


def summary(noise: SessionNoise) -> dict:
    """The figures as JSON-able data: per channel each term's value and 1-sigma with its unit
    (None: not resolved by the data), and what was analysed."""
    fit = noise.fit
    channels = []
    for c, (name, unit) in enumerate(zip(noise.channels, noise.units, strict=True)):
        entry = {"channel": name, "unit": unit}
        units = noise_units(unit)
        for k, term in enumerate(TERMS):
            ok = bool(fit.resolved[k, c])
            entry[term] = {"value": float(fit.value[k, c]) if ok else None,
                           "sigma": float(fit.sigma[k, c]) if ok else None, "unit": units[term]}
        channels.append(entry)
    return {"stream": noise.stream, "source": noise.source, "windows": len(noise.windows),
            "seconds": noise.curve.seconds, "rate_hz": noise.curve.rate,
            "taus_s": noise.curve.tau.tolist(), "channels": channels}


def rows(noise: SessionNoise) -> list:
    """Table rows: channel, then each term as 'value +- sigma unit' ('not resolved' if not)."""
    out = []
    for entry in summary(noise)["channels"]:
        cells = [entry["channel"]]
        for term in TERMS:
            t = entry[term]
            cells.append("not resolved" if t["value"] is None
                         else f"{t['value']:.3g} +- {t['sigma']:.2g} {t['unit']}")
        out.append(cells)
    return out


HEAD = ("channel", *(WORDS[t] for t in TERMS))


def allan_png(noise: SessionNoise) -> bytes:
    """The Allan deviation figure as PNG bytes."""
    return html.png(allan_figure(noise))


def allan_figure(noise: SessionNoise) -> Figure:
    """The Allan deviation figure (module docstring): one panel per unit of the stream."""
    units = sorted(set(noise.units))
    fig = Figure(figsize=(6 * len(units), 4.5))
    axes = fig.subplots(1, len(units), squeeze=False)[0]
    tau, fit, rate = noise.curve.tau, noise.fit, noise.curve.rate
    factors = np.unique(np.geomspace(noise.curve.m[0], noise.curve.m[-1], 64).round())
    dense = factors / rate
    for ax, unit in zip(axes, units, strict=True):
        cols = [c for c, u in enumerate(noise.units) if u == unit]
        for c in cols:
            dev = np.sqrt(noise.curve.avar[:, c])
            lo, hi = zip(*(allantools.confidence_interval(d, max(nu, 1e-3), BAND)
                           for d, nu in zip(dev, fit.edf[:, c], strict=True)), strict=True)
            line, = ax.loglog(tau, dev, "o", ms=3, label=noise.channels[c] if len(cols) <= 6
                              else (f"{len(cols)} channels" if c == cols[0] else None))
            ax.fill_between(tau, lo, hi, color=line.get_color(), alpha=0.15, lw=0)
            model = fit.model_avar(factors, rate)[:, c]  # below zero where a term fitted < 0
            ax.loglog(dense, np.sqrt(np.where(model > 0, model, np.nan)), "-", lw=0.7,
                      color=line.get_color())
        _slopes(ax, dense, fit.theta[cols], fit.resolved[:, cols], unit)
        ax.set_xlabel("averaging time tau (s)")
        ax.set_ylabel(f"Allan deviation ({unit})")
        ax.grid(True, which="both", lw=0.3)
        ax.legend(fontsize=7)
    return fig


def _slopes(ax, tau, theta, resolved, unit: str) -> None:
    """The lines of the fitted terms of the median channel among those whose table calls the term
    resolved (`resolved`: (3, c)): slopes -1/2, 0, +1/2, each named with its value in the legend;
    a term no channel resolves has no line."""
    units = noise_units(unit).values()
    shapes = (1.0 / tau, np.full_like(tau, FLOOR), tau / 3.0)
    for k, (shape, slope, name, u) in enumerate(zip(shapes, ("-1/2", "0", "+1/2"), "NBK", units,
                                                    strict=True)):
        if resolved[k].any():
            term = float(np.median(theta[resolved[k], k]))
            ax.loglog(tau, np.sqrt(term * shape), "--", lw=0.8, color=("k", "0.35", "0.6")[k],
                      label=f"slope {slope}: {name} = {math.sqrt(term):.3g} {u}")


def add_to_report(report, session, streams) -> None:
    """A section and a figure per stream of `streams` (of the session) whose static data give its
    noise; a stream without enough static data gets a line saying so."""
    for name in streams:
        try:
            noise = session_noise(session, name)
        except CalibrationInputError as exc:
            report.sections.append(html.section(f"noise-{name}", f"Noise: {name}",
                                                f"<p>{html.e(exc.problem)}</p>"))
            continue
        report.summary.setdefault("noise", {})[name] = summary(noise)
        what = (f"{noise.curve.seconds:.1f} s of static data in {len(noise.windows)} window(s) "
                f"({noise.source}), at {noise.curve.rate:g} Hz")
        report.sections.append(html.section(
            f"noise-{name}", f"Noise: {name}",
            f"<p>{html.e(what)}; 1-sigma after +-.</p>" + html.table(rows(noise), HEAD)))
        report.plots.append(html.Plot(
            f"allan-{name}", f"Allan deviation: {name}",
            "Overlapping Allan deviation of each channel (points) with its 68 % confidence band, "
            "the fitted model (solid) and the median channel's fitted terms that the table calls "
            "resolved (dashed: slope -1/2 white noise N, 0 bias instability B, +1/2 random walk "
            "K; IEEE Std 952-1997 Annex C).", allan_png(noise)))
