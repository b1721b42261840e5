"""`station diagnose SESSION`: name the effects that separate a rotary or free-static session from
its twin."""

import json
from pathlib import Path

from station.diagnose import data, diagnose, report, static_report
from station.errors import CalibrationInputError


def register(subparsers) -> None:
    """Add the `diagnose` subcommand."""
    p = subparsers.add_parser(
        "diagnose",
        help="find where a rotary session and its twin disagree and name the effect",
        description="Fit the nominal model, compare the session with its digital twin, test "
        "every named effect by its likelihood ratio, add the strongest significant one and "
        "repeat (docs/diagnose.md).",
    )
    p.add_argument("session", metavar="SESSION",
                   help="rotary data file (.npz) or free-static session (.h5 of station import)")
    p.add_argument("--json", action="store_true", help="print the diagnosis as JSON")
    p.add_argument("--report", metavar="FILE.html", help="write an HTML report with the plot")
    p.add_argument("--alpha", type=float, default=0.01, help="family-wise significance level")
    p.add_argument("--max-effects", type=int, default=3, help="at most this many effects")
    p.set_defaults(run=run)


def run(args) -> int:
    """Diagnose, print, optionally write the report; bad input is reported, not raised."""
    path = Path(args.session)
    if static_report.is_static_session(path):
        return static_report.command(args)
    if path.suffix != ".npz" or not path.is_file():
        print(f"station diagnose: {path} is not a rotary .npz data file; record or simulate one "
              "(station simulate --protocol rotary --out x.npz)")
        return 2
    if not 0 < args.alpha < 1:
        print(f"station diagnose: --alpha {args.alpha} must lie between 0 and 1")
        return 2
    try:
        session = data.load(path)
        result = diagnose(session, alpha=args.alpha, max_effects=args.max_effects)
    except (CalibrationInputError, ValueError, OSError) as err:
        print(f"station diagnose: {err}")
        return 2
    doc = report.to_dict(result, session, str(path))
    print(json.dumps(doc, indent=1) if args.json else report.text(doc))
    if args.report:
        Path(args.report).write_text(report.html_report(doc))
    return 0
