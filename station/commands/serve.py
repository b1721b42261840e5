"""`station serve`: the technician's station in a browser (docs/serve.md).

A local web application: pick the bench profile and type or scan the unit's serial, check the
devices, run a session of the profile's protocol kind (rotary, iron, static) with the pose to set
drawn, the step, the stillness, the live stream and table rate, the positions done and the time
left; Pause, Resume, Abort (the table stopped); the verdict at once with the calibration file, the
report and an export; the unit's history and the line's state from the record store.

The session runs the same code as `station record` (the protocols talk to the technician at the
browser instead of the terminal) and writes into --sessions (default ./sessions); its calibration
file is recorded in the record store as `station record --solve` does. One session per bench at a
time, whatever the number of browsers watching. The page and its assets come from the station
itself (nothing from the internet). It listens on the loopback only, unless --host names another
address: every request then needs the token (--token, or one made at start; the address printed
carries it). Ctrl-C or SIGTERM stops the server (exit code 130), a session running aborted first
(the table stopped).
"""

import ipaddress
import json
import sys
from pathlib import Path

EXPORT = "c-header"
"""The export written beside every calibration made from the page (any number of sensors)."""


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    from station.commands import db_arguments

    p.description = __doc__
    p.epilog = (
        "examples:\n  station serve --profile bench.toml\n"
        "  station twin --profile-out twin.toml &   # then:\n"
        "  station serve --profile twin.toml --profile bench_iron.toml --port 8750\n"
        "  station serve --profile bench.toml --host 0.0.0.0   # the address printed has a token\n"
        "  station serve --profile bench.toml --port 0 --json  # a free port, said as JSON"
    )
    p.add_argument("--profile", type=Path, action="append", required=True,
                   help="a bench profile (TOML) the page offers; give it once per bench profile")
    p.add_argument("--host", default="127.0.0.1",
                   help="the address to listen on (default 127.0.0.1, the loopback; any other "
                        "needs the token)")
    p.add_argument("--port", type=int, default=8750, help="the port (default 8750; 0: any free)")
    p.add_argument("--sessions", type=Path, default=Path("sessions"),
                   help="the folder of the session files (default ./sessions)")
    p.add_argument("--token", help="the token a browser must give when --host is not the "
                                   "loopback (default: one made at start)")
    db_arguments(p)
    p.add_argument("--json", action="store_true",
                   help="say where the page is as one JSON line on stdout (url, port, profiles, "
                        "sessions folder), for a script that starts the station")
    p.set_defaults(run=run)


def run(args) -> int:
    server, session = build_server(args)
    try:
        server.serve()
    finally:
        session.close()
    return 0


def build_server(args):
    """(`station.serve.app.Listening` server, BenchSession) of the command's arguments, checked;
    the server's socket is bound (OSError as an InputError naming the address)."""
    import secrets

    from station.commands import bench_profile
    from station.errors import InputError
    from station.serve.app import Listening, build
    from station.serve.session import BenchSession

    if not 0 <= args.port <= 65535:
        raise InputError(f"--port {args.port}: give 0-65535 (0: any free port)")
    profiles = {}
    for path in args.profile:
        path = bench_profile(path)
        name = path.name.removesuffix(".toml")
        if name in profiles:
            raise InputError(f"two bench profiles named {name!r}; give each its own file name")
        profiles[name] = path
    loopback = _loopback(args.host)
    if loopback and args.token:
        raise InputError("--token is for a station bound beyond the loopback (--host); leave it "
                         "out")
    token = None if loopback else args.token or secrets.token_urlsafe(16)
    if token is not None and len(token) < 12:
        raise InputError("--token: give at least 12 characters (or leave it out: one is made)")
    folder = args.sessions.resolve()
    session = BenchSession(profiles, folder, lambda path: conclude(path, args))
    lookups = {"devices": lambda name: _devices(session, name),
               "history": lambda serial: history(args.db, serial),
               "line": lambda: line(args.db),
               "sessions": lambda: sessions(folder, session.path if session.running() else None)}
    app = build(session, lookups, token)
    served = Listening(app, args.host, args.port)
    where = f"http://{args.host}:{served.port}/" + (f"?token={token}" if token else "")
    if getattr(args, "json", False):
        print(json.dumps({"url": where, "port": served.port, "profiles": list(profiles),
                          "sessions": str(folder)}), flush=True)
    else:
        print(f"station serve: the station's page is at {where} (Ctrl-C stops it)",
              file=sys.stderr, flush=True)
    return served, session


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _devices(session, name: str) -> dict:
    """The devices of the bench profile `name` (its own unit serial: none is typed yet)."""
    from station.acquire.bench import BenchProfile
    from station.serve.devices import devices

    return devices(BenchProfile.load(session.profile_path(name)))


def conclude(path: Path, args) -> dict:
    """A completed session's calibration file (as `station record --solve`), its report, the
    export, its record in the store; what the page shows (the verdict, the files by name)."""
    from station.commands import keep_records
    from station.commands.export import export
    from station.commands.record import solve
    from station.report import session as report

    summary = solve(path)
    calibration = Path(summary["calibration"])
    report.build(path).write(path.with_suffix(".html"))
    exported = export(calibration, EXPORT)
    keep_records(args, [calibration])
    files = [("calibration file", calibration.name), ("report", path.with_suffix(".html").name),
             (f"export ({EXPORT})", exported.name), ("session file", path.name)]
    return {"verdict": summary["verdict"], "chi2_per_dof": summary["chi2_per_dof"],
            "status": summary["status"], "files": files}


def sessions(folder: Path, busy: Path | None = None) -> list:
    """The session files of the folder, newest first: name, positions done and planned, and
    whether it can be resumed (interrupted before its last position); not `busy`, the one
    being recorded (never opened while the session's writer holds it)."""
    import re

    from station.errors import StationError
    from station.serve.session import SESSION_FILE
    from station.session import Session

    found = []
    for path in sorted(folder.glob("*.h5"), key=lambda p: p.stat().st_mtime, reverse=True)[:50]:
        if not re.fullmatch(SESSION_FILE, path.name) or path == busy:
            continue
        try:
            with Session.open(path) as s:
                last, meta = s.last_completed_position(), s.metadata
        except (StationError, OSError):
            continue
        planned = len(meta.get("fixture_poses") or meta.get("axes") or ()) or \
            (meta.get("settings") or {}).get("poses") or 0
        done = 0 if last is None else last + 1
        found.append({"name": path.name, "done": done, "planned": planned,
                      "resumable": bool(planned) and done < planned})
    return found


def history(db: str | None, serial: str) -> dict:
    """The unit's calibrations in the record store (`station history`)."""
    from station.commands import existing_store
    from station.errors import InputError
    from station.records.analysis import history as unit_history
    from station.session.units import SERIAL

    if not SERIAL.match(serial):
        raise InputError(f"unit serial {serial!r}: give 1-64 letters, digits, '.', '_' or '-'")
    with existing_store(db) as store:
        records = store.history(serial)
    if not records:
        raise InputError(f"no calibration of unit {serial!r} in the record store yet")
    return unit_history(records, serial)


def line(db: str | None) -> dict:
    """The line's state from the record store (`station fleet`): records, units, yield, per
    model, and the benches whose health charts flag a run rule."""
    from station.commands import existing_store
    from station.commands.fleet import flagged_benches
    from station.records.analysis import fleet
    from station.records.query import Selection

    with existing_store(db) as store:
        report = fleet(store, Selection({"kind": "session"}))
    return {"records": report["records"], "units": report["units"], "yield": report["yield"],
            "models": {m: r["yield"] for m, r in report["models"].items()},
            "benches flagged": flagged_benches(report) or "none"}
