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
def given_values():
    """A ValueError that a library function raises about values given on the command line (a
    settings dataclass, a simulated unit, a twin) becomes an InputError: one line, exit 2."""
    try:
        yield
    except InputError:
        raise
    except ValueError as err:
        raise InputError(str(err)) from err


def table_words(err: BaseException) -> str:
    """"the table was stopped; " when a stop command got through after `err`, "" otherwise (no
    table, or the driver's note already tells the operator to stop it by hand)."""
    return "the table was stopped; " if getattr(err, "table_stopped", None) else ""
