"""One module per `station` subcommand; each exposes `register(p)` (its options on parser `p`) and
sets `run(args)`. Errors are raised, not printed: `station.cli` turns them into one line and an
exit code. The checks every command makes on the files it is given live here."""

import contextlib
from pathlib import Path

from station.errors import InputError, MissingFileError


def existing_file(path, what: str, suffixes=()) -> Path:
    """`path` as a Path if it names a regular file (with one of `suffixes`, when given)."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"{path} is not a file; give the path of {what}")
    if suffixes and path.suffix.lower() not in suffixes:
        raise InputError(f"{path} is not {what} (expected {' or '.join(suffixes)})")
    return path


def bench_profile(path) -> Path:
    """The bench profile `path` names: a file, or a bundled example by name (`bench_serial`:
    drivers/profiles/bench_serial.toml); MissingFileError listing the bundled ones otherwise."""
    from drivers.profile import BUNDLED

    path = Path(path)
    bundled = BUNDLED / f"{path.name.removesuffix('.toml')}.toml"
    if not path.is_file() and path.parent == Path(".") and path.name.startswith("bench_") \
            and bundled.is_file():
        return bundled
    names = ", ".join(sorted(p.stem for p in BUNDLED.glob("bench_*.toml")))
    return existing_file(path, f"a bench profile (.toml), or a bundled one: {names}")


def existing_session(path, positions=None, check: bool = True) -> Path:
    """`path` as a Path if it names a session file that reads back intact: every object and
    checksummed chunk, once, in a child process whose CPU time is bounded
    (`station.session.check`); with `positions` (0-based), damage in other positions'
    samples is let through; `check` False (--no-check): only that it is a file."""
    from station.session.check import checked

    path = existing_file(path, "a session file (.h5)")
    if check:
        checked(path, positions)
    return path


def no_check_argument(p) -> None:
    """`--no-check` on parser `p` (the commands that read a session file)."""
    p.add_argument("--no-check", action="store_true",
                   help="skip the structure check of the session file (every object and chunk "
                        "read in a child process first): for a file the check could not finish "
                        "on (exit 1, 'could not be checked'); without it, damaged sample chunks "
                        "are dropped as lost samples and damaged HDF5 metadata can hang the "
                        "command (docs/cli.md)")


def no_watchdog_argument(p) -> None:
    """`--no-watchdog` on parser `p` (record and resume of a thermal campaign:
    station.acquire.watchdog)."""
    p.add_argument("--no-watchdog", action="store_true",
                   help="a thermal campaign: record even though the table's or the chamber's "
                        "register map has no watchdog ([table.watchdog], [chamber.watchdog]): a "
                        "killed or hung station then leaves them running")


def new_file(path, option: str = "--out", force: bool | None = None) -> Path:
    """`path` as a Path if writing it loses nothing: absent, or `force` given. force None: the
    command has no --force, so the refusal does not offer it."""
    path = Path(path)
    if path.exists() and not force:
        raise InputError(f"{path} exists; choose another {option}"
                         + ("" if force is None else " or add --force"))
    return path


@contextlib.contextmanager
def working(what: str):
    """A spinner with `what` on stderr while a long step runs (on a terminal; nothing otherwise,
    so piped output and one-line errors stay as they are)."""
    from rich.console import Console

    with Console(stderr=True).status(what):
        yield


@contextlib.contextmanager
def progress(what: str, unit: str):
    """A progress bar with `what` on stderr while countable work runs (on a terminal; nothing
    otherwise, so JSON and pipes stay clean). Yields `advance(done, total)`, which the work calls
    with the `unit`s done so far and the total it knows of."""
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
    )

    console = Console(stderr=True)
    if not console.is_terminal:
        yield lambda done, total: None
        return
    columns = (TextColumn(what), BarColumn(), MofNCompleteColumn(), TextColumn(unit),
               TimeElapsedColumn())
    with Progress(*columns, console=console, transient=True) as bar:
        task = bar.add_task(what, total=None)
        yield lambda done, total: bar.update(task, completed=done, total=total)


@contextlib.contextmanager
def given_values():
    """A ValueError that a library function raises about values given on the command line (a
    settings dataclass, a simulated unit, a twin) becomes an InputError: one line, exit 2."""
    try:
        yield
    except InputError:
        raise
    except ValueError as err:
        raise InputError(str(err)) from err


def still_arguments(p) -> None:
    """The still-pose detector's options on parser `p` (solve, replay, diagnose;
    docs/stillness.md)."""
    p.add_argument("--rest", metavar="START:END",
                   help="still poses: a declared rest period, seconds from the first sample, for "
                        "the noise level (default: the median over the still stretches)")
    p.add_argument("--threshold", type=float,
                   help="still poses: enter threshold in multiples of the noise variance (default "
                        "4; leave = 2 x threshold)")
    p.add_argument("--still-channels", choices=("acc", "acc+gyro"),
                   help="still poses: the accelerometers decide (acc: the default for imported "
                        "recordings), or the gyros can veto too (acc+gyro: diagnose's default "
                        "with a gyro); recorded sessions: every channel of the stream, as the "
                        "live protocol")
    p.add_argument("--min-still", type=float, metavar="SECONDS",
                   help="still poses: shortest pose kept (default 1.5 s)")


def faces_argument(p) -> None:
    """`--faces` on parser `p` (solve, replay): an imported recording's still poses are the faces
    of a right-angle block."""
    p.add_argument("--faces", action="store_true", default=None,
                   help="still poses of an import: they are the faces of a right-angle block in "
                        "one mounting (repeats allowed), solved with the right-angle "
                        "constraints of Hwangbo & Kanade Eq. 15; needed when the poses are only "
                        "the six axis-aligned directions")


def channels_argument(p) -> None:
    """`--channels` on parser `p` (solve, replay): calibrate some of the stream's channels."""
    p.add_argument("--channels", type=channel_names, metavar="NAME,NAME,...",
                   help="calibrate only these of the stream's calibrated channels, in this order "
                        "(at least a triad), e.g. one IMU of an array imported as one stream: "
                        "--channels acc1_x,acc1_y,acc1_z")


def channel_names(text: str) -> tuple:
    """The channel names of a comma-separated `--channels` value."""
    import argparse

    names = tuple(name.strip() for name in text.split(","))
    if not all(names):
        raise argparse.ArgumentTypeError(f"{text!r}: give channel names separated by commas, "
                                         "e.g. --channels ax1,ay1,az1")
    return names


def still_values(args) -> dict:
    """{rest, threshold, still_channels, min_still} of the options `still_arguments` added, the
    rest period parsed from START:END seconds (None where not given)."""
    rest = None
    if args.rest is not None:
        start, sep, end = args.rest.partition(":")
        try:
            rest = (float(start), float(end)) if sep else None
        except ValueError:
            rest = None
        if rest is None:
            raise InputError(f"--rest {args.rest!r}: give START:END in seconds from the first "
                             "sample, e.g. --rest 0:50")
    return {"rest": rest, "threshold": args.threshold, "still_channels": args.still_channels,
            "min_still": args.min_still}


def table_words(err: BaseException) -> str:
    """"the table was stopped; " when a stop command got through after `err`, "" otherwise (no
    table, or the driver's note already tells the operator to stop it by hand)."""
    return "the table was stopped; " if getattr(err, "table_stopped", None) else ""


def db_arguments(p) -> None:
    """`--db URL` and `--no-db` on parser `p` (the commands that write calibration files: each is
    recorded in the calibration record store, docs/records.md)."""
    p.add_argument("--db", metavar="URL",
                   help="record the calibration in this store: sqlite:///PATH or "
                        "postgresql://user@host/dbname (default: $STATION_DB, else station.db "
                        "beside the calibration file); a failed write then exits 1 (the "
                        "calibration file is written whatever happens)")
    p.add_argument("--no-db", action="store_true",
                   help="do not record the calibration in the record store")


def keep_records(args, files, kind: str = "session", near=None) -> int:
    """Record the calibration files `files` (just written) in the store of --db, STATION_DB or
    the default (`station.records.store.store_url`: station.db in the directory `near`, default
    the first file's), unless --no-db.

    A record never undoes a calibration: the files stay written whatever happens here. Done, it
    says where on stderr; failed, one line on stderr says what and how to fix it, and the exit
    code is 1 when the command line named the store (--db: this record was asked for), else 0
    (STATION_DB or the default store: the line goes on calibrating while its store is down, and
    `station db import` records the files later). Returns that exit code."""
    import sys

    from station.errors import StationError
    from station.records.store import store_url

    files = [Path(f) for f in files]
    if getattr(args, "no_db", False) or not files:
        return 0
    url, explicit = store_url(getattr(args, "db", None), near or files[0].resolve().parent)
    try:
        ids, where = record_files(url, files, kind)
    except (StationError, OSError) as exc:
        words = " ".join(str(exc).split())
        print(f"station {args.command}: {', '.join(map(str, files))} written but not recorded "
              f"in the record store: {words} (--no-db skips recording; `station db import DIR` "
              "records the files later)", file=sys.stderr)
        return 1 if explicit else 0
    known = [str(i) for i in ids if i is not None]
    print(f"station {args.command}: recorded in {where}"
          + (f" (record {', '.join(known)})" if known else " (already there)"), file=sys.stderr)
    return 0


def record_files(url: str, files, kind: str) -> tuple:
    """([record id or None (already there), ...], the store's name): each calibration file of
    `files` recorded in the store at `url`."""
    from station.calfiles.calfile import load
    from station.records.record import Record
    from station.records.store import open_store

    with open_store(url) as store:
        return [store.add(Record.from_calibration(load(f), f, kind)) for f in files], store.where


def store_argument(p) -> None:
    """`--db URL` on parser `p` of a command that reads the record store (history, fleet)."""
    p.add_argument("--db", metavar="URL",
                   help="the record store (default: $STATION_DB, else ./station.db)")


def existing_store(db: str | None):
    """The record store that --db `db`, STATION_DB or ./station.db names, opened for reading
    (`station.records.store.open_store` with create=False: a missing store is refused)."""
    from station.records.store import open_store, store_url

    return open_store(store_url(db)[0], create=False)


def queried_files(db: str | None, query: str, kind: str) -> list:
    """The calibration files of the records of `kind` that `query` picks in the record store
    (--db, STATION_DB or ./station.db), oldest first (`station.records.query.recorded_files`:
    each must still be there with its recorded sha256)."""
    from station.records.query import Selection, recorded_files

    selection = Selection.parse(query)
    with existing_store(db) as store:
        return recorded_files(store, selection, kind, query)
