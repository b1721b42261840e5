"""`station combine`: the calibration files of several sessions of one unit -> one calibration for
its next session, with the repeatability between sessions (`station.calfiles.combined`).

One session's 1-sigma covers that session only. Re-seat the unit, switch it on again, and its
biases (and, less, its scale factors and axes) move by more than that (turn-on repeatability,
mounting, temperature). Given K >= 2 files of the same unit, solved with the same sensors, units,
frame and magnitude, each class of parameters (the entries of a, the biases, the scale factors,
the axis angles) gets a between-session standard deviation tau (random effects: the posterior
mean of tau^2 under the restricted likelihood and a weak half-Cauchy prior, so that a few sessions
that happen to agree do not give a tau of 0; the Paule-Mandel point estimate and a 95 % upper
bound beside it; the output says how many sessions each rests on); the combined file holds the
weighted means and, as every 1-sigma, the figure for the next session: sqrt(sigma_mean^2 + tau^2),
widened for the few degrees of freedom tau was estimated from (docs/solvers.md "Repeatability").
"""

import json
from pathlib import Path

import numpy as np


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    from station.commands import db_arguments

    p.description = __doc__
    p.epilog = (
        "examples:\n  station combine exp_1.cal.json exp_2.cal.json exp_3.cal.json "
        "--out array.cal.json\n"
        "  station combine SN42-mon.cal.json SN42-tue.cal.json --out SN42.cal.json --json\n"
        "  station combine --from-db \"serial=SN42 since=2026-11-01\" --out SN42.cal.json\n\n"
        "exit code 0: written; 1: a source file is marked suspect (written marked suspect); "
        "2: bad input"
    )
    p.add_argument("calibrations", type=Path, nargs="*", metavar="CAL",
                   help="calibration files (.cal.json) of the sessions, from `station solve`")
    p.add_argument("--from-db", metavar="QUERY",
                   help="instead of CAL files: the session calibrations of the record store "
                        "(--db) that the query picks, e.g. \"serial=SN42 since=2026-11-01\" "
                        "(docs/records.md); each file is checked against its recorded sha256")
    p.add_argument("--out", type=Path, required=True, help="combined calibration file to write")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    db_arguments(p)
    p.add_argument("--json", action="store_true", help="machine-readable summary")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.calfiles.calfile import load
    from station.calfiles.combined import combine
    from station.commands import existing_file, keep_records, new_file, queried_files
    from station.errors import InputError

    out = new_file(args.out, force=args.force)
    if bool(args.calibrations) == bool(args.from_db):
        raise InputError("give the calibration files to combine, or --from-db QUERY (not both)")
    paths = args.calibrations or queried_files(args.db, args.from_db, "session")
    names = [str(p) for p in paths]
    cals = [load(existing_file(p, "a calibration file (.cal.json)")) for p in paths]
    cal = combine(cals, names)
    cal.save(out, overwrite=args.force)
    within = np.median([c.bias_sigma for c in cals], axis=0)
    summary = {"calibration": str(out), "unit_serial": cal.unit_serial, "sessions": len(cals),
               "status": cal.fit["status"], "status_reasons": cal.fit["status_reasons"],
               "repeatability": cal.fit["repeatability"], "bias": cal.bias.tolist(),
               "bias_sigma": cal.bias_sigma.tolist(), "bias_sigma_session": within.tolist(),
               "scale_factors": cal.scale_factors.tolist(),
               "scale_factors_sigma": cal.scale_factors_sigma.tolist()}
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(_text(cal, cals, out))
    return max(0 if cal.fit["status"] == "good" else 1, keep_records(args, [out], "combined"))


def _text(cal, cals, out) -> str:
    """The summary in words: each class's tau against the sessions' own 1-sigma, and the table."""
    rep = cal.fit["repeatability"]
    lines = [f"unit {cal.unit_serial}: {len(cals)} sessions combined; every 1-sigma is the figure "
             "for the next session (pooled mean + the spread between sessions); each tau rests on "
             f"{len(cals)} sessions: the posterior mean of tau^2 (REML, a weak prior), never 0 "
             "(the sessions cannot exclude a spread below their own noise)"]
    own = {"a": [c.a_sigma for c in cals], "bias": [c.bias_sigma for c in cals],
           "scale_factors": [c.scale_factors_sigma for c in cals],
           "axis_angles": [c.axis_angles_sigma for c in cals]}
    for name, r in rep.items():
        sigma = np.median(np.array(own[name])[np.array(own[name]) > 0])
        lines.append(f"  {name:13s} between sessions tau {r['tau']:.3g} (95 % upper bound "
                     f"{r['tau_upper']:.3g}, point estimate {r['tau_point']:.3g}; Q {r['q']:.1f} "
                     f"on {r['dof']} dof); one session's median 1-sigma {sigma:.3g}")
    lines.append(f"  {'sensor':>10} {'scale factor':>13} {'1 sigma':>9} {'bias':>12} "
                 f"{'1 sigma':>9} {'(session)':>9}")
    within = np.median([c.bias_sigma for c in cals], axis=0)
    for i, name in enumerate(cal.sensors):
        lines.append(f"  {name:>10} {cal.scale_factors[i]:13.6f} {cal.scale_factors_sigma[i]:9.2g}"
                     f" {cal.bias[i]:12.6g} {cal.bias_sigma[i]:9.2g} {within[i]:9.2g}")
    if cal.fit["status"] != "good":
        lines.append("SUSPECT: " + "; ".join(cal.fit["status_reasons"]))
    lines.append(f"written to {out}")
    return "\n".join(lines)
