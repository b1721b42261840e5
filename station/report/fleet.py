"""The fleet report as one HTML page (`station fleet --html FILE`): yield, each model's parameter
charts with their run-rule flags, the benches' health charts (table rate error, chamber settling
per session, with the centre and 3-sigma limits of their baseline), and the outliers."""

from station.report.html import Plot, figure, page, png, section, table

BENCH_FIGURES = {"table_rate_error": ("table rate error", "measured / commanded - 1"),
                 "chamber_settling_s": ("chamber settling", "s")}


def fleet_page(report: dict, source: str) -> str:
    """The HTML page of a fleet report (`station.records.analysis.fleet`); `source`: the store."""
    y = report["yield"]
    head = section("yield", "Yield", table(
        [["all", report["records"], report["units"], y["judged"], y["PASS"], y["FAIL"],
          y["MARGINAL"], _pct(y["fraction"])]]
        + [[model, m["records"], m["units"], m["yield"]["judged"], m["yield"]["PASS"],
            m["yield"]["FAIL"], m["yield"]["MARGINAL"], _pct(m["yield"]["fraction"])]
           for model, m in report["models"].items()],
        ["model", "records", "units", "judged", "PASS", "FAIL", "MARGINAL", "yield"]))
    models = "".join(section(f"model-{model}", f"Model {model}: parameters and control charts",
                             table([_chart_row(c) for c in m["parameters"]], CHART_HEAD))
                     for model, m in report["models"].items())
    benches = "".join(figure(_bench_plot(bench, name, doc))
                      for bench, health in report["benches"].items()
                      for name, doc in health.items() if isinstance(doc, dict))
    outliers = section("outliers", "Outliers (beyond 3 sigma of their chart)", table(
        [[o["model"], o["parameter"], o["sensor"], o["id"], o["created"], f"{o['value']:.6g}",
          f"{o['z']:+.1f}"] for o in report["outliers"]],
        ["model", "parameter", "sensor", "record", "created", "value", "z"]))
    return page("Fleet report", source, head + models + benches + outliers)


CHART_HEAD = ["parameter", "sensor", "unit", "n", "mean", "sd", "centre", "sigma", "violations",
              "first flag"]


def _chart_row(c: dict) -> list:
    """One chart's row of a model's table (CHART_HEAD)."""
    chart, first = c.get("chart"), c.get("first_flag")
    return [c["parameter"], c["sensor"], c["unit"], c["n"], f"{c['mean']:.6g}",
            "-" if c["sd"] is None else f"{c['sd']:.3g}",
            "-" if chart is None else f"{chart['centre']:.6g}",
            "-" if chart is None else f"{chart['sigma']:.3g}", c.get("violations", "-"),
            "-" if first is None else f"{first['rule']} at record {first['id']} "
                                      f"({first['created']})"]


def _pct(fraction) -> str:
    """A fraction in percent, "-" when unknown."""
    return "-" if fraction is None else f"{100 * fraction:.1f} %"


def _bench_plot(bench: str, name: str, doc: dict) -> Plot:
    """The chart of one bench health figure: points per session, centre +- 3 sigma, flags."""
    from matplotlib.figure import Figure

    words, unit = BENCH_FIGURES[name]
    fig = Figure(figsize=(8, 3))
    ax = fig.add_subplot()
    x = range(len(doc["values"]))
    ax.plot(x, doc["values"], "o-", ms=3, lw=0.8)
    chart = doc.get("chart")
    if chart is not None:
        for k, style in ((0, "-"), (3, "--"), (-3, "--")):
            ax.axhline(chart["centre"] + k * chart["sigma"], color="gray", ls=style, lw=0.8)
        ax.plot(doc["flagged"], [doc["values"][i] for i in doc["flagged"]], "rx", ms=8)
    ax.set_xlabel("session")
    ax.set_ylabel(unit)
    first = doc.get("first_flag")
    caption = (f"{words} ({unit}) per session, centre and 3-sigma limits of the first "
               f"{chart['baseline'] if chart else '-'} sessions, run-rule flags as crosses; "
               f"{doc['points']} sessions; " + ("no baseline chart (too few sessions)"
                                                if chart is None else
               f"first flag: {first['rule']} at session {first['index'] + 1} ({first['created']})"
               if first else "no run rule fired"))
    return Plot(f"bench-{bench}-{name}", f"Bench {bench}: {words}", caption, png(fig))
