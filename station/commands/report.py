"""`station report`: one self-contained HTML report of a session file, plus its figures as PNG.

The report (station/report/session.py) shows the summary, warnings in plain words, the residuals against
the noise level, the sensitive axes, the coverage of the orientations, the table rate stability,
the stream health and the uncertainty of each parameter. The figures are embedded in the HTML and
also written next to it as <stem>-<figure>.png. An existing report of the same name is replaced.
"""

import json
import sys
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser(
        "report", help="write an HTML report (and PNG figures) of a session file",
        description=__doc__,
        epilog="examples:\n  station report sessions/SN42.h5\n"
               "  station report sessions/SN42.h5 --out reports/SN42.html --json")
    p.add_argument("session", type=Path, help="session file (.h5)")
    p.add_argument("--out", type=Path,
                   help="HTML file to write (default: the session's name with .html)")
    p.add_argument("--result", metavar="NAME",
                   help="stored calibration results/NAME to report (default: the newest)")
    p.add_argument("--json", action="store_true",
                   help="print the summary, warnings and files written as JSON")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.report import session as report
    from station.files.session import SessionFormatError

    if not args.session.is_file():
        print(f"station report: {args.session} is not a file; give the path of a session (.h5)",
              file=sys.stderr)
        return 1
    out = args.out or args.session.with_suffix(".html")
    if out.resolve() == args.session.resolve():
        print("station report: --out would overwrite the session file; choose an .html name",
              file=sys.stderr)
        return 1
    try:
        built = report.build(args.session, args.result)
        files = built.write(out)
    except (SessionFormatError, ValueError, OSError) as exc:
        print(f"station report: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps({**built.summary, "files": [str(f) for f in files]}, indent=2))
    else:
        print(f"report written to {files[0]} ({len(files) - 1} figures next to it)")
        for warning in built.warnings:
            print(f"  warning: {warning}")
    return 0
