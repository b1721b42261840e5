"""`station noise`: each channel's noise from a session's static data, by the Allan deviation.

The static data are the protocol's static windows (rotary) or still poses (iron, free static),
or, in a session without protocol events (an imported recording, a long rest), the still
intervals found in the stream. Their overlapping Allan variances are pooled and fitted with the
IEEE Std 952-1997 terms: white-noise density N (angle / velocity random walk, u sqrt(s)), bias
instability B (u) and rate / acceleration random walk K (u/sqrt(s)), each with its 1-sigma; a term
the data cannot resolve (too short a rest) is reported as not resolved (null in --json).
docs/noise.md defines the terms, the fit and its band.

`--store CAL.cal.json` puts the figures into a calibration file of the unit (its `noise`, per
sensor, replacing any there): what Kalibr's imu.yaml needs (`station export --to kalibr`), whose
random walks want a long rest (an hour or more) that a calibration session seldom holds. The
stream is then the one of the calibration's sensors (by name, else by unit), and a session of
another unit is refused.
"""

import dataclasses
import json
from pathlib import Path


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    from station.commands import no_check_argument

    p.description = __doc__
    p.epilog = (
        "examples:\n  station noise sessions/rotary-12gyro.h5\n"
        "  station noise rest.h5 --stream gyro --json\n"
        "  station noise rest.h5 --plot rest-allan.png\n"
        "  station noise rest.h5 --store SN42.cal.json   # the figures into the calibration\n\n"
        "exit code 0: done; 1: the session file could not be checked (--no-check); 2: bad "
        "input (no such stream, no or too little static data, a damaged file)"
    )
    p.add_argument("session", type=Path, help="session file (.h5)")
    p.add_argument("--stream", metavar="NAME",
                   help="the stream to analyse (default: the one `station solve` calibrates, "
                        "or with --store the calibration's; the error lists them when several "
                        "could be meant)")
    p.add_argument("--plot", type=Path, metavar="FILE.png",
                   help="write the Allan deviation plot (log-log, fitted slopes drawn)")
    p.add_argument("--store", type=Path, metavar="CAL.cal.json",
                   help="put the figures into this calibration file of the unit (its noise "
                        "figures replaced; for `station export --to kalibr`)")
    no_check_argument(p)
    p.add_argument("--json", action="store_true", help="machine-readable figures")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.calfiles.calfile import load
    from station.commands import existing_file, existing_session
    from station.errors import InputError
    from station.reduce.noise import session_noise
    from station.replay import calibration_channels, noise_stream
    from station.report import noise as words
    from station.session import Session

    if args.plot is not None and args.plot.suffix.lower() != ".png":
        raise InputError(f"--plot {args.plot} must name a .png file")
    cal = None if args.store is None else load(existing_file(args.store, "a calibration file "
                                                                         "(.cal.json)"))
    existing_session(args.session, check=not args.no_check)
    with Session.open(args.session) as session:
        stream = args.stream or noise_stream(session, cal)
        if stream not in session.specs:
            raise InputError(f"{args.session} has no stream {stream!r}; its streams are "
                             f"{', '.join(session.specs)} (--stream)")
        channels = None if cal is None else calibration_channels(session, stream, cal)
        if cal is not None:
            _same_unit(cal, session, stream, args)
        found = session_noise(session, stream, channels)
    if args.plot is not None:
        args.plot.write_bytes(words.allan_png(found))
    figures = words.summary(found)
    stored = None if cal is None else _store(cal, found, args.store, args.session)
    if args.json:
        print(json.dumps({**figures, "plot": None if args.plot is None else str(args.plot),
                          "stored": stored}, indent=2))
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
    print("  legend: N, the white noise's density (angle / velocity random walk); B, the bias "
          "instability (the Allan deviation's floor); K, the rate / acceleration random walk; "
          "+- its 1 sigma (docs/noise.md)")
    if args.plot is not None:
        print(f"plot written to {args.plot}")
    if stored is not None:
        print(_stored_words(stored))
    return 0


def _stored_words(stored: dict) -> str:
    """What `_store` wrote, in one line: the terms stored and those left out."""
    terms = {"bias_instability": "bias instability", "random_walk": "random walk"}
    held = ["white noise", *(words for term, words in terms.items() if stored[term])]
    missing = [words for term, words in terms.items() if not stored[term]]
    left = (f"; {' and '.join(missing)} not resolved for every sensor, so left out: record a "
            "longer rest") if missing else ""
    return f"noise figures stored in {stored['file']} ({', '.join(held)}{left})"


def _same_unit(cal, session, stream: str, args) -> None:
    """Refuse a session of another unit than the calibration's (both serials known)."""
    from station.errors import InputError
    from station.session.units import unit_serial

    serial = unit_serial(session.metadata, session.specs, stream, args.session) \
        or session.unit_serial
    if serial and cal.unit_serial and serial != cal.unit_serial:
        raise InputError(f"{args.session} records unit {serial!r} and {args.store} is the "
                         f"calibration of unit {cal.unit_serial!r}; give a rest recording of "
                         "the same unit (an import names its unit with `station import ... "
                         "--unit-serial SERIAL`)")


def _store(cal, found, path, session_path) -> dict:
    """Write `found`'s figures into the calibration file `path` (its `cal`), with where they came
    from in its session record; which terms it now holds."""
    from station.calfiles.calfile import NoiseFigures

    figures = NoiseFigures.from_fit(found.fit, found.curve.rate, found.curve.seconds)
    source = {"path": str(Path(session_path).resolve()), "stream": found.stream,
              "seconds": figures.seconds}
    cal = cal.with_noise(figures)
    cal = dataclasses.replace(cal, session={**(cal.session or {}), "noise_source": source})
    cal.save(path, overwrite=True)
    return {"file": str(path), "white": True,
            "bias_instability": figures.bias_instability is not None,
            "random_walk": figures.random_walk is not None}
