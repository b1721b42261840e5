"""`station noise`: each channel's noise from a session's static data, by the Allan deviation.

The static data are the protocol's static windows (rotary) or still poses (iron, free static),
or, in a session without protocol events (an imported recording, a long rest), the still
intervals found in the stream. Their overlapping Allan variances are pooled and fitted with the
IEEE Std 952-1997 terms: white-noise density N (angle / velocity random walk, u sqrt(s)), bias
instability B (u) and rate / acceleration random walk K (u/sqrt(s)), each with its 1-sigma; a term
the data cannot resolve (too short a rest) is reported as not resolved (null in --json).
docs/noise.md defines the terms, the fit and its band.
"""

import json
from pathlib import Path


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    from station.commands import no_check_argument

    p.description = __doc__
    p.epilog = (
        "examples:\n  station noise sessions/rotary-12gyro.h5\n"
        "  station noise rest.h5 --stream gyro --json\n"
        "  station noise rest.h5 --plot rest-allan.png\n\n"
        "exit code 0: done; 1: the session file could not be checked (--no-check); 2: bad "
        "input (no such stream, no or too little static data, a damaged file)"
    )
    p.add_argument("session", type=Path, help="session file (.h5)")
    p.add_argument("--stream", default="imu", metavar="NAME",
                   help="the stream to analyse (default: imu)")
    p.add_argument("--plot", type=Path, metavar="FILE.png",
                   help="write the Allan deviation plot (log-log, fitted slopes drawn)")
    no_check_argument(p)
    p.add_argument("--json", action="store_true", help="machine-readable figures")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.commands import existing_session
    from station.errors import InputError
    from station.files.session import Session
    from station.reduce.noise import session_noise
    from station.report import noise as words

    if args.plot is not None and args.plot.suffix.lower() != ".png":
        raise InputError(f"--plot {args.plot} must name a .png file")
    existing_session(args.session, check=not args.no_check)
    with Session.open(args.session) as session:
        found = session_noise(session, args.stream)
    if args.plot is not None:
        args.plot.write_bytes(words.allan_png(found))
    figures = words.summary(found)
    if args.json:
        print(json.dumps({**figures, "plot": None if args.plot is None else str(args.plot)},
                         indent=2))
        return 0
    print(f"{args.session}: stream {found.stream!r}, {figures['seconds']:.1f} s of static data "
          f"in {figures['windows']} window(s) ({found.source}), {figures['rate_hz']:g} Hz; "
          f"taus {found.curve.tau[0]:.3g} .. {found.curve.tau[-1]:.3g} s")
    head = words.HEAD
    table = [head, *words.rows(found)]
    width = [max(len(r[i]) for r in table) for i in range(len(head))]
    for r in table:
        print("  " + "  ".join(c.ljust(w) for c, w in zip(r, width, strict=True)))
    if not found.fit.resolved.all():
        print("  not resolved: the static data are too short (or the term too small) to tell it "
              "from zero at 2 sigma; record a longer rest")
    if args.plot is not None:
        print(f"plot written to {args.plot}")
    return 0
