"""A damaged session file found before a command trusts it: `checked(path)`.

HDF5 parses a file's metadata in C while holding Python's GIL, so no Python timeout can stop it: a
damaged object header can make the library loop. So `checked` reads the whole file in a child
process: forked from this one when it runs one thread (`station.session.forked`; it inherits
numpy and h5py, whose imports a new interpreter would spend as much CPU time on as a small solve),
else a new interpreter (`python -m station.session.check FILE`, which imports h5py, numpy and
the session modules, never the solver). The child reads every group, attribute and dataset,
each dataset chunk by chunk (HDF5 verifies the writer's fletcher32 checksum of every chunk as it
reads it), and each dataset's claimed size against the storage the file really holds for it (a
damaged header that claims 5e7 rows in a 1 MB file must not make a reader allocate gigabytes). A
file with damaged chunks or objects, or one that crashes the HDF5 library (SIGSEGV, SIGBUS,
SIGABRT, ...), is refused with one `SessionFormatError` naming what is damaged and, for sample
rows, the positions they belong to. A killed writer's file (flagged open for write, no lock held)
is read as a closed file (`_opened`): HDF5's reader for a live writer's file retries every failed
read for hours.

The child's WORK is bounded, not the wall clock: a busy host slows a child down without making
the file any less intact (issue 29: 61 of 249 commands at a load of 17-37 called intact files
damaged under the former wall-clock limit, which counted the child's start-up). The child gets
`cpu_seconds(size)` of CPU time (RLIMIT_CPU: SIGXCPU past it), and a wall-clock backstop of
`WALL_FACTOR` times that only for a child that neither finishes nor spends its CPU (storage that
does not answer). A check that could not finish (out of CPU time, stopped by a signal from
outside, the backstop) is a `SessionUncheckedError` (exit code 1): no verdict, never "damaged";
`--no-check` skips the check.

A command reads each file once: the survey of a file is kept for the process by its path, device,
inode, size and modification time (`_SURVEYS`), so a second look at an unchanged file launches no
child. A batch (`station solve A.h5 B.h5 ...`) surveys all its files in one child (`survey_all`),
each within its own CPU time; a file that child could not finish is checked alone.

Files written before the checksums (no fletcher32 filter) are still read; damage inside their
raw numbers cannot be seen here, only by the quality gate of the fit (`station.solve.quality`).
"""

import json
import os
import signal
import subprocess
import sys

import numpy as np

from station.errors import SessionFormatError, SessionUncheckedError
from station.session.forked import Forked, forkable
from station.session.torn import tail_rows

CPU_BASE = 10.0
"""Seconds of CPU time any file's check may use, plus `CPU_PER_BYTE` of its size. Measured
(2-core host, user + system): about 0.55 s for a 1.2 MB session and for a 37 MB one of 500
positions alike, most of it Python's start and the imports of numpy and h5py; the survey itself
reads about 300 MB/s (0.12 s for the 37 MB)."""
CPU_PER_BYTE = 1 / 10e6
WALL_FACTOR = 30
"""The wall-clock backstop, in multiples of the CPU limit: at a load of 30 on 2 cores a child
still gets 1/15 of a core, so only a hung child meets it."""
CHILD = ("-m", "station.session.check")
"""The interpreter's arguments that run the survey in the child, FILE after them."""
CRASHES = frozenset({signal.SIGSEGV, signal.SIGBUS, signal.SIGABRT, signal.SIGFPE, signal.SIGILL})
"""Signals that end a child inside the HDF5 library on the data it read: evidence of damage. Any
other signal (SIGXCPU of the CPU limit, SIGKILL, SIGTERM, SIGINT) stopped it from outside."""
AGAIN = "Run the command again, or add --no-check to skip the check (docs/cli.md)"
"""What to do after a check stopped from outside or by the backstop."""
SHOWN = 3
"""Damaged places a message names."""
MAX_EXPANSION = 64
"""A compressed dataset may claim at most this many times the bytes it stores."""

_SURVEYS = {}
"""(real path, device, inode, size, mtime_ns) -> the survey of a check that finished."""


def checked(path, positions=None, cpu_limit: int | None = None) -> None:
    """Refuse `path` (SessionFormatError) unless every object and chunk of it reads back intact;
    SessionUncheckedError when the check could not finish within `cpu_limit` seconds of CPU time
    (default `cpu_seconds` of its size) or the wall-clock backstop. With `positions` (0-based),
    damaged sample rows are allowed when they belong to other positions only (the reader drops
    them: `Session.stream`). Each version of a file is read once per process."""
    from station.session._repair import open_flags

    path = os.fspath(path)
    open_flags(path)  # not HDF5 at all, or a damaged superblock: said at once
    found = _survey_once(path, cpu_limit)
    if found["problems"] or found["damaged"] and not _spared(found, positions):
        raise SessionFormatError(describe(path, found))


def cpu_seconds(size: int) -> int:
    """The CPU time (whole seconds, as RLIMIT_CPU counts) a check of a file of `size` bytes may
    use: `CPU_BASE` + size x `CPU_PER_BYTE`, rounded up."""
    return int(np.ceil(CPU_BASE + size * CPU_PER_BYTE))


def _survey_once(path: str, cpu_limit: int | None) -> dict:
    """The survey of `path` (`survey`) from a child, or the one this process already has of the
    same file unchanged."""
    key = _key(path)
    found = _SURVEYS.get(key)
    if found is None:
        found = _SURVEYS[key] = _survey_in_child(path, cpu_limit or cpu_seconds(key[3]))
    return found


def _key(path: str) -> tuple:
    """(real path, device, inode, size, mtime_ns): one version of one file."""
    st = os.stat(path)
    return os.path.realpath(path), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def survey_all(paths) -> None:
    """Survey many files in one child process (a batch, e.g. `station solve A.h5 B.h5 ...`)
    instead of a child each, and keep the surveys for `checked`, whose verdict on each file is
    then the same as for one file. The child gives each file its own `cpu_seconds` of CPU time
    (the soft limit moved on before each, `_each`) and prints each survey as it finishes. A file
    it did not finish (the HDF5 library crashed on it, or it ran out of its CPU time or the
    backstop) is left to `checked`, which surveys it alone and says what happened; a new child
    goes on with the files after it. Paths that are not files are left to the command."""
    todo = [p for p in map(os.fspath, paths) if os.path.isfile(p) and _key(p) not in _SURVEYS]
    while todo:
        found = _surveys_in_child(todo)
        for path, result in zip(todo, found, strict=False):
            _SURVEYS[_key(path)] = result
        todo = todo[len(found) + 1:]


def _surveys_in_child(paths: list) -> list:
    """The surveys of the first files of `paths` that one child finished, in order."""
    limit = sum(cpu_seconds(os.path.getsize(p)) for p in paths)
    with _child(paths, limit) as child:
        try:
            out, _ = child.communicate(timeout=WALL_FACTOR * limit)
        except subprocess.TimeoutExpired:
            child.kill()
            out, _ = child.communicate()
    found = []
    for line in out.splitlines():
        try:
            found.append(json.loads(line))
        except ValueError:
            break
    return found[:len(paths)]


def _child(paths: list, cpu_limit: int):
    """The child that surveys `paths`, given `cpu_limit` s of CPU time: forked from this process
    when it has one thread (`station.session.forked`: numpy and h5py come imported), else a new
    interpreter (`python -m station.session.check FILE...`)."""
    if forkable():
        import h5py  # noqa: F401 - once, before the fork: the child's and the reader's after it

        child = Forked(lambda out: _each(paths, out))
    else:
        cmd = [sys.executable, *CHILD, *paths]
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
        child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                 errors="replace", env=env)
    _limit_cpu(child.pid, cpu_limit)
    return child


def _survey_in_child(path: str, cpu_limit: int) -> dict:
    """`survey(path)` run by a child process limited to `cpu_limit` s of CPU time; a crash inside
    the HDF5 library is damage (SessionFormatError), a child that could not finish is no verdict
    (SessionUncheckedError)."""
    wall = WALL_FACTOR * cpu_limit
    with _child([path], cpu_limit) as child:
        try:
            out, err = child.communicate(timeout=wall)
        except subprocess.TimeoutExpired:
            child.kill()
            child.communicate()
            raise SessionUncheckedError(
                f"{path} could not be checked: reading its HDF5 structure did not finish within "
                f"{wall:.0f} s, nor spend its {cpu_limit} s of CPU time (the file's storage may "
                f"not answer, or the host is overloaded); it was not found damaged. {AGAIN}"
            ) from None
    code = child.returncode
    if code < 0 and -code not in CRASHES:
        raise SessionUncheckedError(_stopped(path, -code, cpu_limit))
    try:
        return json.loads(out.splitlines()[-1])
    except (IndexError, ValueError):
        why = f"signal {signal.Signals(-code).name}" if code < 0 else f"exit {code}"
        last = err.strip().splitlines()[-1:] or [""]
        raise SessionFormatError(
            f"{path} is damaged: the HDF5 library failed reading it ({why}{': ' if last[0] else ''}"
            f"{last[0][:200]}); use an undamaged copy, or record the session again") from None


def _limit_cpu(pid: int, seconds: int) -> None:
    """Give the child `pid` `seconds` of CPU time: SIGXCPU then, SIGKILL 5 s later (a child
    already gone needs no limit)."""
    import contextlib
    import resource

    with contextlib.suppress(ProcessLookupError):
        resource.prlimit(pid, resource.RLIMIT_CPU, (seconds, seconds + 5))


def _stopped(path: str, signum: int, cpu_limit: int) -> str:
    """The words for a check child that a signal from outside the HDF5 library ended."""
    if signum == signal.SIGXCPU:
        return (f"{path} could not be checked: reading its HDF5 structure used its {cpu_limit} s "
                "of CPU time without finishing (the HDF5 library may be looping on damaged "
                "metadata); it was not found damaged. Use another copy of it, or add --no-check "
                "to skip the check (docs/cli.md)")
    return (f"{path} could not be checked: the check's child process was stopped by "
            f"{signal.Signals(signum).name} before it finished (killed from outside, or out of "
            f"memory); it was not found damaged. {AGAIN}")


def _spared(survey: dict, positions) -> bool:
    """True when every damaged row is a sample row of a known position outside `positions`."""
    damaged = survey.get("positions")
    return (positions is not None and damaged is not None and not set(damaged) & set(positions)
            and all(d["dataset"].startswith("/streams/") and d["rows"] for d in survey["damaged"]))


def describe(path, survey: dict) -> str:
    """One message for the damage a survey found (at most `SHOWN` places named)."""
    parts = list(survey["problems"])
    for d in survey["damaged"]:
        rows = f" rows {d['rows'][0]}-{d['rows'][1] - 1}" if d["rows"] else ""
        parts.append(f"{d['dataset']}{rows} do not read back intact")
    more = f" and {len(parts) - SHOWN} more" if len(parts) > SHOWN else ""
    words = f"{path} is damaged: {'; '.join(parts[:SHOWN])}{more}"
    damaged, recorded = survey.get("positions"), survey.get("recorded", 0)
    if damaged:
        others = [p + 1 for p in range(recorded) if p not in damaged]
        words += (f". The damaged samples belong to position(s) "
                  f"{_ranges([p + 1 for p in damaged])} (1-based)")
        if others:
            words += f"; `station replay FILE --positions {_ranges(others)}` solves the others"
    return words + ". Nothing was computed from it; use an undamaged copy, or record again"


def _ranges(numbers: list) -> str:
    """[1, 2, 3, 6] -> "1-3,6"."""
    runs = []
    for n in numbers:
        if runs and n == runs[-1][1] + 1:
            runs[-1][1] = n
        else:
            runs.append([n, n])
    return ",".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def survey(path) -> dict:
    """Read every object of `path`: {"problems": [...], "damaged": [{dataset, rows, error}],
    "positions": [...]} (the positions whose sample rows are damaged, when the events tell)."""
    import h5py

    try:
        f = _opened(path)
    except (OSError, SessionFormatError) as e:
        return {"problems": [f"not a readable HDF5 file ({e})"], "damaged": []}
    problems, damaged = [], []
    with f:
        names = []
        try:
            f.visit(names.append)
            _attributes(f)
        except Exception as e:  # noqa: BLE001 - a damaged header raises anything h5py has
            problems.append(f"its structure is damaged ({type(e).__name__}: {e})")
        for name in names:
            try:
                obj = f[name]
                _attributes(obj)
                if isinstance(obj, h5py.Dataset):
                    damaged += _dataset(obj, problems)
            except Exception as e:  # noqa: BLE001
                problems.append(f"/{name} cannot be read ({type(e).__name__}: {e})")
        positions, recorded = _positions(f, damaged) if damaged and not problems else (None, 0)
    return {"problems": problems, "damaged": damaged, "positions": positions,
            "recorded": recorded}


def _opened(path):
    """`path` open for reading with h5py: a live writer's file as HDF5's SWMR reader sees it; a
    killed writer's (flagged open for write, no lock held) as a closed file (`FlagsCleared`): its
    length checked against its superblock and a metadata checksum failure an error at once, where
    the SWMR reader retries, sleeping twice as long each time (0.27, 0.54, 1.1, 2.1, 4.3 s, ...
    measured on one read past the end of a truncated file), for hours."""
    import h5py

    from station.session._repair import FlagsCleared, open_flags
    from station.session.format import LIBVER

    flags = open_flags(path)
    if flags and not _held(path):
        return h5py.File(FlagsCleared(path), "r", libver=LIBVER)
    return h5py.File(path, "r", swmr=flags != 0, libver=LIBVER)


def _held(path: str) -> bool:
    """True when a process holds a lock on `path`: a live writer (`SessionWriter` holds a shared
    flock while it lives), or a reader through HDF5's file locking; False for a killed writer's
    file (the kernel released its lock)."""
    import fcntl

    fd = os.open(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)
    return False


def _attributes(obj) -> None:
    """Read every attribute value of `obj` (a damaged attribute message raises)."""
    for key in obj.attrs:
        obj.attrs[key]


def _dataset(ds, problems: list) -> list:
    """The damaged chunks of one dataset as row ranges; its size claim checked first."""
    claimed = ds.size * ds.dtype.itemsize
    chunk = ds.dtype.itemsize * int(np.prod(ds.chunks)) if ds.chunks else 0
    allowed = ds.id.get_storage_size() * (MAX_EXPANSION if ds.compression else 1) + chunk
    if claimed > max(allowed, 1 << 16):
        problems.append(f"{ds.name} claims {ds.shape[0]} rows ({claimed} bytes) but the file "
                        f"holds {ds.id.get_storage_size()} bytes for it")
        return []
    if ds.chunks is None or ds.ndim == 0:
        try:
            ds[()]
        except Exception as e:  # noqa: BLE001
            return [{"dataset": ds.name, "rows": None, "error": str(e)}]
        return []
    step, out = ds.chunks[0], []
    for start in range(0, ds.shape[0], step):
        try:
            ds[start:start + step]
        except Exception as e:  # noqa: BLE001
            if tail_rows(ds, start) is not None:  # a flush cut by a kill (`torn`)
                continue
            out.append({"dataset": ds.name, "rows": [start, min(start + step, ds.shape[0])],
                        "error": str(e)})
    return out


def _positions(f, damaged: list) -> tuple:
    """(0-based positions whose span of host time overlaps damaged sample rows, or None when not
    known; the number of positions recorded)."""
    from station.session.reader import read_events

    try:
        events = read_events(f["events"], f.filename)
    except Exception:  # noqa: BLE001 - damaged events: the positions cannot be told
        return None, 0
    spans = {}
    for e in events:
        if e.position is not None:
            lo, hi = spans.get(e.position, (e.time, e.time))
            spans[e.position] = (min(lo, e.time), max(hi, e.time))
    hit = set()
    for d in damaged:
        group = f[d["dataset"]].parent
        if not d["dataset"].startswith("/streams/") or "host_time" not in group or not d["rows"]:
            continue
        times = _readable_times(group, d["rows"], damaged)
        if times is None:
            return None, max(spans, default=-1) + 1
        lo, hi = times
        hit |= {p for p, (a, b) in spans.items() if a <= hi and b >= lo}
    return sorted(int(p) for p in hit) or None, max(spans, default=-1) + 1


def _readable_times(group, rows, damaged):
    """(first, last) host time around damaged rows, from the nearest readable rows."""
    ds = group["host_time"]
    bad = {tuple(d["rows"]) for d in damaged if d["dataset"] == ds.name}
    before, after = rows[0] - 1, rows[1]
    try:
        lo = float(ds[before]) if before >= 0 else -float("inf")
        hi = float(ds[after]) if after < ds.shape[0] else float("inf")
    except Exception:  # noqa: BLE001
        return None
    return None if bad and any(r[0] <= before < r[1] for r in bad) else (lo, hi)


def _each(paths: list, out=None) -> None:
    """The child's work: one line of JSON, the survey, per file in order, each printed as it is
    done; with several files, each within its own `cpu_seconds` of CPU time from its start (the
    soft RLIMIT_CPU moved on before each, under the hard limit the parent set)."""
    import resource

    for path in paths:
        if len(paths) > 1:
            use = resource.getrusage(resource.RUSAGE_SELF)
            soft = int(np.ceil(use.ru_utime + use.ru_stime)) + cpu_seconds(os.path.getsize(path))
            hard = resource.getrlimit(resource.RLIMIT_CPU)[1]
            if hard != resource.RLIM_INFINITY:
                soft = min(soft, hard)
            resource.setrlimit(resource.RLIMIT_CPU, (soft, hard))
        print(json.dumps(survey(path)), file=out or sys.stdout, flush=True)


if __name__ == "__main__":
    _each(sys.argv[1:])
