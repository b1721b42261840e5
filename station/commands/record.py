"""`station record`: a live session with the devices of a bench profile.

The bench profile (TOML) says where the devices are and how to run the protocol:

    [bench]
    unit_serial = "SN42"          # serial number of the unit under calibration
    clock_speed = 1.0             # optional; > 1 only against `station twin --speed`
    # lockstep = "/tmp/lockstep-.../clock.sock"   # written by `station twin`: its stepped clock

    [imu]                         # several units on one rotary table: an [[imu]] table per
    link = "serial"               # or "can"; unit, with these keys, its own unit_serial and
                                  # optionally its mounting (3 rows: plate frame -> unit frame;
                                  # docs/protocols.md "Several units on one table")
    profile = "imu12_serial"      # device profile: path (relative to this file) or bundled name
    port = "/dev/ttyUSB0"         # serial: device path or pyserial URL
    # interface = "socketcan"     # can: python-can interface, channel and optional bitrate
    # channel = "can0"
    # rate_hz = 200.0             # optional: overrides the device profile's sample rate

    [table]                       # rotary only
    host = "192.168.0.50"         # Modbus TCP rotary table
    port = 502
    profile = "table_modbus"      # register map: path or bundled name ("table_two_axis": the
                                  # station sets every position itself, no operator input)
    # reply_timeout = 0.5         # optional: wall s to wait for each reply (default 0.5; 30 on
                                  # a lockstep clock); a silent table is lost after 3 tries

    [protocol]
    kind = "rotary"               # "rotary" (default), "iron" or "static"
    positions = 20                # rotary; any other key: a field of the protocol's settings
    # spins = 1                   # two-axis table: spins of the position axis after the positions
    # redo_limit = 2              # a flagged window is recorded again at once, at most this often
                                  # per position; then the session stops (docs/protocols.md)

    [fixture]                     # rotary, optional: a lettered cube (and wedge) to mount the
    layout = [[...], [...], [...]]  # unit in; the positions are then planned fixture poses
    noise_density = 1.7e-4        # (`station plan`; docs/protocols.md, "Fixture and plan")
    wedge = true

    [plan]                        # two-axis table, optional: the position axis' angles and the
    layout = [[...], [...], [...]]  # spins are then planned (`station plan`; docs/protocols.md
    noise_density = 1.7e-4        # "Two-axis sessions"); `spins` is the plan's

    [chamber]                     # rotary, optional: a thermal campaign (docs/protocols.md,
    host = "192.168.0.60"         # "Thermal sessions"): the chamber's Modbus TCP address (or
    setpoints = [263.15, 313.15]  # serial_port), setpoints in K, ramp, stability, window,
    safe = 296.15                 # soak_timeout, safe, poll; --out is then a directory
                                  # (the table's and chamber's register maps need a watchdog,
                                  # docs/devices.md "Watchdog", or --no-watchdog)

    [tolerances]                  # optional: the unit type's tolerances, for a PASS/FAIL verdict
    scale_factor = 0.03           # |k_i - 1| (station.solve.verdict)
    bias = 0.05                   # |b_i|, in the readings' SI unit
    axis_angle_deg = 2.0          # |angle_ij - nominal angle_ij|, where the layout is known

The three protocols (docs/protocols.md):
- rotary (`station.protocols.rotary`): gyros on a rotary table, Eq. (18) of Rupniewski; the
  technician re-mounts the unit and presses Enter; Ctrl-D or Ctrl-C aborts and stops the table;
  on a two-axis table nobody does anything: the station sets the position axis at `positions`
  angles spread over a turn, then spins it `spins` times, or at the angles and spins its [plan]
  plans (docs/protocols.md "Two-axis sessions");
- iron (`station.protocols.iron`): accelerometers in a right-angle iron, standing on its faces
  (keys: mountings, faces, hold, gravity, ...), Hwangbo & Kanade's constraints;
- static (`station.protocols.static`): accelerometers turned by hand into free still poses (keys:
  poses, separation_deg, hold, gravity, ...); gyro channels of the stream help find the poses.
  The iron and static protocols need no [table]; the stations finds each still pose itself;
  `layout = [[...], [...], [...]]` gives the accelerometers' nominal axes (3 rows, a column per
  accelerometer channel; default the identity for a triad), used to tell where "up" is.

The protocol runs through the recorder into a crash-safe session file; `--solve` then writes its
calibration file as `station solve` does (several units: one per unit,
<session>.<unit serial>.cal.json). Examples of bench profiles: drivers/profiles/bench_*.toml;
`station twin` writes one for its virtual devices.
"""

import json
import sys
import time
from pathlib import Path

from station.errors import InputError


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    from station.commands import db_arguments, no_watchdog_argument

    p.description = __doc__
    p.epilog = (
        "examples:\n  station record --profile bench.toml --out sessions/SN42.h5\n"
        "  station twin --speed 40 --profile-out twin.toml &   # then:\n"
        "  station record --profile twin.toml --out twin.h5 --solve --json\n"
        "  station record --profile thermal.toml --out campaigns/SN42 --solve   # [chamber]"
    )
    p.add_argument("--profile", type=Path, required=True, help="bench profile (TOML)")
    p.add_argument("--out", type=Path, help="session file to create (default: "
                   "sessions/<unit serial>-<date>.h5); a thermal campaign: its directory")
    p.add_argument("--solve", action="store_true",
                   help="solve the session afterwards into <session>.cal.json")
    p.add_argument("--accept-suspect", action="store_true",
                   help="with --solve: write a fit that fails the quality gate, marked suspect")
    p.add_argument("--live", action="store_true",
                   help="show the live view (phase, windows, table, link) while recording")
    no_watchdog_argument(p)
    db_arguments(p)
    p.add_argument("--json", action="store_true", help="machine-readable summary")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.acquire.bench import BenchProfile, record
    from station.acquire.operator import ConsoleOperator
    from station.commands import bench_profile, keep_records, new_file
    from station.commands.solve import unit_line, units_exit, verdict_exit
    from station.protocols import KINDS
    from station.solve.verdict import words

    bench = BenchProfile.load(bench_profile(args.profile))
    if bench.chamber is not None:
        return _campaign(args, bench)
    kind = KINDS[bench.protocol]
    if args.live and not kind.live_view:
        shown = ", ".join(name for name, k in KINDS.items() if k.live_view)
        raise InputError(f"the live view shows {shown} sessions; record a {bench.protocol} "
                         "session without --live")
    out = args.out or Path("sessions") / f"{bench.unit_serial}-{time.strftime('%Y%m%d-%H%M%S')}.h5"
    new_file(out)
    if args.solve and not bench.plate:  # refused now, not after the session was recorded
        new_file(out.with_suffix(".cal.json"),
                 "--out (--solve writes the session's calibration file beside it)")
    out.parent.mkdir(parents=True, exist_ok=True)
    operator = ConsoleOperator(stdout=sys.stderr if args.json else sys.stdout)
    try:
        summary = record(bench, out, operator, live=args.live)
        if args.solve and bench.plate:
            summary["calibrations"] = solve_plate(out, args.accept_suspect)
        elif args.solve:
            summary["calibration"] = solve(out, args.accept_suspect)
    except BaseException as err:
        err.add_note(how_to_go_on(err, out))
        raise
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        units = f" of {len(summary['units'])} units" if bench.plate else ""
        print(f"recorded {summary['positions_done']} of {summary['positions_planned']} positions "
              f"({summary['samples']} samples{units}) into {out} in "
              f"{summary['wall_seconds']:.1f} s")
        if args.solve and bench.plate:
            print("\n".join(unit_line(s) for s in summary["calibrations"]))
        elif args.solve:
            print(f"calibration: {summary['calibration']['calibration']} (chi2/dof "
                  f"{summary['calibration']['chi2_per_dof']:.2f}: the residuals against the "
                  "readings' noise, near 1 when the model explains the data)")
            if summary["calibration"]["verdict"]:
                print(words(summary["calibration"]["verdict"]))
    if args.solve and bench.plate:
        return max(units_exit(summary["calibrations"]),
                   keep_records(args, [s["calibration"] for s in summary["calibrations"]]))
    if args.solve:
        return max(verdict_exit(summary["calibration"]["verdict"]),
                   keep_records(args, [summary["calibration"]["calibration"]]))
    return 0


def how_to_go_on(err: BaseException, out: Path) -> str:
    """The note on an error (or Ctrl-C) that ended `station record`: whether the table was
    stopped, then what the session file `out` holds and how to go on with it - or that none was
    written (a device that failed before the first sample)."""
    from station.commands import table_words

    if not out.exists():
        return f"{table_words(err)}no session file was written ({out} does not exist)"
    return (f"{table_words(err)}{out} keeps the completed positions; go on with `station resume "
            f"{out}`")


def solve_plate(path, accept_suspect: bool = False) -> list:
    """Solve every unit of a session recorded with several units as `station solve` does, into
    <session>.<unit serial>.cal.json each; their summaries."""
    from station.commands.solve import session_units, solve_units, unit_files

    units = session_units(path)
    return solve_units(path, units, unit_files(path, units), accept_suspect=accept_suspect)


def solve(path, accept_suspect: bool = False) -> dict:
    """Solve the recorded session as `station solve` does; its summary."""
    from station.commands.solve import solve_session, summarise

    out = Path(path).with_suffix(".cal.json")
    cal = solve_session(path, accept_suspect=accept_suspect)
    cal.save(out)
    return summarise(cal, out)


def _campaign(args, bench) -> int:
    """A thermal campaign (the profile has a [chamber] section) into the directory --out."""
    from station.acquire.operator import ConsoleOperator
    from station.acquire.watchdog import require_watchdogs
    from station.commands import keep_records
    from station.protocols.thermal import run_campaign
    from station.session.campaign import Campaign

    require_watchdogs(bench, args.no_watchdog)
    if args.live:
        raise InputError("--live shows one rotary session; record a thermal campaign without it")
    out = args.out or Path("sessions") / f"{bench.unit_serial}-{time.strftime('%Y%m%d-%H%M%S')}"
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} is a file; a thermal campaign is written into a directory "
                         "(--out DIR)")
    campaign = Campaign.create(out, bench.unit_serial, bench.source, bench.chamber.setpoints)
    operator = ConsoleOperator(stdout=sys.stderr if args.json else sys.stdout)
    code = report_campaign(run_campaign(bench, campaign, operator), args.json, args.solve,
                           args.accept_suspect)
    return max(code, keep_records(args, [out / "campaign.cal.json"], "campaign")
               if args.solve else 0)


def report_campaign(summary: dict, as_json: bool, solve: bool = False,
                    accept_suspect: bool = False) -> int:
    """Print a finished campaign's summary (as JSON or words); with `solve`, write its
    calibration file first (campaign.cal.json in its directory)."""
    from station.commands.solve import campaign_text, solve_campaign, summarise_campaign

    if solve:
        out = Path(summary["campaign"]) / "campaign.cal.json"
        cal, fit = solve_campaign(summary["campaign"], accept_suspect)
        cal.save(out)
        summary["calibration"] = summarise_campaign(cal, fit, out)
    if as_json:
        print(json.dumps(summary, indent=2))
        return 0
    temps = ", ".join(f"{s['unit_temperature']:.2f}" for s in summary["soaks"])
    print(f"thermal campaign {summary['campaign']}: {len(summary['soaks'])} soaks done (the "
          f"unit at {temps} K); the chamber is at its safe setpoint "
          f"{summary['safe_setpoint']:.2f} K")
    if solve:
        print(campaign_text(summary["calibration"]))
    return 0
