"""`station history SERIAL`: every calibration of a unit in the record store, oldest first, with
the drift between consecutive calibrations in sigmas, per parameter, the largest named.

Drift of a parameter from one calibration to the next: (x2 - x1) / sqrt(s1^2 + s2^2), each 1-sigma
the calibration's own (docs/records.md). Beyond about 3 it is unlikely to be noise: the unit moved
(or its bench did: `station fleet` shows the benches' health).
"""

import json


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.description = __doc__
    p.epilog = ("examples:\n  station history SN1234\n"
                "  station history SN1234 --db postgresql://station@db.line/calibrations --json")
    p.add_argument("serial", help="the unit's serial number")
    p.add_argument("--db", metavar="URL",
                   help="the record store (default: $STATION_DB, else ./station.db)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.errors import InputError
    from station.records.analysis import history
    from station.records.store import open_store, store_url

    with open_store(store_url(args.db)[0], create=False) as store:
        records = store.history(args.serial)
        where = store.where
    if not records:
        raise InputError(f"no calibration of unit {args.serial!r} in the record store {where}; "
                         "check the serial, or the store (--db, `station db import DIR`)")
    h = history(records, args.serial)
    print(json.dumps(h, indent=2) if args.json else text(h))
    return 0


def text(h: dict) -> str:
    """The history in words: one line per calibration, its largest drift from the one before."""
    lines = [f"unit {h['unit_serial']}: {len(h['calibrations'])} calibrations",
             f"{'record':>7} {'created':20} {'kind':8} {'verdict':8} {'bench':12} largest drift "
             "from the one before"]
    for c in h["calibrations"]:
        step = c["drift"][0] if c["drift"] else None
        words = (f"{step['parameter']} {step['sensor']} {step['sigmas']:+.2f} sigma "
                 f"({step['change']:+.3g} {step['unit']})" if step else "-")
        lines.append(f"{c['id']:>7} {c['created']:20} {c['kind']:8} {c['verdict'] or '-':8} "
                     f"{c['bench'] or '-':12} {words}")
    big = h["largest_drift"]
    if big:
        lines.append(f"largest drift: {big['parameter']} of {big['sensor']}, {big['sigmas']:+.2f} "
                     f"sigma ({big['change']:+.3g} {big['unit']}) from record {big['from']} to "
                     f"{big['to']}" + ("; beyond 3 sigma: the unit moved more than its "
                                      "calibrations' noise" if abs(big["sigmas"]) > 3 else ""))
    return "\n".join(lines)
