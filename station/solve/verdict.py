"""PASS or FAIL: a calibrated unit against the tolerances of its type.

Each tested parameter's estimate x with its 1-sigma s is compared with its nominal value x0 and
its tolerance T (the largest accepted |x - x0|):

    pass      |x - x0| + MARGIN s <= T      (inside the tolerance, beyond reasonable doubt)
    fail      |x - x0| - MARGIN s >  T      (outside it, beyond reasonable doubt)
    marginal  otherwise                     (within MARGIN sigma of the limit: measure again,
                                             with more positions or a longer window)

The unit passes when every tested parameter passes; it fails when any fails; else it is marginal.
Parameters (the tolerances' keys, in a bench profile's `[tolerances]` table):

    scale_factor    |k_i - 1| of each sensor (readings are SI through the device profile's scale,
                    so a perfect sensor has scale factor 1)
    bias            |b_i| of each sensor, in the readings' SI unit
    axis_angle_deg  |angle_ij - nominal angle_ij| of each pair of sensitive axes, degrees (the
                    angles are frame-free; tested only where the nominal layout is known)
"""

from dataclasses import dataclass, fields

import numpy as np

from station.errors import InputError

MARGIN = 2.0
"""Standard deviations between an estimate and a limit for a pass or a fail."""


@dataclass(frozen=True)
class Tolerances:
    """Largest accepted deviations of a unit type from nominal; None: not tested."""

    scale_factor: float | None = None
    bias: float | None = None
    axis_angle_deg: float | None = None

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if value is not None and not (isinstance(value, int | float)
                                          and not isinstance(value, bool) and value > 0):
                raise InputError(f"tolerance {f.name} must be a positive number, got {value!r}")

    @classmethod
    def from_table(cls, table: dict, where: str = "[tolerances]") -> "Tolerances":
        """Tolerances from a TOML table (untrusted), naming `where` in any refusal."""
        if not isinstance(table, dict):
            raise InputError(f"{where} must be a table of tolerances")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(table) - known)
        if unknown:
            raise InputError(f"{where}: unknown tolerance(s) {unknown}; known: {sorted(known)}")
        try:
            return cls(**table)
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None

    @property
    def empty(self) -> bool:
        return all(getattr(self, f.name) is None for f in fields(self))


def recorded_tolerances(metadata: dict, path):
    """The `[tolerances]` of the bench profile a session was recorded with, or None."""
    bench = metadata.get("bench")
    tables = bench.get("tables") if isinstance(bench, dict) else None
    if not isinstance(tables, dict) or "tolerances" not in tables:
        return None
    return Tolerances.from_table(tables["tolerances"], f"{path}: the bench profile's [tolerances]")


def judge(deviation: float, sigma: float, limit: float) -> str:
    """"pass", "fail" or "marginal" for |x - x0| = deviation with 1-sigma `sigma`."""
    if deviation + MARGIN * sigma <= limit:
        return "pass"
    if deviation - MARGIN * sigma > limit:
        return "fail"
    return "marginal"


def verdict(cal, tolerances: Tolerances, names=None, nominal=None) -> dict:
    """The verdict on `cal` (anything with scale_factors, bias, axis_angles and their _sigma
    arrays, e.g. a calibration file or a CalibrationResult): {"overall": "PASS" | "FAIL" |
    "MARGINAL", "parameters": [...], "untested": [...]} with one entry per tested parameter
    (name, value, sigma, nominal, limit, verdict). names: the sensors' (default s1..sm);
    nominal: the nominal layout (d x m) for the axis angles, or None."""
    names = list(names) if names is not None else [f"s{i + 1}" for i in range(len(
        cal.scale_factors))]
    items, untested = [], []
    if tolerances.scale_factor is not None:
        items += [(f"{n} scale factor", k, s, 1.0, tolerances.scale_factor)
                  for n, k, s in zip(names, cal.scale_factors, cal.scale_factors_sigma,
                                     strict=True)]
    if tolerances.bias is not None:
        if cal.bias is None or cal.bias_sigma is None:
            untested.append("bias (not measured)")
        else:
            items += [(f"{n} bias", b, s, 0.0, tolerances.bias)
                      for n, b, s in zip(names, cal.bias, cal.bias_sigma, strict=True)]
    if tolerances.axis_angle_deg is not None:
        if nominal is None:
            untested.append("axis angles (no nominal layout)")
        else:
            u = np.asarray(nominal, float) / np.linalg.norm(nominal, axis=0)
            angle0 = np.degrees(np.arccos(np.clip(u.T @ u, -1, 1)))
            angle, sd = np.degrees(cal.axis_angles), np.degrees(cal.axis_angles_sigma)
            i, j = np.triu_indices(len(names), 1)
            items += [(f"angle {names[p]}-{names[q]} (deg)", angle[p, q], sd[p, q],
                       angle0[p, q], tolerances.axis_angle_deg) for p, q in zip(i, j, strict=True)]
    parameters = [{"name": name, "value": float(x), "sigma": float(s), "nominal": float(x0),
                   "limit": float(t), "verdict": judge(abs(x - x0), s, t)}
                  for name, x, s, x0, t in items]
    found = {p["verdict"] for p in parameters}
    overall = "FAIL" if "fail" in found else "MARGINAL" if "marginal" in found else "PASS"
    return {"overall": overall, "margin_sigma": MARGIN, "parameters": parameters,
            "untested": untested}


def words(v: dict) -> str:
    """The verdict in plain words, one line per parameter that did not pass."""
    tested = len(v["parameters"])
    head = f"VERDICT: {v['overall']} ({tested} parameters tested"
    head += f"; not tested: {', '.join(v['untested'])})" if v["untested"] else ")"
    lines = [head, tested_words(v)]
    for p in v["parameters"]:
        if p["verdict"] != "pass":
            lines.append(f"  {p['verdict'].upper()}: {p['name']} {p['value']:.6g} +- "
                         f"{p['sigma']:.2g}, tolerance {p['nominal']:.6g} +- {p['limit']:.3g}")
    return "\n".join(lines)


def tested_words(v: dict) -> str:
    """What the verdict `v` tested against what, in one line: each kind of parameter with its
    count and limit, and the rule."""
    kinds = (("scale factor", "scale factors", lambda n: n.endswith(" scale factor"),
              "|k - 1| <= {:g}"),
             ("bias", "biases", lambda n: n.endswith(" bias"), "|b| <= {:g}"),
             ("axis angle", "axis angles", lambda n: n.startswith("angle "),
              "within {:g} deg of nominal"))
    parts = []
    for one, many, match, limit in kinds:
        found = [p for p in v["parameters"] if match(p["name"])]
        if found:
            parts.append(f"{len(found)} {one if len(found) == 1 else many} "
                         + limit.format(max(p["limit"] for p in found)))
    return (f"  tested against the unit type's tolerances: {', '.join(parts) or 'none'}; each "
            f"passes when its estimate +- {v['margin_sigma']:g} sigma is inside the limit, fails "
            "when outside, else is marginal")
