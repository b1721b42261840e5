"""`station resume` on crafted session metadata (issue 30): no traceback, no hang.

A rotary session is recorded on the virtual bench (lockstep time) with one position left to
record; then each field that `station resume` rebuilds the bench and the protocol from - every
key of `virtual_bench`, every rotary setting, `axes`, `spins`, `phis` - is set in turn to NaN,
inf, a negative number, a huge number and a value of the wrong type, the metadata's checksum
written again (a crafted file, not a damaged one), and `station resume` runs on the copy in its
own process. Each run ends as:

- refused: exit 2 with one line on stderr naming the field (the metadata check);
- resumed: exit 0 (the value is valid: e.g. a negative table rate, the other direction);
- error: another exit code with one line (e.g. a device error), counted apart;
- unnamed: exit 2 with one line that does not name the field (a refusal, but a vague one);
- traceback: a Python traceback on stderr (or more than one line);
- hang: no end within `--limit` wall seconds (the only verdict a wall clock gives; the runs are
  in lockstep time and a refusal takes no wall time of its own).

    .venv/bin/python -P bench/resume_faults.py [--limit 60] [--json]
"""

import argparse
import dataclasses
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VALUES = {"nan": math.nan, "inf": math.inf, "negative": -1, "huge": 1e300,
          "wrong_type": "fast"}
"""The values every field is set to, by name."""


def fields() -> list:
    """(path, ...) of every metadata field the rotary resume uses."""
    from station.protocols.rotary import RotarySettings
    from station.twin.rotary_bench import BENCH_KEYS

    return ([("virtual_bench", k) for k in sorted(BENCH_KEYS)]
            + [("settings", f.name) for f in dataclasses.fields(RotarySettings)]
            + [("axes",), ("spins",), ("phis",)])


def source(scratch: Path) -> Path:
    """A rotary session of the virtual bench with 2 of 3 positions recorded: recorded whole at 2
    positions, its metadata then asking for 3 (as a session killed after its second)."""
    from station.protocols.rotary import RotarySettings, suggested_axes
    from station.twin.rotary_bench import VirtualBench, record_rotary

    path = scratch / "source.h5"
    settings = RotarySettings(rate=1.0, revolutions=1, static=2.0, rest=0.5, guard=0.5,
                              steady=0.5)
    with VirtualBench(seed=7, rate_hz=25.0, remount_time=1.0) as bench:
        record_rotary(bench, path, settings, suggested_axes(3)[:2])
    rewrite(path, path, lambda m: m.update(axes=suggested_axes(3).tolist()))
    return path


def rewrite(src: Path, out: Path, edit) -> None:
    """Copy `src` to `out` with its metadata changed by `edit(metadata)` and its checksum
    written again (NaN and inf written as JSON's NaN and Infinity)."""
    import hashlib

    import h5py
    import numpy as np

    out.write_bytes(src.read_bytes())
    with h5py.File(out, "r+") as f:
        metadata = json.loads(f["metadata"][()])
        edit(metadata)
        text = json.dumps(metadata, sort_keys=True)
        del f["metadata"]
        ds = f.create_dataset("metadata", data=text, dtype=h5py.string_dtype())
        ds.attrs["sha256"] = np.bytes_(hashlib.sha256(text.encode()).hexdigest())


def put(metadata: dict, path: tuple, value) -> None:
    """Set the field at `path` of `metadata` to `value`."""
    target = metadata
    for key in path[:-1]:
        target = target.setdefault(key, {})
    target[path[-1]] = value


def run(path: Path, limit: float) -> dict:
    """`station resume path` in its own process group (stdin closed): (exit code, stderr, wall
    seconds), or a hang: the whole group killed after `limit` wall seconds."""
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "station", "resume", str(path)], cwd=ROOT,
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        _, err = proc.communicate(timeout=limit)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        return {"kind": "hang", "seconds": round(time.monotonic() - t0, 2)}
    return {"code": proc.returncode, "stderr": err.strip(),
            "seconds": round(time.monotonic() - t0, 2)}


def outcome(result: dict, field: str) -> str:
    """refused, resumed, unnamed, error, traceback or hang (module docstring)."""
    if result.get("kind") == "hang":
        return "hang"
    said = result["stderr"]
    if "Traceback" in said or len(said.splitlines()) > 1:
        return "traceback"
    if result["code"] == 0:
        return "resumed"
    if result["code"] == 2:
        return "refused" if field in said else "unnamed"
    return "error"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--limit", type=float, default=60.0, help="wall seconds a resume may take")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    counts = {k: 0 for k in ("tried", "refused", "resumed", "unnamed", "error", "traceback",
                             "hang")}
    failures, slowest = [], 0.0
    with tempfile.TemporaryDirectory() as tmp:
        scratch = Path(tmp)
        src = source(scratch)
        for path in fields():
            for name, value in VALUES.items():
                copy = scratch / f"fuzzed-{'.'.join(path)}-{name}.h5"  # a hang's may stay locked
                rewrite(src, copy, lambda m, p=path, v=value: put(m, p, v))
                result = run(copy, args.limit)
                kind = outcome(result, path[-1])
                counts["tried"] += 1
                counts[kind] += 1
                slowest = max(slowest, result["seconds"])
                if kind in ("traceback", "hang", "error", "unnamed"):
                    failures.append({"field": ".".join(path), "value": name, **result})
    counts["slowest_s"] = round(slowest, 2)
    if args.json:
        print(json.dumps({"resume": counts, "failures": failures[:30]}, indent=2))
    else:
        print("resume " + " ".join(f"{k} {v}" for k, v in counts.items()))
        for f in failures[:30]:
            print(f)
    return 1 if counts["traceback"] + counts["hang"] + counts["unnamed"] else 0


if __name__ == "__main__":
    sys.exit(main())
