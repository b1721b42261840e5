"""`station fleet [KEY=VALUE ...]`: the line's calibrations from the record store: yield, each
model's parameter distributions and control charts, the benches' health, the outliers.

Control charts (docs/records.md, "Fleet"): a Shewhart X chart per model, parameter and sensor in
time order, its centre and sigma from the first --baseline points; each point judged by the
Western Electric / Nelson run rules (1 beyond 3 sigma, 2 of 3 beyond 2 sigma, 8 in a row on one
side, 6 in a row trending). The benches' health: the table rate error (and a thermal chamber's
settling) of each session, charted and judged the same way, so a drifting rate table is flagged
while its units still pass. The words select records as `--from-db` does (serial, model, lot,
bench, verdict, since, until, ...); by default the one-session calibrations (kind=session: a
combined file's sessions are counted once, as sessions; kind=campaign for thermal campaigns).
"""

import json
import sys


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    from station.commands import store_argument
    from station.records.spc import BASELINE

    p.description = __doc__
    p.epilog = ("examples:\n  station fleet\n  station fleet model=imu12-serial since=2026-11-23\n"
                "  station fleet bench=bench2 --json\n  station fleet --html fleet.html\n"
                "  station fleet --csv > charts.csv\n\n"
                "exit code 0: no run rule fired on a bench's health; 1: a bench is flagged")
    p.add_argument("query", nargs="*", metavar="KEY=VALUE",
                   help="which records (default all): serial, model, lot, bench, verdict, kind, "
                        "operator, host, session, table, chamber, imu, since, until")
    store_argument(p)
    p.add_argument("--baseline", type=int, default=BASELINE, metavar="N",
                   help=f"points of each chart's baseline period (default {BASELINE})")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--json", action="store_true", help="machine-readable report")
    out.add_argument("--csv", action="store_true",
                     help="one CSV row per chart (model, parameter, sensor, distribution, "
                          "limits, flags) on stdout")
    p.add_argument("--html", metavar="FILE", help="also write the report as an HTML page")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.commands import existing_store, new_file
    from station.errors import InputError
    from station.records.analysis import fleet
    from station.records.query import Selection

    if args.baseline < 2:
        raise InputError(f"--baseline {args.baseline}: give 2 points or more (20-25 is usual)")
    html = None if args.html is None else new_file(args.html, "--html")
    selection = Selection.parse(" ".join(args.query))
    if "kind" not in selection.terms:  # a combined file re-counts its sessions
        selection = Selection({**selection.terms, "kind": "session"})
    with existing_store(args.db) as store:
        report = fleet(store, selection, args.baseline)
        where = store.where
    if html is not None:
        from station.report.fleet import fleet_page

        html.write_text(fleet_page(report, where), encoding="utf-8")
    if args.json:
        print(json.dumps(report, indent=2))
    elif args.csv:
        write_csv(report, sys.stdout)
    else:
        print(text(report))
    return 1 if flagged_benches(report) else 0


def flagged_benches(report: dict) -> list:
    """(bench, figure, first flag) of every bench health chart a run rule fired on."""
    return [(bench, name, doc["first_flag"]) for bench, health in report["benches"].items()
            for name, doc in health.items()
            if isinstance(doc, dict) and doc.get("first_flag")]


CSV_HEAD = ("model", "parameter", "sensor", "unit", "n", "mean", "sd", "min", "max", "centre",
            "sigma", "violations", "first_rule", "first_record", "first_created")


BENCH_UNITS = {"table_rate_error": "1", "chamber_settling_s": "s"}
"""The unit of each bench health figure."""


def write_csv(report: dict, out) -> None:
    """One row per parameter chart (CSV_HEAD), then one per bench health chart."""
    import csv

    w = csv.writer(out)
    w.writerow(CSV_HEAD)
    rows = [(model, c) for model, m in report["models"].items() for c in m["parameters"]]
    rows += [(f"bench {bench}", {"parameter": name, "sensor": "", "unit": BENCH_UNITS[name],
                                 "n": doc["points"],
                                 "mean": None, "sd": None, "min": None, "max": None, **doc})
             for bench, health in report["benches"].items()
             for name, doc in health.items() if isinstance(doc, dict)]
    for model, c in rows:
        chart, first = c.get("chart") or {}, c.get("first_flag") or {}
        w.writerow([model, c["parameter"], c["sensor"], c["unit"], c["n"], c["mean"], c["sd"],
                    c["min"], c["max"], chart.get("centre"), chart.get("sigma"),
                    c.get("violations"), first.get("rule"), first.get("id"),
                    first.get("created")])


def text(r: dict) -> str:
    """The report in words: yield, the flagged charts, the benches, the outliers."""
    y = r["yield"]
    lines = [f"{r['records']} calibrations of {r['units']} units; yield "
             + (f"{100 * y['fraction']:.1f} % ({y['PASS']} PASS, {y['FAIL']} FAIL, "
                f"{y['MARGINAL']} MARGINAL of {y['judged']} judged)" if y["judged"]
                else "unknown (no verdicts: no tolerances given)")]
    for model, m in r["models"].items():
        charts = m["parameters"]
        flagged = [c for c in charts if c.get("first_flag")]
        my = m["yield"]
        lines.append(f"model {model}: {m['records']} calibrations, {m['units']} units, yield "
                     + ("-" if my["fraction"] is None else f"{100 * my['fraction']:.1f} %")
                     + f"; {len(flagged)} of {len(charts)} control charts flagged")
        lines += [f"  {c['parameter']} {c['sensor']} ({c['unit']}): {c['first_flag']['rule']} at "
                  f"record "
                  f"{c['first_flag']['id']} ({c['first_flag']['created']}), {c['violations']} "
                  f"violations; mean {c['mean']:.6g}, sd {c['sd']:.3g}" for c in flagged]
    for bench, health in r["benches"].items():
        for name, doc in health.items():
            if not isinstance(doc, dict):
                continue
            first = doc.get("first_flag")
            state = ("not charted (fewer sessions than the baseline)" if doc["chart"] is None
                     else f"FLAGGED: {first['rule']} at session {first['index'] + 1} "
                          f"({first['created']}, value {first['value']:.3g})" if first
                     else "in control")
            lines.append(f"bench {bench}: {name.replace('_', ' ')} over {doc['points']} "
                         f"sessions: {state}")
    lines += [f"outlier: record {o['id']} ({o['created']}) {o['parameter']} {o['sensor']} "
              f"z {o['z']:+.1f}" for o in r["outliers"]]
    return "\n".join(lines)
