"""`station diagnose SESSION`: name the effects that separate a rotary or free-static session from
its twin.

Free-static sessions (imported recordings) are cut into still poses on the accelerometer, with the
gyro's veto when there is a gyro (the diagnosis models the gyro's still means too;
--still-channels acc lets the accelerometer alone decide); --rest, --threshold and --min-still set
the detector (docs/stillness.md)."""

import json
from pathlib import Path

from station.commands import (
    existing_file,
    existing_session,
    no_check_argument,
    progress,
    still_arguments,
    still_values,
)
from station.diagnose import data, diagnose, static_report
from station.diagnose.plausibility import Site
from station.diagnose.static import diagnose_static
from station.errors import InputError
from station.reduce.stillness import StillOptions
from station.report import diagnosis as report
from station.session import Session
from station.session.units import recorded_units


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.description = (
        "Fit the nominal model, compare the session with its digital twin, test "
        "every named effect by its likelihood ratio, add the strongest significant one and "
        "repeat (docs/diagnose.md)."
    )
    p.epilog = (
        "examples:\n  station diagnose sessions/rotary-12gyro.h5\n"
        "  station diagnose unit7.h5 --report unit7-diagnosis.html --json\n"
        "  station simulate --effect latency=delay=0.002 --out x.npz && station diagnose x.npz\n"
        "  station import csv hand.h5 hand.csv --stream acc=ax,ay,az --unit acc=g --fs 100 && "
        "station diagnose hand.h5"
    )
    p.add_argument("session", metavar="SESSION",
                   help="session (.h5: rotary, or free-static from station import) or rotary "
                   "data file (.npz)")
    no_check_argument(p)
    p.add_argument("--json", action="store_true", help="print the diagnosis as JSON")
    p.add_argument("--report", metavar="FILE.html", help="write an HTML report with the plot")
    p.add_argument("--alpha", type=float, default=0.01, help="family-wise significance level")
    p.add_argument("--max-effects", type=int, default=3, help="at most this many effects")
    p.add_argument("--latitude", type=float, metavar="DEG",
                   help="site latitude, degrees north: an Earth rate is named only when it "
                   "matches the Earth's there (without it: its magnitude only)")
    p.add_argument("--stream", metavar="NAME",
                   help="the unit to diagnose in a rotary session of several units on one table "
                   "(its stream: imu, imu2, ...); a one-unit session has only imu")
    p.add_argument("--noise", metavar="CAL.cal.json", type=Path, nargs="+",
                   help="the unit's calibration file(s) holding its noise figures (station noise "
                   "REST.h5 --store CAL.cal.json; a free-static session: one per stream, "
                   "accelerometer and gyro): their bias random walk and flicker enter the noise "
                   "model the gaps are judged against (docs/diagnose.md)")
    still_arguments(p)
    p.set_defaults(run=run)


def unit_stream(recorded, path, stream: str | None) -> str:
    """The stream to diagnose: `stream`, one of the session's units (station.session.units)
    or imu for a one-unit session; a session of several units needs it named."""
    streams = [u.stream for u in recorded_units(recorded.metadata, recorded.specs, path)]
    if stream is None and streams:
        raise InputError(f"{path} holds {len(streams)} units on one table (streams "
                         f"{', '.join(streams)}): diagnose one at a time, e.g. --stream "
                         f"{streams[0]}")
    if stream is not None and stream not in (streams or ["imu"]):
        raise InputError(f"{path} has no unit on stream {stream!r}; its units' streams: "
                         f"{', '.join(streams or ['imu'])}")
    return stream or "imu"


def with_noise(session, paths, streams):
    """The session with the coloured noise of the calibration files `paths` (their noise
    figures' bias random walk and bias instability) in its noise model: each file is one
    stream's, recognised by its units among `streams` [(units, sensors, first channel)]; a
    stream without a file, or a term a file does not resolve, has none. Refused when a file's
    units or sensors match no stream, two files name one stream, or no file resolves a term."""
    import dataclasses

    import numpy as np

    from station.calfiles.calfile import load
    from station.diagnose import coloured

    channels = sum(n for _, n, _ in streams)
    terms = {t: np.zeros(channels) for t in coloured.TERMS}
    seen = set()
    for path in paths:
        cal = load(existing_file(path, "a calibration file (.cal.json) with noise figures"))
        units = set(cal.units)
        slot = next((st for st in streams if units == {st[0]} and len(cal.units) == st[1]), None)
        if slot is None or slot[0] in seen:
            wanted = " and ".join(f"{n} sensor(s) in {u}" for u, n, _ in streams)
            raise InputError(f"{path} holds the noise of {len(cal.units)} sensor(s) in "
                             f"{', '.join(sorted(units))}{' again' if slot else ''}; the session "
                             f"has {wanted}: give one calibration file per stream of this unit")
        seen.add(slot[0])
        for term, values in terms.items():
            figure = None if cal.noise is None else getattr(cal.noise, term)
            if figure is not None:
                values[slot[2]: slot[2] + slot[1]] = np.asarray(figure, float)
    terms = {t: v for t, v in terms.items() if np.any(v > 0)}
    if not terms:
        raise InputError(f"{', '.join(map(str, paths))} hold(s) no bias random walk or bias "
                         "instability among the noise figures: record a longer rest of the unit "
                         "and store its figures (station noise REST.h5 --store CAL.cal.json), or "
                         "diagnose without --noise (white noise only)")
    return dataclasses.replace(session, **terms)


def run(args) -> int:
    """Diagnose, print, optionally write the report."""
    path = existing_file(args.session, "a session (.h5 recorded or imported by the station) or a "
                         "rotary .npz data file (station simulate --protocol rotary --out x.npz)",
                         (".npz", ".h5"))
    if not 0 < args.alpha < 1:
        raise InputError(f"--alpha {args.alpha} must lie between 0 and 1")
    still = StillOptions(*still_values(args).values())
    if args.latitude is not None and not -90 <= args.latitude <= 90:
        raise InputError(f"--latitude {args.latitude} must lie between -90 and 90 degrees")
    rotary = path.suffix == ".npz"
    if rotary:
        session = data.load(path)
    else:
        existing_session(path, check=not args.no_check)
        with Session.open(path) as recorded:
            rotary = data.is_rotary(recorded)  # the one dispatch point for other protocols
            session = data.from_session(recorded, unit_stream(recorded, path, args.stream)) \
                if rotary else None
    if not rotary and args.stream is not None:
        raise InputError(f"{path} is not a rotary recording of several units: --stream is for "
                         "those (station twin --units)")
    if rotary and args.noise:
        session = with_noise(session, args.noise, [("rad/s", session.shape[2], 0)])
    if rotary and still != StillOptions():
        raise InputError(f"{path} is a rotary recording: --rest, --threshold, --still-channels and "
                         "--min-still are for still-pose (free-static) sessions")
    noise_source = ", ".join(map(str, args.noise)) if args.noise else None
    with progress(f"diagnosing {path.name}: testing the named effects (at most "
                  f"{args.max_effects} kept)", "fits") as advance:
        if rotary:
            doc = report.to_dict(diagnose(session, alpha=args.alpha, max_effects=args.max_effects,
                                          site=Site(args.latitude), progress=advance),
                                 session, str(path), noise_source)
        else:
            static = static_report.load(path, still)
            if args.noise:
                static = with_noise(static, args.noise, [
                    ("m/s^2", static.m, 0), *([("rad/s", 3, static.m)] if static.gyro else [])])
            doc = report.static_to_dict(
                diagnose_static(static, alpha=args.alpha, max_effects=args.max_effects,
                                latitude_deg=args.latitude, progress=advance),
                static, str(path), noise_source)
    print(json.dumps(doc, indent=1) if args.json else report.text(doc))
    if args.report:
        page = report.html_report if rotary else report.static_html_report
        Path(args.report).write_text(page(doc))
    return 0
