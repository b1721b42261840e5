"""A damaged session file found before a command trusts it: `checked(path)`.

HDF5 parses a file's metadata in C while holding Python's GIL, so no Python timeout can stop it: a
damaged object header can make the library loop, and its SWMR reader retries checksum failures for
minutes. So `checked` reads the whole file in a child process (`python -m
station.files.session.check FILE`) under a time limit: every group, attribute and dataset, each
dataset chunk by chunk (HDF5 verifies the writer's fletcher32 checksum of every chunk as it reads
it), and each dataset's claimed size against the storage the file really holds for it (a damaged
header that claims 5e7 rows in a 1 MB file must not make a reader allocate gigabytes). A file that
does not finish in time, crashes the child, or has damaged chunks is refused with one
`SessionFormatError` naming what is damaged and, for sample rows, the positions they belong to.

Files written before the checksums (no fletcher32 filter) are still read; damage inside their
raw numbers cannot be seen here, only by the quality gate of the fit (`station.solve.quality`).
"""

import json
import os
import subprocess
import sys

import numpy as np

from station.errors import SessionFormatError
from station.files.session.torn import tail_rows

BASE_LIMIT = 5.0
"""Seconds any file may take to be read through, plus `SECONDS_PER_BYTE` of its size."""
SECONDS_PER_BYTE = 1 / 50e6
SHOWN = 3
"""Damaged places a message names."""
MAX_EXPANSION = 64
"""A compressed dataset may claim at most this many times the bytes it stores."""


def checked(path, positions=None, limit: float | None = None) -> None:
    """Refuse `path` (SessionFormatError) unless every object and chunk of it reads back intact
    within the time limit (default: `BASE_LIMIT` + its size / 50 MB/s). With `positions` (0-based),
    damaged sample rows are allowed when they belong to other positions only (the reader drops
    them: `Session.stream`)."""
    from station.files.session._repair import open_flags

    path = os.fspath(path)
    open_flags(path)  # not HDF5 at all, or a damaged superblock: said at once
    limit = limit or BASE_LIMIT + os.path.getsize(path) * SECONDS_PER_BYTE
    cmd = [sys.executable, "-m", "station.files.session.check", path]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=limit, env=env,
                              check=False)
    except subprocess.TimeoutExpired:
        raise SessionFormatError(
            f"{path} is damaged: reading its HDF5 structure did not finish within {limit:.0f} s "
            "(the HDF5 library loops or retries on damaged metadata); nothing in it can be "
            "trusted. Use an undamaged copy, or record the session again") from None
    try:
        survey = json.loads(done.stdout.splitlines()[-1])
    except (IndexError, ValueError):
        raise SessionFormatError(
            f"{path} is damaged: the HDF5 library failed reading it (exit {done.returncode}); "
            "use an undamaged copy, or record the session again") from None
    if survey["problems"] or survey["damaged"] and not _spared(survey, positions):
        raise SessionFormatError(describe(path, survey))


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

    from station.files.session._repair import open_flags
    from station.files.session.format import LIBVER

    try:
        f = h5py.File(path, "r", swmr=open_flags(path) != 0, libver=LIBVER)
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
    from station.files.session.reader import read_events

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


if __name__ == "__main__":
    print(json.dumps(survey(sys.argv[1])))
