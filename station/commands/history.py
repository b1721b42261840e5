"""`station history SERIAL`: every calibration of a unit in the record store, oldest first, with
the drift between consecutive calibrations in sigmas, per parameter, the largest named.

Drift of a parameter from one calibration to the next: (x2 - x1) / sqrt(s1^2 + s2^2), each 1-sigma
the calibration's own (docs/records.md). Beyond about 3 it is unlikely to be noise: the unit moved
(or its bench did: `station fleet` shows the benches' health).
"""

import json


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    from station.commands import store_argument

    p.description = __doc__
    p.epilog = ("examples:\n  station history SN1234\n"
                "  station history SN1234 --last 3 --parameter bias   # its last three biases\n"
                "  station history SN1234 --db postgresql://station@db.line/calibrations --json")
    p.add_argument("serial", help="the unit's serial number")
    store_argument(p)
    p.add_argument("--last", type=int, metavar="N",
                   help="only the last N calibrations (the drift of the first from the one "
                        "before it is kept)")
    p.add_argument("--parameter", metavar="NAME",
                   help="also list this parameter of every sensor at each calibration, with its "
                        "1-sigma and drift: bias, scale_factor, noise_white, ...")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.commands import existing_store
    from station.errors import InputError
    from station.records.analysis import history

    with existing_store(args.db) as store:
        records = store.history(args.serial)
        where = store.where
    if not records:
        raise InputError(f"no calibration of unit {args.serial!r} in the record store {where}; "
                         "check the serial, or the store (--db, `station db import DIR`)")
    if args.last is not None and args.last < 1:
        raise InputError(f"--last {args.last}: give 1 or more calibrations")
    h = history(records, args.serial)
    if args.last is not None:
        h["calibrations"] = h["calibrations"][-args.last:]
    if args.parameter is not None and not any(
            key.split(" ")[0] == args.parameter for c in h["calibrations"]
            for key in c["parameters"]):
        raise InputError(f"unit {args.serial} has no parameter {args.parameter!r}; its "
                         f"parameters: {', '.join(names(h))}")
    print(json.dumps(h, indent=2) if args.json else text(h, args.parameter))
    return 0


def names(h: dict) -> list:
    """The parameter names of a history's calibrations."""
    return sorted({key.split(" ")[0] for c in h["calibrations"] for key in c["parameters"]})


def text(h: dict, parameter: str | None = None) -> str:
    """The history in words: one line per calibration, its largest drift from the one before;
    with `parameter`, that parameter of every sensor under each line (value +- 1 sigma, drift
    from the calibration before in sigmas)."""
    lines = [f"unit {h['unit_serial']}: {len(h['calibrations'])} calibrations",
             f"{'record':>7} {'created':20} {'kind':8} {'verdict':8} {'bench':12} largest drift "
             "from the one before"]
    for c in h["calibrations"]:
        step = c["drift"][0] if c["drift"] else None
        words = (f"{step['parameter']} {step['sensor']} {step['sigmas']:+.2f} sigma "
                 f"({step['change']:+.3g} {step['unit']})" if step else "-")
        lines.append(f"{c['id']:>7} {c['created']:20} {c['kind']:8} {c['verdict'] or '-':8} "
                     f"{c['bench'] or '-':12} {words}")
        if parameter is not None:
            lines += parameter_lines(c, parameter)
    big = h["largest_drift"]
    if big and all(c["id"] != big["to"] for c in h["calibrations"]):
        big = None  # outside the --last calibrations shown
    if big:
        lines.append(f"largest drift: {big['parameter']} of {big['sensor']}, {big['sigmas']:+.2f} "
                     f"sigma ({big['change']:+.3g} {big['unit']}) from record {big['from']} to "
                     f"{big['to']}" + ("; beyond 3 sigma: the unit moved more than its "
                                      "calibrations' noise" if abs(big["sigmas"]) > 3 else ""))
    return "\n".join(lines)


def parameter_lines(c: dict, parameter: str) -> list:
    """One calibration's `parameter` of every sensor: value +- 1 sigma (unit), drift in sigmas."""
    drift = {d["sensor"]: d["sigmas"] for d in c["drift"] if d["parameter"] == parameter}
    return [f"{'':8}{key.split(' ', 1)[1]:>8} {value:+.6g} +- {sigma:.2g} {unit}"
            + (f"  drift {drift[key.split(' ', 1)[1]]:+.2f} sigma"
               if key.split(" ", 1)[1] in drift else "")
            for key, (value, sigma, unit) in c["parameters"].items()
            if key.split(" ")[0] == parameter]
