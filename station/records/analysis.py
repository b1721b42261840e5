"""The questions the store answers: a unit's history with its drift, and the fleet report (yield,
per-model distributions, control charts, the benches' health, outliers).

Drift between two calibrations of a unit, per parameter: (x2 - x1) / sqrt(s1^2 + s2^2), in
sigmas of the difference (each 1-sigma is the calibration's own; |drift| > 3 is unlikely to be
noise). Control charts and run rules: `station.records.spc`.
"""

import numpy as np

from station.records import spc

MAX_LISTED = 20
"""Flags and outliers listed per chart / report (the counts are always whole)."""


def drift(before, after) -> list:
    """Per parameter both records have with a 1-sigma: {"parameter", "sensor", "change", "sigmas"}
    from `before` to `after`, the largest |sigmas| first."""
    old = {(p.name, p.sensor): p for p in before.parameters}
    out = []
    for p in after.parameters:
        q = old.get((p.name, p.sensor))
        if q is None or p.sigma is None or q.sigma is None:
            continue
        spread = float(np.hypot(p.sigma, q.sigma))
        if spread > 0:
            out.append({"parameter": p.name, "sensor": p.sensor, "unit": p.unit,
                        "change": p.value - q.value, "sigmas": (p.value - q.value) / spread})
    return sorted(out, key=lambda d: -abs(d["sigmas"]))


def history(records: list, serial: str) -> dict:
    """A unit's calibrations, oldest first, each with its drift from the one before; `largest`:
    the largest drift over the whole history (None with fewer than two calibrations)."""
    entries, largest = [], None
    for k, r in enumerate(records):
        steps = drift(records[k - 1], r) if k else []
        entries.append({"id": r.id, "created": r.created, "kind": r.kind, "model": r.model,
                        "verdict": r.verdict, "status": r.status, "bench": r.bench,
                        "session_path": r.session_path, "calibration_path": r.calibration_path,
                        "station_version": r.station_version,
                        "parameters": {f"{p.name} {p.sensor}": [p.value, p.sigma, p.unit]
                                       for p in r.parameters},
                        "drift": steps})
        if steps and (largest is None or abs(steps[0]["sigmas"]) > abs(largest["sigmas"])):
            largest = {**steps[0], "from": records[k - 1].id, "to": r.id}
    return {"unit_serial": serial, "calibrations": entries, "largest_drift": largest}


def yields(verdicts) -> dict:
    """{"judged", "PASS", "FAIL", "MARGINAL", "fraction"}: how many records were judged, of each
    verdict, and the fraction that passed (None when none was judged)."""
    counts = {v: 0 for v in ("PASS", "FAIL", "MARGINAL")}
    for v in verdicts:
        if v in counts:
            counts[v] += 1
    judged = sum(counts.values())
    return {"judged": judged, **counts, "fraction": counts["PASS"] / judged if judged else None}


def chart_document(x, ids, created, baseline: int, every_index: bool = False) -> dict:
    """A control chart's summary: points, centre, sigma, the rule violations (how many, the first
    MAX_LISTED with each point's record id, time and z) and the points beyond 3 sigma (the
    MAX_LISTED largest |z|), or only the points without a chart. ids, created: each point's
    record id and time (arrays). every_index: also `flagged`, the index of every point a rule
    flags (a short series')."""
    c = spc.chart(x, baseline)
    if c is None:
        return {"points": len(x), "chart": None, **({"flagged": []} if every_index else {})}

    def point(i: int, rule: str) -> dict:
        return {"index": i, "rule": rule, "id": int(ids[i]), "created": str(created[i]),
                "value": float(x[i]), "z": float(c.z[i])}

    beyond = np.flatnonzero(np.abs(c.z) > 3)
    largest = beyond[np.argsort(-np.abs(c.z[beyond]), kind="stable")][:MAX_LISTED]
    flags = [point(i, rule) for i, rule in c.violations[:MAX_LISTED]]
    return {"points": len(x), "chart": {"centre": c.centre, "sigma": c.sigma,
                                        "baseline": baseline},
            "violations": len(c.violations), "flags": flags,
            "first_flag": flags[0] if flags else None,
            "beyond_3_sigma": [point(int(i), "beyond_3_sigma") for i in largest],
            **({"flagged": sorted({i for i, _ in c.violations})} if every_index else {})}


def parameter_charts(series: list, summaries: list, baseline: int) -> dict:
    """{model: [{"parameter", "sensor", "unit", "n", "mean", "sd", "min", "max",
    ...chart_document}]}: one chart per model, parameter, sensor and unit (raw counts are never
    charted with SI values), its points in the records' time order. series: the store's
    [(name, sensor, unit, record ids, values)] (`Store.series`); summaries: the records' rows
    (`fleet`), in time order. Parameters of records not among the summaries (stored meanwhile)
    wait for the next report."""
    if not summaries:
        return {}
    ids = np.array([row[0] for row in summaries], dtype=np.int64)
    created = np.array([row[5] for row in summaries], dtype=object)
    labels = [row[2] or "unknown" for row in summaries]
    models = sorted(set(labels))
    code = {m: k for k, m in enumerate(models)}
    model_of = np.array([code[m] for m in labels], dtype=np.int64)
    by_id = np.argsort(ids)
    charts = {}
    for name, sensor, unit, record_ids, values in series:
        rank = _ranks(record_ids, ids, by_id)
        keep = rank >= 0
        order = np.argsort(rank[keep], kind="stable")
        rank, x = rank[keep][order], values[keep][order]
        for m in np.unique(model_of[rank]):
            mine = model_of[rank] == m
            v, r = x[mine], rank[mine]
            charts.setdefault(models[m], []).append({
                "parameter": name, "sensor": sensor, "unit": unit, "n": len(v),
                "mean": float(v.mean()),
                "sd": float(v.std(ddof=1)) if len(v) > 1 else None, "min": float(v.min()),
                "max": float(v.max()), **chart_document(v, ids[r], created[r], baseline)})
    return charts


def _ranks(record_ids: np.ndarray, ids: np.ndarray, by_id: np.ndarray) -> np.ndarray:
    """The time rank (index in `ids`, the records in time order) of each of `record_ids`, -1
    for an id not among them; by_id: argsort of ids."""
    sorted_ids = ids[by_id]
    pos = np.searchsorted(sorted_ids, record_ids).clip(max=len(ids) - 1)
    return np.where(sorted_ids[pos] == record_ids, by_id[pos], -1)


def bench_health(summaries: list, baseline: int) -> dict:
    """{bench: {"sessions", "table_rate_error": chart_document, "chamber_settling_s": ...}}: one
    point per session (the records of one session file share its figures), in time order."""
    benches = {}
    for row in summaries:
        rid, _, _, bench, session, created, _, rate, settling = row
        sessions = benches.setdefault(bench or "unknown", {})
        sessions.setdefault(session or f"record {rid}", (rid, created, rate, settling))
    out = {}
    for bench, sessions in benches.items():
        points = list(sessions.values())
        out[bench] = {"sessions": len(points),
                      **{name: _figure_chart(points, k, baseline)
                         for k, name in ((2, "table_rate_error"), (3, "chamber_settling_s"))}}
    return out


def _figure_chart(points: list, k: int, baseline: int) -> dict | None:
    """chart_document of column k of the sessions' points that have it, with the points
    themselves (values, created: one per session, few), None if none has."""
    have = [p for p in points if p[k] is not None]
    if not have:
        return None
    values, created = [float(p[k]) for p in have], [p[1] for p in have]
    return {**chart_document(np.array(values), [p[0] for p in have], created, baseline, True),
            "values": values, "created": created}


def outliers(models: dict) -> list:
    """Points beyond 3 sigma of their parameter's chart, the largest |z| first (MAX_LISTED)."""
    found = [{"model": model, "parameter": c["parameter"], "sensor": c["sensor"], **f}
             for model, charts in models.items() for c in charts
             for f in c.get("beyond_3_sigma", ())]
    return sorted(found, key=lambda f: -abs(f["z"]))[:MAX_LISTED]


def fleet(store, selection, baseline: int = spc.BASELINE) -> dict:
    """The fleet report of the records `selection` picks: yield (overall and per model),
    per-model parameter distributions with their control charts, the benches' health charts,
    and the outliers."""
    summaries = store.summaries(selection)
    models = parameter_charts(store.series(selection), summaries, baseline)
    by_model = {}
    for row in summaries:
        by_model.setdefault(row[2] or "unknown", []).append(row)
    return {"selection": selection.terms, "records": len(summaries),
            "units": len({row[1] for row in summaries}), "baseline": baseline,
            "yield": yields(row[6] for row in summaries),
            "models": {model: {"records": len(rows), "units": len({r[1] for r in rows}),
                               "yield": yields(r[6] for r in rows),
                               "parameters": models.get(model, [])}
                       for model, rows in by_model.items()},
            "benches": bench_health(summaries, baseline),
            "outliers": outliers(models)}
