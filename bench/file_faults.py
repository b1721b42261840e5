"""Damaged inputs against every reader (issues 20, 30): no traceback, no hang, no changed result.

Session files: each damaged file is a copy of a good session (recorded on the virtual bench into a
scratch folder by the current writer, so it carries its checksums) with one kind of damage:
truncated as a killed writer leaves it, a zeroed 4 KB block, flipped bytes (the killed writer's
open flags set on top of each), a dataset claiming 5e7 rows; each goes through `station solve`.

Every other input where it enters (issue 30), each file through one of the commands that read it
(in turn):
- metadata_deep: session metadata nested 65 to 100,000 deep (checksum rewritten: crafted, not
  damaged): replay, solve, diagnose, apply
- metadata_number: a number of the session metadata set to 1e999, -1e999, NaN or 10**400:
  replay, solve, diagnose, apply
- table_nan: NaN or inf at a random row of the recorded table time or angle: replay, solve,
  diagnose, report
- calfile_number: a number of a calibration file set to 1e999, -1e999, NaN or 10**400: apply,
  export
- calfile_deep: a calibration file nested 65 to 100,000 deep: apply, export
- profile_deep: a bench profile (TOML) holding arrays nested 17 to 100,000 deep: record
- profile_wide: a device profile of 1,025 to 100,000 channels: record
- npz_bomb: an .npz whose `y` (all zeros, deflated ~1000 times) inflates to 20-1400 MB: import,
  diagnose

Per class the bench prints files tried / clean errors (of them "could not be checked": the
session check ran out of its CPU time, exit 1, no verdict) / tracebacks / hangs / results
accepted that differ from the undamaged file's (any accepted calibration file, profile or .npz
of these classes is a changed result: each is damaged). A hang is a run past `--limit` (default
60 s: the check may spend 10 s + size / 10 MB/s of CPU time, which a busy host stretches in wall
time; 15 s before issue 29, when the check had a 5 s wall-clock limit).

    .venv/bin/python -P bench/file_faults.py [--files 200] [--seed 1] [--limit 60] [--json]
        [--classes truncated+killed,...]

A worker process runs the commands one file after the other; a file that takes longer than the
limit is counted as a hang and the worker is restarted. `bench/resume_faults.py` fuzzes the
metadata `station resume` rebuilds a bench from.
"""

import argparse
import json
import random
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent))  # last: bench/serial.py is not pyserial
import input_faults  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("rotary.h5",)

WORKER = r"""
import contextlib, io, json, os, sys, traceback
import numpy as np
from station.cli import main
commands, sys.stdin = sys.stdin, open(os.devnull)  # nobody answers a prompt
for line in commands:
    argv = json.loads(line)
    err = io.StringIO()
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
            code = main(argv)
        kind = "ok" if code == 0 else "error"
    except SystemExit as e:
        kind, code = "error", e.code
    except BaseException as e:
        where = traceback.format_exc().splitlines()[-3][:160]
        kind, code = "traceback", repr(e)[:200] + " | " + where
    print(json.dumps({"kind": kind, "code": code, "stderr": err.getvalue()[-300:],
                      "unchecked": "could not be checked" in err.getvalue()}), flush=True)
"""


def fresh_sources(scratch: Path) -> dict:
    """Sessions written now by the current writer (so with its checksums) into `scratch`: a
    rotary session recorded through the real drivers on the virtual bench, as
    sessions/record_examples.py records the committed example; name -> its calibration file's
    JSON, solved undamaged (the reference)."""
    from station.protocols.rotary import RotarySettings, suggested_axes
    from station.twin.rotary_bench import VirtualBench, record_rotary

    settings = RotarySettings(rate=1.0, revolutions=1, static=4.0, rest=0.5, guard=0.5,
                              steady=0.5)
    out = {}
    for name in SOURCES:
        src = scratch / name
        with VirtualBench(seed=7, speed=40.0, rate_hz=25.0, remount_time=1.0) as bench:
            record_rotary(bench, src, settings, suggested_axes(8))
        cal = scratch / (name + ".cal.json")
        subprocess.run([sys.executable, "-m", "station", "solve", str(src), "--out", str(cal),
                        "--force"], check=True, capture_output=True)
        out[name] = json.loads(cal.read_text())
    return out


def set_open_flags(data: bytearray) -> None:
    """The 'open for SWMR write' flags a killed writer leaves (superblock v3, byte 11), with the
    superblock checksum rewritten."""
    from station.session._repair import _lookup3

    data[11] = 0x05
    struct.pack_into("<I", data, 44, _lookup3(bytes(data[:44])))


def damage(kind: str, source: Path, out: Path, rng: random.Random) -> None:
    """Write one damaged copy of `source` to `out`."""
    b = bytearray(source.read_bytes())
    base, _, killed = kind.partition("+")
    if base == "truncated":
        b = b[:rng.randrange(2048, len(b))]
    elif base == "zeroed":
        at = rng.randrange(0, len(b) - 4096)
        b[at:at + 4096] = bytes(4096)
    elif base == "flipped":
        for _ in range(rng.choice((1, 2, 4, 16))):
            b[rng.randrange(0, len(b))] ^= 1 << rng.randrange(8)
    if killed and len(b) >= 48:
        set_open_flags(b)
    out.write_bytes(bytes(b))
    if base == "inflated":
        import h5py

        with h5py.File(out, "r+") as f:
            for column in ("counts", "seq", "device_time", "host_time"):
                f["streams/imu"][column].resize(rng.randrange(10**7, 10**8), axis=0)


SESSION_KINDS = ("truncated+killed", "zeroed", "zeroed+killed", "flipped", "flipped+killed",
                 "inflated")
KINDS = SESSION_KINDS + tuple(input_faults.KINDS)


class Worker:
    """A `station solve` worker process with a per-file time limit (s)."""

    def __init__(self, limit: float):
        self.proc, self.limit = None, limit

    def run(self, argv: list) -> dict:
        """`station ARGV` in the worker: its outcome (ok, error, traceback, hang)."""
        if self.proc is None:
            self.proc = subprocess.Popen([sys.executable, "-c", WORKER], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                         text=True, cwd=ROOT)
        t0 = time.monotonic()
        self.proc.stdin.write(json.dumps([str(a) for a in argv]) + "\n")
        self.proc.stdin.flush()
        import selectors

        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        ready = sel.select(self.limit)
        sel.close()
        if not ready:
            self.proc.kill()
            self.proc.wait()
            self.proc = None
            return {"kind": "hang", "seconds": time.monotonic() - t0}
        line = self.proc.stdout.readline()
        if not line:
            self.proc.wait()
            self.proc = None
            return {"kind": "traceback", "code": "worker died"}
        result = json.loads(line)
        result["seconds"] = time.monotonic() - t0
        return result

    def close(self):
        if self.proc is not None:
            self.proc.stdin.close()
            self.proc.wait()


def changed(cal: dict, reference: dict) -> bool:
    """True when an accepted calibration differs from the undamaged file's."""
    import numpy as np

    def numbers(c):
        return np.concatenate([np.ravel(np.asarray(c["sensitivity"]["a"], float)),
                               np.ravel(np.asarray(c["bias"]["b"], float))])

    a, b = numbers(cal), numbers(reference)
    return a.shape != b.shape or not np.allclose(a, b, rtol=1e-9, atol=0)


def session_case(kind: str, i: int, scratch: Path, rng: random.Random) -> dict:
    """Damaged session file i of `kind` through `station solve` (`input_faults.case`'s form)."""
    path = scratch / f"{kind}-{i}.h5"
    damage(kind, scratch / SOURCES[0], path, rng)
    out = scratch / f"{kind}-{i}.cal.json"
    return {"argv": ["solve", path, "--out", out, "--force"], "made": [path, out], "out": out,
            "accept": "compare"}


def tally(counts: dict, r: dict, case: dict, reference: dict, where: dict, worst: list,
          messages: dict) -> None:
    """Count one run's outcome `r` of `case` in `counts` (an acceptance as its `accept` says,
    `input_faults`: compared with the undamaged file's calibration `reference`, unverified, or
    changed)."""
    counts["tried"] += 1
    counts["slowest_s"] = max(counts["slowest_s"], round(r["seconds"], 2))
    if r["kind"] == "ok":
        if case["accept"] == "unverified":
            counts["unverified_accepted"] += 1
            return
        same = case["accept"] == "compare" and case["out"].exists() and \
            not changed(json.loads(case["out"].read_text()), reference)
        counts["same_accepted" if same else "changed_accepted"] += 1
        if not same:
            worst.append({**where, "stderr": r.get("stderr")})
    elif r["kind"] == "error":
        counts["clean_errors"] += 1
        counts["unchecked"] += r["unchecked"]
        messages.setdefault(where["class"], []).append(r["stderr"].strip())
    else:
        counts["tracebacks" if r["kind"] == "traceback" else "hangs"] += 1
        worst.append({**where, **r})


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--files", type=int, default=200, help="damaged files per class")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--limit", type=float, default=60.0, help="seconds a file may take")
    p.add_argument("--classes", default=",".join(KINDS),
                   help=f"comma-separated classes (default all: {','.join(KINDS)})")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    rng = random.Random(args.seed)
    rows, worst, messages = {}, [], {}
    with tempfile.TemporaryDirectory() as tmp:
        scratch = Path(tmp)
        references = fresh_sources(scratch)
        sources = input_faults.Sources(scratch, scratch / SOURCES[0],
                                       scratch / (SOURCES[0] + ".cal.json"))
        worker = Worker(args.limit)
        for kind in args.classes.split(","):
            counts = dict(tried=0, clean_errors=0, unchecked=0, tracebacks=0, hangs=0,
                          changed_accepted=0, same_accepted=0, unverified_accepted=0,
                          slowest_s=0.0)
            for i in range(args.files):
                case = session_case(kind, i, scratch, rng) if kind in SESSION_KINDS \
                    else input_faults.case(kind, i, sources, rng)
                r = worker.run(case["argv"])
                tally(counts, r, case, references[SOURCES[0]],
                      {"class": kind, "file": i, "command": case["argv"][0]}, worst, messages)
                for made in case["made"]:
                    made.unlink(missing_ok=True)
            rows[kind] = counts
        worker.close()
    if args.json:
        print(json.dumps({"classes": rows, "failures": worst[:30],
                          "messages": {k: v[:3] for k, v in messages.items()}}, indent=2))
    else:
        for kind, c in rows.items():
            print(f"{kind:18} " + " ".join(f"{k} {v}" for k, v in c.items()))
        for w in worst[:30]:
            print(w)
        for kind, said in messages.items():
            print(f"{kind}, e.g.: {said[0]}")
    bad = sum(c["tracebacks"] + c["hangs"] + c["changed_accepted"] for c in rows.values())
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
