"""`station report`: one self-contained HTML report of a session file, plus its figures as PNG.

The report (station/report/session.py) shows the summary, warnings in plain words, the residuals
against the noise level, the sensitive axes, the coverage of the orientations, the table rate
stability, the stream health and the uncertainty of each parameter. The figures are embedded in the
HTML and also written next to it as <stem>-<figure>.png. An existing report of the same name is
replaced.

A session of several units on one table gets one report per unit, BASE.<unit serial>.html (BASE:
the session's or --out's name without its suffix), each with its unit's calibration, stream health
and noise; --stream reports one unit.
"""

import json
from pathlib import Path


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    from station.commands import no_check_argument

    p.description = __doc__
    p.epilog = (
        "examples:\n  station report sessions/SN42.h5\n"
        "  station report sessions/SN42.h5 --out reports/SN42.html --json\n"
        "  station report sessions/plate.h5 --stream imu2"
    )
    p.add_argument("session", type=Path, help="session file (.h5)")
    p.add_argument("--out", type=Path,
                   help="HTML file to write (default: the session's name with .html)")
    p.add_argument("--result", metavar="NAME",
                   help="stored calibration results/NAME to report (default: the newest)")
    p.add_argument("--stream", metavar="NAME",
                   help="one unit's stream of a session of several units on one table (imu, "
                        "imu2, ...); default: a report per unit")
    p.add_argument("--json", action="store_true",
                   help="print the summary, warnings and files written as JSON")
    no_check_argument(p)
    p.set_defaults(run=run)


def run(args) -> int:
    from station.commands import existing_session
    from station.commands.solve import session_units
    from station.errors import InputError

    out = args.out or args.session.with_suffix(".html")
    if out.resolve() == args.session.resolve():
        raise InputError("--out would overwrite the session file; choose an .html name")
    existing_session(args.session, check=not args.no_check)
    if args.stream is not None and args.stream not in (streams := _streams(args.session)):
        raise InputError(f"{args.session} has no stream {args.stream!r}; its streams are "
                         f"{', '.join(streams)} (omit --stream for them all)")
    units = [] if args.stream is not None else session_units(args.session)
    if not units:
        return _print([_report(args.session, args.result, args.stream, out)], args.json)
    base = out.name.removesuffix(".html")
    return _print([_report(args.session, args.result, u.stream,
                           out.with_name(f"{base}.{u.unit_serial}.html")) for u in units],
                  args.json, several=True)


def _streams(path) -> list:
    """The sample streams of the session file `path`."""
    from station.session import Session

    with Session.open(path) as session:
        return list(session.specs)


def _report(path, result, stream, out) -> dict:
    """Build and write one report; its summary with the files written."""
    from station.report import session as report

    built = report.build(path, result, stream)
    files = built.write(out)
    return {**built.summary, "files": [str(f) for f in files]}


def _print(reports: list, as_json: bool, several: bool = False) -> int:
    """The reports written, as JSON ({"units": [...]} for several units) or a line each."""
    if as_json:
        print(json.dumps({"units": reports} if several else reports[0], indent=2))
        return 0
    for r in reports:
        unit = f"unit {r['unit_serial']}: " if several else ""
        print(f"{unit}report written to {r['files'][0]} ({len(r['files']) - 1} figures next "
              "to it)")
        for warning in r["warnings"]:
            print(f"  warning: {warning}")
    return 0
