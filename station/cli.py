"""The `station` command: a table of subcommands, imported only when used, and THE error handler.

Each subcommand lives in `station/commands/<module>.py` and exposes `register(p)`, which describes
its parser `p` (description, options, examples) and sets `run`. `COMMANDS` below is the one list
of them with their one-line summaries, so `station --help` imports no command (python-can's
`BACKENDS` idea). Exit codes (docs/cli.md):

    0    done
    1    failed (the station could not do what was asked; the message says why)
    2    bad input (a missing or wrong file, a bad option, data the calibration cannot use)
    3    a device failed (IMU link, rotary table, device profile errors are 2)
    130  interrupted (Ctrl-C, or SIGTERM: `kill`); the rotary table has been stopped
    141  stdout closed early (e.g. piped into `head`)

Every error the station raises on purpose (`station.errors.StationError`,
`drivers.errors.DeviceError`) is printed as one line on stderr; `--verbose` adds the traceback and
debug logging. Anything else is a bug and keeps its traceback.
"""

import argparse
import io
import logging
import os
import sys

from station.acquire import interrupts

# name -> (module under station/commands/, one-line summary for `station --help`)
COMMANDS = {
    "demo": ("demo", "calibrate a 12-gyro unit on the virtual bench through the real drivers"),
    "record": ("record", "record a session (rotary, iron or static) with the devices of a bench "
                         "profile"),
    "plan": ("plan", "plan a session's positions on the bench's fixture or two-axis table, "
                     "with their expected error"),
    "twin": ("twin", "run the virtual bench's devices (serial IMU, Modbus table) for `record`"),
    "resume": ("resume", "continue a rotary session after a kill, pause or abort"),
    "replay": ("replay", "re-reduce and re-solve a recorded rotary, iron or free-static session"),
    "solve": ("solve", "solve a recorded session into a calibration file"),
    "combine": ("combine", "combine the calibration files of several sessions of one unit, with "
                           "their repeatability"),
    "apply": ("apply", "apply a calibration file to readings (CSV or session) -> calibrated "
                       "vectors"),
    "export": ("export", "export calibrations for other tools: C header, Kalibr, ArduPilot, PX4, "
                          "ROS, imucal"),
    "noise": ("noise", "noise of a session's static data: Allan deviation, white noise, bias "
                       "instability, random walk"),
    "report": ("report", "write an HTML report (and PNG figures) of a session file"),
    "diagnose": ("diagnose", "find where a session and its twin disagree and name the effect"),
    "simulate": ("simulate", "simulate a session of the digital twin"),
    "import": ("import_", "convert a foreign recording (text, CSV, .npz) into a session file"),
    "devices": ("devices", "list serial ports and CAN interfaces"),
    "history": ("history", "every calibration of a unit in the record store, with its drift"),
    "fleet": ("fleet", "yield, parameter distributions, control charts and bench health from the "
                       "record store"),
    "db": ("db", "the calibration record store: import folders, check, info"),
    "serve": ("serve", "the technician's station in a browser: run sessions, see verdicts and "
                       "history"),
}

BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
"""Thread counts of the BLAS libraries numpy may use, read when numpy is first imported."""

EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141


class Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr, exit code 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


class _Version(argparse.Action):
    """`--version`: the installed distribution's version, looked up only when asked."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, **kwargs):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        from station.files.provenance import software_version

        print(f"station {software_version()}")
        parser.exit()


def chosen(argv) -> str | None:
    """The subcommand named in argv (the first word that is one), or None."""
    return next((a for a in argv if a in COMMANDS), None)


def build_parser(argv=()) -> Parser:
    """The parser; only the subcommand named in argv is imported and fully described."""
    import importlib

    parser = Parser(prog="station",
                    description="IMU calibration station: record, solve, replay, diagnose.",
                    epilog="exit codes: 0 done, 1 failed, 2 bad input, 3 device, "
                           "130 interrupted. `station COMMAND --help` for each command.")
    parser.add_argument("--version", action=_Version, help="print the version and exit")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="debug logging, and the traceback of an error")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    name = chosen(argv)
    for command, (module, summary) in COMMANDS.items():
        p = sub.add_parser(command, help=summary, add_help=command == name,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        if command == name:
            importlib.import_module(f"station.commands.{module}").register(p)
            parser.chosen = p
    return parser


def parse(argv) -> argparse.Namespace:
    """The arguments; words no parser knows are refused by the subcommand's parser, so the
    message names it (`station apply: unrecognized arguments: ...`), not only `station`."""
    parser = build_parser(argv)
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        getattr(parser, "chosen", parser).error(f"unrecognized arguments: {' '.join(unknown)}")
    return args


class _WholeWrites(io.RawIOBase):
    """Standard output whose writes are whole or raise. On a pipe whose reader has gone (`station
    apply x.cal.json s.h5 | head`) `os.write` may first return a short count; Python's buffered
    writer passes it on and the text layer drops the rest silently, so the command would end 0
    with its output cut. Here the next write raises BrokenPipeError: exit code 141."""

    def __init__(self, fd: int):
        super().__init__()
        self.fd = fd

    def writable(self) -> bool:
        return True

    def fileno(self) -> int:
        return self.fd

    def isatty(self) -> bool:
        return os.isatty(self.fd)

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        done = 0
        while done < len(view):
            done += os.write(self.fd, view[done:])
        return done


def whole_stdout() -> None:
    """Replace the process's standard output (when it is fd 1, not a test's capture) with one
    whose writes are whole (`_WholeWrites`), same encoding and line buffering."""
    out = sys.stdout
    if out is not sys.__stdout__ or out is None:
        return
    try:
        fd = out.fileno()
    except (OSError, ValueError):
        return
    out.flush()
    sys.stdout = io.TextIOWrapper(io.BufferedWriter(_WholeWrites(fd)), encoding=out.encoding,
                                  errors=out.errors, line_buffering=out.line_buffering)


def configure_logging(verbose: bool) -> None:
    """Module loggers go to stderr through rich: warnings, or everything with --verbose."""
    logging.basicConfig(level=logging.DEBUG if verbose else logging.WARNING, format="%(message)s",
                        handlers=[log_handler(verbose)], force=True)
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL if not verbose else logging.INFO)


def log_handler(verbose: bool) -> logging.Handler:
    """The station's log handler: rich on stderr, whose lock a Ctrl-C cannot leave taken.

    Python 3.11's `Handler.handle` takes the lock in `acquire()`, a Python call: a
    KeyboardInterrupt landing right after (the main thread logging a warning) left it taken, and
    the next thread to log (a failing heartbeat, which the station then joins) waited for ever
    (tests/test_cli_logging.py). Python 3.13 takes it with `with`, as here (a C lock's `with` has
    no Python frame in between)."""
    from rich.console import Console
    from rich.logging import RichHandler

    class Handler(RichHandler):
        def handle(self, record) -> bool:
            shown = self.filter(record)
            if shown:
                with self.lock:
                    self.emit(record)
            return shown

    return Handler(console=Console(stderr=True), show_path=verbose, markup=False)


def one_blas_thread() -> None:
    """One BLAS thread, unless the environment names a count (before numpy is imported: the
    commands import it). The station's matrices are small; on a busy host idle BLAS threads
    spin on the cores that the recorder's threads need (docs/cli.md, "Threads")."""
    for var in BLAS_THREADS:
        os.environ.setdefault(var, "1")


def main(argv=None) -> int:
    """Run one command; errors the station raises on purpose become one line and an exit code."""
    one_blas_thread()
    argv = sys.argv[1:] if argv is None else list(argv)
    whole_stdout()
    args = parse(argv)
    configure_logging(args.verbose)
    previous = interrupts.install()  # kill = ^C, and never lost
    try:
        return int(args.run(args) or 0)
    except KeyboardInterrupt as err:
        return _fail(args, err, EXIT_INTERRUPTED, "interrupted")
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no error at exit's flush
        return EXIT_BROKEN_PIPE
    except FileExistsError as err:  # a file to create appeared meanwhile (another command)
        return _fail(args, err, 2, f"{err.filename} {err.strerror}" if err.filename else "")
    except Exception as err:
        from drivers.errors import DeviceError
        from station.errors import StationError

        if not isinstance(err, StationError | DeviceError):
            raise
        return _fail(args, err, err.exit_code)
    finally:
        interrupts.restore(previous)


def _fail(args, err: BaseException, code: int, message: str = "") -> int:
    """Print `station COMMAND: message; notes` as one line on stderr (the traceback first under
    --verbose); the notes are what the command added on the way out (e.g. the table was
    stopped)."""
    if args.verbose:
        import traceback

        traceback.print_exc()
    words = " ".join((message or str(err)).split())  # one line, whatever the message holds
    print("; ".join([f"station {args.command}: {words}", *getattr(err, "__notes__", ())]),
          file=sys.stderr)
    return code

