"""Scale of the data path (issue 17): replay time and peak memory against the session's size.

Per size (rotary positions): `station simulate` (12-gyro array) writes the array file, `station
import npz` makes it a session file, `station replay` reduces and solves it; each step runs in a
fresh child process whose peak RSS (`resource.getrusage(RUSAGE_CHILDREN).ru_maxrss` of a child
that runs only that step), CPU time (user + system, its own children's included: the structure
check runs in one) and wall time are measured. A baseline child only imports `station.replay`.
Diagnose is measured at each size of `--diagnose-at` (default 500 and 1000 positions) on its own
session at `--diagnose-fs` (default 200 Hz, the simulator's rate: its memory grows with the
samples, 12 gyros x 7000 a position).

Acceptance (issue 17): the replay time grows at most linearly (exponent of a power-law fit of the
time against the positions <= 1.1; the fit over all sizes is flattened by the start-up, so the
exponent between the two largest sizes is given too) and the replay's peak RSS stays under
200 MB + 0.2 x the session file's size at every size; diagnose at 500 positions under 2 GB.
Issue 35: the replay of 2000 positions at 20 Hz in at most `REPLAY_CPU_S` of CPU, diagnose at
500 and at 1000 positions (200 Hz) in at most `DIAGNOSE_RSS_MB` of peak RSS. The machine's load
stretches wall times, not CPU times: the targets are read on CPU time.

The sessions are kept modest so that 2000 positions take minutes: `--fs` 20 Hz (700 samples a
35 s position) at the simulator's default timing (10 s static, 25 s moving at pi/2 rad/s).

    python -P bench/scale_replay.py [--sizes 20,100,500,2000] [--fs 20] [--diagnose-at 500,1000]
        [--json]
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

MB = 1 << 20
REPLAY_CPU_S = 3.0
"""Issue 35: CPU seconds of the replay of 2000 positions at 20 Hz."""
REPLAY_CPU_AT = 2000
DIAGNOSE_RSS_MB = 1024
"""Issue 35: peak RSS of diagnose at 500 and at 1000 positions, 200 Hz."""


def child(code: str, *argv) -> dict:
    """Wall time (s), CPU time (s, user + system, the child's own children included) and peak
    RSS (MB) of a fresh Python child running `code` with `argv`: RUSAGE_CHILDREN as seen by a
    helper process whose only child it is."""
    helper = ("import resource, subprocess, sys, time, json\n"
              "t = time.perf_counter()\n"
              "p = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
              "wall = time.perf_counter() - t\n"
              "use = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
              "print(json.dumps({'rc': p.returncode, 'wall_s': wall, "
              "'cpu_s': use.ru_utime + use.ru_stime, 'peak_rss_mb': use.ru_maxrss / 1024, "
              "'stderr': p.stderr[-2000:]}))\n")
    out = subprocess.run([sys.executable, "-c", helper, sys.executable, "-P", "-c", code,
                          *map(str, argv)], capture_output=True, text=True, check=True)
    result = json.loads(out.stdout)
    if result["rc"] != 0:
        raise RuntimeError(f"child {code[:60]!r} {argv} failed: {result['stderr']}")
    del result["stderr"], result["rc"]
    return result


STATION = "import sys; from station.cli import main; sys.exit(main(sys.argv[1:]))"


def station(*argv) -> dict:
    """`station ARGV` in a measured child."""
    return child(STATION, *argv)


def exponent(sizes, times) -> float:
    """Slope of log(time) against log(size): the power of a time ~ size^p fit."""
    return float(np.polyfit(np.log(sizes), np.log(times), 1)[0])


def session(n: int, fs: float, work: Path) -> tuple:
    """(session file, simulate's figures, import's figures) of a simulated rotary session of n
    positions at fs Hz, its array file deleted."""
    npz, h5 = work / f"rotary{n}_{fs:g}.npz", work / f"rotary{n}_{fs:g}.h5"
    sim = station("simulate", "--positions", n, "--fs", fs, "--seed", 1, "--out", npz)
    imp = station("import", "npz", h5, npz)
    npz.unlink()
    return h5, sim, imp


def diagnosed(n: int, fs: float, work: Path) -> dict:
    """station diagnose's wall time, CPU time and peak RSS on a session of n positions at fs Hz,
    against issue 35's `DIAGNOSE_RSS_MB`."""
    h5, _, _ = session(n, fs, work)
    diag = station("diagnose", h5, "--json")
    h5.unlink()
    return {"positions": n, "fs_hz": fs, "grid_values": int(round(n * 35 * fs)) * 12,
            "wall_s": diag["wall_s"], "cpu_s": diag["cpu_s"], "peak_rss_mb": diag["peak_rss_mb"],
            "limit_mb": DIAGNOSE_RSS_MB, "ok": diag["peak_rss_mb"] <= DIAGNOSE_RSS_MB}


def measure(sizes, fs: float, diagnose_at, diagnose_fs: float, work: Path) -> dict:
    """The figures of every size, the baseline and diagnose (see the module docstring)."""
    rows = []
    baseline = child("import station.replay")
    for n in sizes:
        h5, sim, imp = session(n, fs, work)
        size_mb = h5.stat().st_size / MB
        rep = station("replay", h5, "--json")
        limit = 200 + 0.2 * size_mb
        rows.append({"positions": n, "samples": int(round(n * 35 * fs)), "file_mb": size_mb,
                     "replay_s": rep["wall_s"], "replay_cpu_s": rep["cpu_s"],
                     "replay_peak_rss_mb": rep["peak_rss_mb"],
                     "rss_limit_mb": limit, "rss_ok": rep["peak_rss_mb"] <= limit,
                     "simulate_s": sim["wall_s"], "simulate_peak_rss_mb": sim["peak_rss_mb"],
                     "import_s": imp["wall_s"], "import_peak_rss_mb": imp["peak_rss_mb"]})
        print(f"{n} positions: {rows[-1]}", file=sys.stderr, flush=True)
        h5.unlink()
    diagnose = []
    for n in diagnose_at:
        diagnose.append(diagnosed(n, diagnose_fs, work))
        print(f"diagnose: {diagnose[-1]}", file=sys.stderr, flush=True)
    sizes, times = [r["positions"] for r in rows], [r["replay_s"] for r in rows]
    p = exponent(sizes, times) if len(rows) > 1 else float("nan")
    last = exponent(sizes[-2:], times[-2:]) if len(rows) > 1 else float("nan")
    return {"fs_hz": fs, "position_s": 35.0, "sizes": rows, "baseline": baseline,
            "time_exponent": p, "exponent_ok": p <= 1.1, "time_exponent_last_step": last,
            "rss_ok": all(r["rss_ok"] for r in rows), "diagnose": diagnose,
            "replay_cpu_target": replay_target(rows),
            "load_average": os.getloadavg(), "cpus": os.cpu_count()}


def replay_target(rows) -> dict | None:
    """Issue 35's replay line: the CPU time of the replay of `REPLAY_CPU_AT` positions against
    `REPLAY_CPU_S`, and the baseline's share (None: that size not measured)."""
    row = next((r for r in rows if r["positions"] == REPLAY_CPU_AT), None)
    if row is None:
        return None
    return {"positions": REPLAY_CPU_AT, "cpu_s": row["replay_cpu_s"], "limit_s": REPLAY_CPU_S,
            "ok": row["replay_cpu_s"] <= REPLAY_CPU_S}


def show(result: dict) -> None:
    """The figures as a table."""
    b = result["baseline"]
    print(f"fs {result['fs_hz']:g} Hz, {result['position_s']:g} s a position; load average "
          f"{', '.join(f'{x:.2f}' for x in result['load_average'])} on {result['cpus']} cpus")
    print(f"baseline (import station.replay): {b['wall_s']:.2f} s, {b['cpu_s']:.2f} s CPU, "
          f"{b['peak_rss_mb']:.0f} MB")
    print(f"{'positions':>9} {'file MB':>8} {'replay s':>9} {'CPU s':>6} {'RSS MB':>7} "
          f"{'limit MB':>9} {'sim s':>7} {'sim MB':>7} {'import MB':>9}")
    for r in result["sizes"]:
        print(f"{r['positions']:>9} {r['file_mb']:>8.1f} {r['replay_s']:>9.2f} "
              f"{r['replay_cpu_s']:>6.2f} {r['replay_peak_rss_mb']:>7.0f} "
              f"{r['rss_limit_mb']:>9.0f} {r['simulate_s']:>7.1f} "
              f"{r['simulate_peak_rss_mb']:>7.0f} {r['import_peak_rss_mb']:>9.0f}")
    print(f"replay time exponent {result['time_exponent']:.2f} (<= 1.1: "
          f"{'ok' if result['exponent_ok'] else 'FAILS'}; between the two largest sizes "
          f"{result['time_exponent_last_step']:.2f}); RSS under the limit at every size: "
          f"{'ok' if result['rss_ok'] else 'FAILS'}")
    target = result["replay_cpu_target"]
    if target:
        print(f"replay of {target['positions']} positions: {target['cpu_s']:.2f} s CPU "
              f"({'ok' if target['ok'] else 'FAILS'}: <= {target['limit_s']:g} s; baseline "
              f"import {b['cpu_s']:.2f} s)")
    for d in result["diagnose"]:
        print(f"diagnose at {d['positions']} positions, {d['fs_hz']:g} Hz: {d['wall_s']:.1f} s, "
              f"{d['cpu_s']:.1f} s CPU, {d['peak_rss_mb']:.0f} MB ({'ok' if d['ok'] else 'FAILS'}:"
              f" <= {d['limit_mb']} MB)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="20,100,500,2000", help="positions, comma-separated")
    ap.add_argument("--fs", type=float, default=20.0, help="sample rate, Hz")
    ap.add_argument("--diagnose-at", default="500,1000",
                    help="positions at which diagnose is measured, comma-separated (0: not "
                    "measured)")
    ap.add_argument("--diagnose-fs", type=float, default=200.0,
                    help="sample rate of diagnose's session, Hz (the simulator's default)")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    with tempfile.TemporaryDirectory(prefix="scale_replay") as work:
        diagnose_at = [int(s) for s in args.diagnose_at.split(",") if int(s)]
        result = measure(sizes, args.fs, diagnose_at, args.diagnose_fs, Path(work))
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        show(result)


if __name__ == "__main__":
    main()
