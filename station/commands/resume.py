"""`station resume SESSION`: continue a session that a kill, a pause, an abort or a lost device
ended: rotary, iron or free-static.

The session file is reopened (rows cut by a kill are dropped), the positions after the last
completed one are recorded, and the file is closed cleanly. A rotary session goes on with the
position after its last completed one (the table is commanded to stop first of all, within a
second of the command's start: `station.acquire.bench.stop_table`); an iron or free-static session
keeps the poses already captured and asks the technician for the others (an iron session resumed
within a mounting goes on with its next face: leave the unit fixed in the iron as it was).
Rotary sessions recorded on the virtual bench (`bench` in their metadata) resume on a new virtual
bench built from it. Sessions recorded with real devices (`station record`) resume with the devices
of a bench profile: `--profile`, by default the one the session was recorded with (its path is in
the metadata); it must be for the same unit and stream (`station.acquire.bench.resume`).
A thermal campaign (its directory or `campaign.json`) goes on at its first setpoint not done, with
the bench profile it was recorded with (or `--profile`), the table stopped first: the unit is
soaked again there, then the session is recorded, or resumed when its file exists
(`station.protocols.thermal`, docs/protocols.md "Thermal sessions").
"""

import json
import sys
from pathlib import Path


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    from station.commands import no_check_argument, no_watchdog_argument

    p.description = __doc__
    p.epilog = (
        "examples:\n  station resume unit7.h5\n"
        "  station resume unit7.h5 --profile bench.toml   # a port moved\n"
        "  station resume demo.h5 --speed 80 --json\n"
        "  station resume campaigns/SN42   # a thermal campaign, at its next setpoint"
    )
    p.add_argument("session", type=Path, help="the session file (.h5), or a thermal campaign's "
                   "directory (it goes on at the first setpoint not done)")
    p.add_argument("--profile", type=Path,
                   help="bench profile of the real devices (default: the one recorded with)")
    p.add_argument("--speed", type=float,
                   help="virtual bench: clock speed, simulated s per wall s (default: as recorded)")
    no_check_argument(p)
    no_watchdog_argument(p)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(run=run)


def run(args) -> int:
    """Stop the table first (nothing else is imported before: `stop_table`), then check the
    file (`existing_session`, about 0.5 s in a child process) and resume."""
    from station.commands import existing_file, existing_session, table_words
    from station.session.campaign import is_campaign

    if is_campaign(args.session):
        return _resume_campaign(args)
    existing_file(args.session, "a session file (.h5)")
    profile = args.profile or _recorded_profile(args.session)
    if profile is not None:
        from station.acquire.bench import stop_table

        stop_table(profile)
    existing_session(args.session, check=not args.no_check)

    from drivers.errors import DeviceError
    from station.errors import AcquisitionError, OperatorAbort
    from station.session import Session

    try:
        if profile is None:
            from station.twin.rotary_bench import resume_rotary

            first = resume_rotary(args.session, **({} if args.speed is None
                                                    else {"speed": args.speed}))
        else:
            first = _resume_with_devices(args.session, profile, args.json)
    except (KeyboardInterrupt, OperatorAbort, AcquisitionError, DeviceError) as err:
        again = "" if args.profile is None else f" --profile {args.profile}"
        err.add_note(f"{table_words(err)}{args.session} keeps the completed positions; go on "
                     f"with `station resume {args.session}{again}`")
        raise
    with Session.open(args.session) as session:
        last = session.last_completed_position()
        n = _planned(session.metadata)
    summary = {"session": str(args.session), "resumed_at": first, "positions": n,
               "completed": 0 if last is None else last + 1}
    if args.json:
        print(json.dumps(summary))
    elif first >= n:
        print(f"{args.session}: all {n} positions were already recorded")
    else:
        print(f"{args.session}: recorded positions {first + 1}..{n} of {n}; the session is "
              "complete")
    return 0


def _planned(metadata: dict) -> int:
    """The positions (rotary) or poses (iron, static) of a session's protocol run."""
    if "axes" in metadata:
        return len(metadata["axes"])
    settings = metadata["settings"]
    return settings["poses"] if "poses" in settings else \
        settings["mountings"] * len(settings["faces"])


def _recorded_profile(path) -> Path | None:
    """The bench profile a `station record` session was recorded with; None for a virtual-bench
    session. Refuses (ProfileError) a recorded profile that is gone."""
    from drivers.profile import ProfileError
    from station.session import Session

    with Session.open(path) as session:
        bench = session.metadata.get("bench")
    if not (isinstance(bench, dict) and isinstance(bench.get("profile"), str)):
        return None
    profile = Path(bench["profile"])
    if not profile.is_file():
        raise ProfileError(f"{path} was recorded with the bench profile {profile}, which is gone; "
                           "give the bench's profile with --profile")
    return profile


def _resume_with_devices(path, profile: Path, quiet: bool) -> int:
    """Resume `path` with the devices of the bench profile, prompting on the console."""
    from station.acquire.bench import BenchProfile, resume
    from station.acquire.operator import ConsoleOperator

    bench = BenchProfile.load(profile)
    return resume(bench, path, ConsoleOperator(stdout=sys.stderr if quiet else sys.stdout))


def _resume_campaign(args) -> int:
    """Continue a thermal campaign (its directory or manifest) at its first soak not done, with
    the bench profile it was recorded with (or --profile); the table is stopped first."""
    from station.acquire.bench import BenchProfile, stop_table
    from station.acquire.operator import ConsoleOperator
    from station.acquire.watchdog import require_watchdogs
    from station.commands import existing_file
    from station.commands.record import report_campaign
    from station.errors import InputError
    from station.protocols.thermal import run_campaign
    from station.session.campaign import Campaign

    campaign = Campaign.load(args.session)
    profile = existing_file(args.profile or Path(campaign.profile), "the campaign's bench "
                            "profile (.toml; give it with --profile)")
    stop_table(profile)
    bench = BenchProfile.load(profile)
    if bench.chamber is None or bench.unit_serial != campaign.unit_serial:
        raise InputError(f"{profile} is not the thermal bench of unit {campaign.unit_serial!r} "
                         "(a [chamber] section and that unit_serial); give the campaign's bench "
                         "profile with --profile")
    require_watchdogs(bench, args.no_watchdog)
    operator = ConsoleOperator(stdout=sys.stderr if args.json else sys.stdout)
    return report_campaign(run_campaign(bench, campaign, operator), args.json)
