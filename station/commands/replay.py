"""`station replay SESSION`: reduce and solve a recorded session (rotary, right-angle iron or
free-static) or an imported recording (`station import`) again from its raw stream.

Settings may differ from the recording's (trimmed windows, a subset of positions or poses, another
solver method, another magnitude); the result is stored in the session under a new results name
(never overwriting one). The same settings give bit-identical numbers: a replay with the defaults
reproduces the results the recording stored (rotary: `station solve`-style solving; iron and
free-static: `results/live`). `--raw OUT` (rotary sessions only) instead sends the recorded IMU
stream again over the serial wire protocol (a pty twin) and records it into the new session file
OUT. Still-pose sessions (iron, free-static, imported) take the detector's settings (--rest,
--threshold, --still-channels, --min-still; docs/stillness.md) and list the poses found and every
candidate rejected, with the reason; --faces solves an import's poses as the faces of a right-angle
block (Eq. 15 constraints). A session of several units on one table (docs/protocols.md) replays
every unit's stream, each stored under its own name (NAME-<stream>, replay-<stream>-<k>), unless
--stream chooses one.
"""

import dataclasses
import json
from pathlib import Path


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    from station.commands import (
        channels_argument,
        faces_argument,
        no_check_argument,
        still_arguments,
    )

    p.description = __doc__
    p.epilog = (
        "examples:\n  station replay sessions/rotary-12gyro.h5      # print only\n"
        "  station replay unit.h5 --trim 0.5 --method ellipsoid --name trim   # and store\n"
        "  station replay unit.h5 --positions 1-6,9 --json\n"
        "  station replay unit.h5 --like trim --no-refine\n"
        "  station replay iron.h5 --positions 1-6 --trim 1\n"
        "  station replay hand.h5 --still-channels acc+gyro --threshold 6 --min-still 1\n"
        "  station replay unit.h5 --raw again.h5"
    )
    p.add_argument("session", type=Path, help="the session file (.h5)")
    p.add_argument("--store", action="store_true",
                   help="store the results in the session file, as results/replay-<k> (without "
                        "it, or --name, nothing is written: the recording stays as it was)")
    p.add_argument("--name", help="store the results under this name (implies --store)")
    p.add_argument("--like", metavar="NAME",
                   help="start from the settings stored with results/NAME (an earlier replay); "
                        "the options given here change them")
    p.add_argument("--trim", type=float,
                   help="seconds left out at both ends of every window (rotary: static and "
                        "rotating windows; iron, static: each pose's window; default 0)")
    p.add_argument("--positions",
                   help="1-based positions (poses) to use, e.g. 1-6,9 (default: all completed)")
    p.add_argument("--method",
                   help="closed-form method: auto (default), pca, ellipsoid, factorization")
    p.add_argument("--no-refine", action="store_true", help="skip the maximum-likelihood step")
    p.add_argument("--magnitude", type=float,
                   help="stimulus magnitude (default: the recorded table rate, or gravity "
                        "for iron and free-static sessions, standard gravity for an import)")
    p.add_argument("--stream", help="sample stream to calibrate (default imu; an import: its one "
                                    "stream in m/s^2)")
    still_arguments(p)
    faces_argument(p)
    channels_argument(p)
    p.add_argument("--raw", type=Path, metavar="OUT",
                   help="replay the raw stream through the serial twin into new session OUT "
                        "(rotary sessions only)")
    no_check_argument(p)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.commands import existing_session, new_file, progress
    from station.replay import replay_raw

    existing_session(args.session, None if args.raw else _positions(args.positions),
                     check=not args.no_check)
    if args.raw is None:
        return _replay_units(args)
    raw = new_file(args.raw, option="file for the raw replay")
    with progress(f"replaying {args.session} through the serial twin into {raw}",
                  "samples") as advance:
        replay_raw(args.session, raw, progress=advance)
    if args.json:
        print(json.dumps({"session": str(args.session), "raw_replay": str(args.raw)}))
    else:
        print(f"{args.session}: raw stream replayed through the serial twin into {args.raw}")
    return 0


def _replay_units(args) -> int:
    """Reduce and solve again the stream the settings name, or with several units on one table
    (`station.session.units`) and no --stream each unit's, stored (--store, --name) under
    a name per unit (NAME-<stream>); print each."""
    from station.commands.solve import session_units

    settings = _settings(args)
    units = [] if settings.stream is not None else session_units(args.session)
    if not units:
        summary = _replay(args, settings, args.name)
        print(json.dumps(summary) if args.json else _text(summary))
        return 0
    summaries = [{"stream": u.stream, "unit_serial": u.unit_serial,
                  **_replay(args, dataclasses.replace(settings, stream=u.stream),
                            args.name and f"{args.name}-{u.stream}", f"replay-{u.stream}")}
                 for u in units]
    print(json.dumps({"units": summaries}) if args.json else "\n".join(
        f"unit {s['unit_serial']} (stream {s['stream']}):\n{_text(s)}" for s in summaries))
    return 0


def _replay(args, settings, name: str | None, prefix: str = "replay") -> dict:
    """The summary of one stream's replay with `settings`, stored as results/`name` (None with
    --store: the first free `prefix`-k; without --store: not stored)."""
    from station.commands import working
    from station.commands.solve import poses
    from station.protocols import KINDS
    from station.replay import free_name, replay, replay_into, stimulus
    from station.session import Session
    from station.solve.quality import check_fit

    with working(f"reducing and solving {args.session}"):
        if args.store or name:
            name = name or free_name(args.session, prefix)
            reduced, result = replay_into(args.session, name, settings)
        else:
            reduced, result = replay(args.session, settings)
    summary = {"session": str(args.session), "results": name,
               "positions": int(reduced.M.shape[1]), "method": result.method,
               "frame": result.frame, "chi2_per_dof": result.chi2 / result.dof,
               "settings": dataclasses.asdict(settings),
               "scale_factors": result.scale_factors.tolist(),
               "scale_factors_sigma": result.scale_factors_sigma.tolist(),
               "magnitude": result.magnitude, **poses(reduced)}
    with Session.open(args.session) as session:
        summary["stimulus"] = stimulus(session, settings)[1]
        hand = KINDS[session.protocol].still
    check = check_fit(result, pose_term=hand)
    return {**summary, "status": check.status, "status_reasons": check.problems}


def _text(summary: dict) -> str:
    """A replay's summary in words."""
    from station.commands.solve import pose_lines

    where = "not stored (--store keeps it)" if summary["results"] is None else \
        f"stored as results/{summary['results']}"
    lines = [f"{summary['session']}: {summary['positions']} positions, {summary['method']} "
             f"({summary['frame']} frame), chi2/dof {summary['chi2_per_dof']:.2f}; {where}",
             *pose_lines(summary),
             "scale factors: " + " ".join(f"{k:.5f}" for k in summary["scale_factors"])]
    if summary["status"] == "suspect":
        lines.append(f"SUSPECT fit: {'; '.join(summary['status_reasons'])}")
    return "\n".join(lines)


def _settings(args):
    """ReplaySettings: the defaults, or those stored with results/<--like>, changed by the
    options given."""
    from station.replay import ReplaySettings, stored_settings

    base = stored_settings(args.session, args.like) if args.like else ReplaySettings()
    from station.commands import still_values

    given = {"trim": args.trim, "positions": _positions(args.positions), "method": args.method,
             "magnitude": args.magnitude, "stream": args.stream, "faces": args.faces,
             "channels": args.channels,
             **still_values(args)}
    changes = {k: v for k, v in given.items() if v is not None}
    if args.no_refine:
        changes["refine"] = False
    return dataclasses.replace(base, **changes)


def _positions(text):
    """0-based positions from a 1-based list like "1-6,9"; None for None."""
    from station.errors import InputError

    if text is None:
        return None
    positions = []
    try:
        for part in text.split(","):
            first, _, last = part.partition("-")
            positions += range(int(first) - 1, int(last or first))
    except ValueError:
        raise InputError(f"--positions {text!r}: give 1-based numbers and ranges, e.g. 1-6,9") \
            from None
    return tuple(positions)
