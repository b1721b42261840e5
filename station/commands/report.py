"""`station report`: one self-contained HTML report of a session file, plus its figures as PNG.

The report (station/report/session.py) shows the summary, warnings in plain words, the residuals
against the noise level, the sensitive axes, the coverage of the orientations, the table rate
stability, the stream health and the uncertainty of each parameter. The figures are embedded in the
HTML and also written next to it as <stem>-<figure>.png. An existing report of the same name is
replaced.
"""

import json
from pathlib import Path


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.description = __doc__
    p.epilog = (
        "examples:\n  station report sessions/SN42.h5\n"
        "  station report sessions/SN42.h5 --out reports/SN42.html --json"
    )
    p.add_argument("session", type=Path, help="session file (.h5)")
    p.add_argument("--out", type=Path,
                   help="HTML file to write (default: the session's name with .html)")
    p.add_argument("--result", metavar="NAME",
                   help="stored calibration results/NAME to report (default: the newest)")
    p.add_argument("--json", action="store_true",
                   help="print the summary, warnings and files written as JSON")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.commands import existing_session
    from station.errors import InputError
    from station.report import session as report

    out = args.out or args.session.with_suffix(".html")
    if out.resolve() == args.session.resolve():
        raise InputError("--out would overwrite the session file; choose an .html name")
    existing_session(args.session)
    built = report.build(args.session, args.result)
    files = built.write(out)
    if args.json:
        print(json.dumps({**built.summary, "files": [str(f) for f in files]}, indent=2))
    else:
        print(f"report written to {files[0]} ({len(files) - 1} figures next to it)")
        for warning in built.warnings:
            print(f"  warning: {warning}")
    return 0
