"""Session-file checks on intact files beside CPU hogs (issue 29): no "damaged" from a busy host.

The files, all intact, written before the hogs start: the example sessions in sessions/, a
500-position rotary session (bench/scale_replay.py's `session`, 20 Hz, 37 MB) and, when
../shared/data/real/ is there, imported real recordings (imu_tk's Xsens MTi, imucal's Ferraris
recording, one MPU-9150 of imucalib). Then `--hogs` processes spin a core each
(bench/under_load.py's `spin`), alone for `--warmup` s, then beside `--workers` threads that run,
in a shuffled order (their processes load the host too: 10 hogs and 10 workers gave a 1-minute
load average of 24 on 2 cores, and 1000 checks and 60 commands took 26 minutes), with a progress
line on stderr every 50 jobs:

- `--checks` checks (`station.session.check.checked`, its cache keeping nothing, so each
  launches its child): the part of a command that said "damaged" under load;
- `--commands` whole session-reading commands (`python -m station solve|replay|noise|apply|
  diagnose|report ...`), each a fresh process.

Counted: intact, refused as damaged (must be 0), "could not be checked", and for the commands any
other failure (stderr kept); the wall time of each check and how many ran past the former
wall-clock limit (5 s + size / 50 MB/s: each of those was "damaged" before issue 29); the load
average sampled every 5 s, and the share of the samples at or above `--load`. A full command
costs 1-9 s of CPU and a check about 0.5 s, so 1000 whole commands at a load of 20 on 2 cores
would take hours: the checks carry the count, the commands show the whole path.

    .venv/bin/python -P bench/check_load.py [--checks 1000] [--commands 60] [--hogs 10]
        [--workers 10] [--load 20] [--warmup 60] [--json]
"""

import argparse
import json
import math
import multiprocessing
import os
import random
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.scale_replay import session as simulated_session  # noqa: E402
from bench.under_load import spin  # noqa: E402
from station.errors import SessionFormatError, SessionUncheckedError  # noqa: E402
from station.session import check  # noqa: E402

REAL = ROOT.parent / "shared" / "data" / "real"
OLD_BASE, OLD_RATE = 5.0, 50e6
"""The former wall-clock limit: 5 s + size / 50 MB/s."""


def station(*argv, cwd=ROOT) -> subprocess.CompletedProcess:
    """`python -m station ARGV` in a fresh process."""
    return subprocess.run([sys.executable, "-m", "station", *map(str, argv)], cwd=cwd,
                          capture_output=True, text=True)


def intact_files(work: Path) -> dict:
    """{name: path} of the intact session files (see the module docstring), written into
    `work`, and the calibration file `apply` uses ("cal")."""
    files = {p.stem: Path(shutil.copy(p, work / p.name))
             for p in sorted((ROOT / "sessions").glob("*.h5"))}
    files["rotary500"], _, _ = simulated_session(500, 20.0, work)
    if REAL.is_dir():
        files.update(imported(work))
    cal = work / "rotary.cal.json"
    done = station("solve", files["rotary-12gyro"], "--out", cal, "--force")
    if done.returncode:
        raise SystemExit(f"solving the example failed: {done.stderr}")
    return {**files, "cal": cal}


def imported(work: Path) -> dict:
    """Real recordings imported into session files by `station import` (as bench/realdata_cli.py
    imports them)."""
    out = {"xsens": work / "xsens.h5", "ferraris": work / "fer.h5", "mpu0": work / "mpu0.h5"}
    steps = [
        ("import", "text", out["xsens"], "--stream", f"acc={REAL / 'imutk-xsens/xsens_acc.mat'}",
         "--unit", "acc=counts:m/s^2", "--stream",
         f"gyro={REAL / 'imutk-xsens/xsens_gyro.mat'}", "--unit", "gyro=counts:rad/s"),
        ("import", "csv", out["ferraris"],
         REAL / "imucal-ferraris/example_ferraris_session.csv", "--no-time", "--fs", 102.4,
         "--stream", "acc=acc_x,acc_y,acc_z", "--unit", "acc=m/s^2", "--stream",
         "gyro=gyr_x,gyr_y,gyr_z", "--unit", "gyro=deg/s"),
        ("import", "text", out["mpu0"], "--no-time", "--fs", 100, "--stream",
         f"acc={REAL / 'imucalib-mpu9150x5/imu0.log'}", "--columns", "acc=1-3", "--unit",
         "acc=m/s^2", "--stream", f"gyro={REAL / 'imucalib-mpu9150x5/imu0.log'}",
         "--columns", "gyro=4-6", "--unit", "gyro=rad/s"),
    ]
    for argv in steps:
        done = station(*argv)
        if done.returncode:
            raise SystemExit(f"station {' '.join(map(str, argv))} failed: {done.stderr}")
    return out


def commands(files: dict, work: Path) -> list:
    """The argv of each session-reading command the bench cycles through."""
    r, out = files["rotary-12gyro"], work / "out"
    out.mkdir(exist_ok=True)
    argvs = [("solve", r, "--out", out / "r.cal.json", "--force"),
             ("replay", files["rotary500"]),
             ("noise", r),
             ("apply", files["cal"], r, "--out", out / "r.csv", "--force"),
             ("solve", files["iron4_example"], "--out", out / "i.cal.json", "--force"),
             ("diagnose", r),
             ("report", r, "--out", out / "r.html")]
    if "xsens" in files:
        argvs += [("solve", files["xsens"], "--magnitude", 9.81744, "--rest", "0:50", "--out",
                   out / "x.cal.json", "--force"),
                  ("replay", files["ferraris"], "--magnitude", 9.81, "--faces"),
                  ("noise", files["mpu0"], "--stream", "acc")]
    return argvs


class Forgetful(dict):
    """A survey cache that keeps nothing: every check launches its own child."""

    def __setitem__(self, key, value) -> None:
        pass


def one_check(path: Path) -> dict:
    """One check of `path` (its own child: the cache is `Forgetful`): outcome and wall time."""
    start = time.perf_counter()
    try:
        check.checked(path)
        outcome, words = "intact", ""
    except SessionFormatError as e:
        outcome, words = "damaged", str(e)
    except SessionUncheckedError as e:
        outcome, words = "unchecked", str(e)
    wall = time.perf_counter() - start
    old = OLD_BASE + path.stat().st_size / OLD_RATE
    return {"job": "check", "file": path.name, "outcome": outcome, "wall_s": wall,
            "past_old_limit": wall > old, "words": words[:300]}


def one_command(argv: tuple) -> dict:
    """One whole command in a fresh process: outcome (intact: exit 0), exit code, wall time."""
    start = time.perf_counter()
    done = station(*argv)
    wall = time.perf_counter() - start
    err = done.stderr.strip()
    outcome = ("intact" if done.returncode == 0 else "damaged" if "is damaged" in err
               else "unchecked" if "could not be checked" in err else "other")
    return {"job": "command", "argv": " ".join(map(str, argv[:2])), "outcome": outcome,
            "exit": done.returncode, "wall_s": wall, "words": err[-300:] if done.returncode else ""}


class LoadSampler:
    """The 1-minute load average, sampled every `period` s in a thread until `stop()`."""

    def __init__(self, period: float = 5.0):
        self.samples, self._stop = [], threading.Event()
        self._thread = threading.Thread(target=self._run, args=(period,), daemon=True)
        self._thread.start()

    def _run(self, period: float) -> None:
        while not self._stop.wait(period):
            self.samples.append(os.getloadavg()[0])

    def stop(self, target: float) -> dict:
        """Stop sampling; min, median, max, the number of samples and the share >= `target`."""
        self._stop.set()
        self._thread.join()
        s = self.samples or [os.getloadavg()[0]]
        return {"min": min(s), "median": statistics.median(s), "max": max(s), "samples": len(s),
                "share_at_target": sum(x >= target for x in s) / len(s), "target": target}


def progress(futures: list, start: float, every: int = 50) -> list:
    """The results of `futures` as they complete; a line on stderr every `every` of them."""
    rows = []
    for future in as_completed(futures):
        rows.append(future.result())
        if len(rows) % every == 0 or len(rows) == len(futures):
            counts = Counter(r["outcome"] for r in rows)
            print(f"{len(rows)}/{len(futures)} in {time.perf_counter() - start:.0f} s, load "
                  f"{os.getloadavg()[0]:.1f}: {dict(counts)}", file=sys.stderr, flush=True)
    return rows


def summary(rows: list, job: str) -> dict:
    """Counts and wall times of one kind of job."""
    mine = [r for r in rows if r["job"] == job]
    walls = sorted(r["wall_s"] for r in mine) or [0.0]
    out = {"runs": len(mine), **{k: sum(r["outcome"] == k for r in mine)
                                 for k in ("intact", "damaged", "unchecked", "other")},
           "wall_s": {"median": statistics.median(walls),
                      "p90": walls[math.ceil(0.9 * len(walls)) - 1], "max": walls[-1]},
           "not_intact": [r for r in mine if r["outcome"] != "intact"][:20]}
    if job == "check":
        out["past_old_wall_limit"] = sum(r["past_old_limit"] for r in mine)
        del out["other"]
    return out


def run(args, work: Path) -> dict:
    """Write the files, load the host, run the jobs; the figures."""
    files = intact_files(work)
    sessions = [p for name, p in files.items() if name != "cal"]
    rng = random.Random(args.seed)
    argvs = commands(files, work)
    jobs = ([(one_check, sessions[i % len(sessions)]) for i in range(args.checks)]
            + [(one_command, argvs[i % len(argvs)]) for i in range(args.commands)])
    rng.shuffle(jobs)
    check._SURVEYS = Forgetful()
    stop = multiprocessing.Event()
    hogs = [multiprocessing.Process(target=spin, args=(stop,), daemon=True)
            for _ in range(args.hogs)]
    for hog in hogs:
        hog.start()
    try:
        before = os.getloadavg()[0]
        time.sleep(args.warmup)  # the 1-minute average follows the hogs
        at_start = os.getloadavg()[0]
        sampler = LoadSampler()
        start = time.perf_counter()
        with ThreadPoolExecutor(args.workers) as pool:
            rows = progress([pool.submit(do, what) for do, what in jobs], start)
        seconds = time.perf_counter() - start
        load = sampler.stop(args.load)
    finally:
        stop.set()
        for hog in hogs:
            hog.join(5)
    return {"hogs": args.hogs, "workers": args.workers, "cpus": os.cpu_count(),
            "load": {"before_hogs": before, "at_start": at_start, **load}, "seconds": seconds,
            "files": {p.name: p.stat().st_size for p in sessions},
            "limits": {"cpu_s": {p.name: check.cpu_seconds(p.stat().st_size) for p in sessions},
                       "wall_backstop_factor": check.WALL_FACTOR},
            "checks": summary(rows, "check"), "commands": summary(rows, "command")}


def show(result: dict) -> None:
    """The figures as text."""
    load = result["load"]
    print(f"{result['hogs']} hogs, {result['workers']} workers on {result['cpus']} cpus, "
          f"{result['seconds']:.0f} s; 1-minute load average at the start {load['at_start']:.1f}, "
          f"during min {load['min']:.1f} median {load['median']:.1f} max {load['max']:.1f}, "
          f"{100 * load['share_at_target']:.0f} % of the samples >= {load['target']:g}")
    for job in ("checks", "commands"):
        s = result[job]
        counts = ", ".join(f"{k} {s[k]}" for k in ("intact", "damaged", "unchecked", "other")
                           if k in s)
        w = s["wall_s"]
        print(f"{job}: {s['runs']} runs: {counts}; wall s median {w['median']:.1f} p90 "
              f"{w['p90']:.1f} max {w['max']:.1f}"
              + (f"; {s['past_old_wall_limit']} past the former wall-clock limit"
                 if "past_old_wall_limit" in s else ""))
        for r in s["not_intact"]:
            print(f"  {r.get('argv') or r.get('file')}: {r['outcome']}: {r['words']}")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--checks", type=int, default=1000, help="checks of intact files")
    p.add_argument("--commands", type=int, default=60, help="whole session-reading commands")
    p.add_argument("--hogs", type=int, default=10, help="processes spinning a core each")
    p.add_argument("--workers", type=int, default=10, help="checks and commands run at once")
    p.add_argument("--load", type=float, default=20.0,
                   help="1-minute load average the run is meant to hold (the share of samples "
                        "at or above it is reported)")
    p.add_argument("--warmup", type=float, default=60.0,
                   help="seconds of the hogs alone before the jobs start")
    p.add_argument("--seed", type=int, default=1, help="order of the jobs")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="check_load") as work:
        result = run(args, Path(work))
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        show(result)
    return 1 if result["checks"]["damaged"] or result["commands"]["damaged"] else 0


if __name__ == "__main__":
    sys.exit(main())
