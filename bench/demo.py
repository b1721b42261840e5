"""Figures of `station demo` (issues 5 and 6): wall time and eps / sqrt(trace(CRLB)) over seeds.

Targets: each default run (20 positions, 12 gyros, 40x clock) finishes in under 60 s of wall time
on the shared 2-core machine (aim 20-30 s) with eps / sqrt(trace(CRLB)) <= 1.5; over several
seeds the mean of eps^2 / trace(CRLB) should be near 1 (the solver is efficient).

    .venv/bin/python -P bench/demo.py [--runs 3] [--imu serial can] [--json]

(-P: do not put bench/ on sys.path, where bench/serial.py would hide pyserial.)
"""

import argparse
import json
import resource
import tempfile
from pathlib import Path

import numpy as np

from station.commands.demo import run_demo


def cpu_seconds() -> float:
    """CPU time (user + system) used so far by this process."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def measure(imu: str, seeds, positions: int, speed: float) -> dict:
    """Run the demo once per seed; per-run figures and their summary."""
    runs = []
    with tempfile.TemporaryDirectory(prefix="bench-demo-") as tmp:
        for seed in seeds:
            cpu = cpu_seconds()
            s = run_demo(Path(tmp) / f"{imu}-{seed}.h5", imu, seed, positions, speed)
            runs.append({"seed": seed, "wall_seconds": s["wall_seconds"],
                         "cpu_seconds": cpu_seconds() - cpu, "ratio": s["eps_over_sqrt_crlb"],
                         "chi2_per_dof": s["chi2_per_dof"], "samples": s["samples"]})
    ratio = np.array([r["ratio"] for r in runs])
    wall = np.array([r["wall_seconds"] for r in runs])
    return {"imu": imu, "positions": positions, "speed": speed, "runs": runs,
            "wall_seconds_max": float(wall.max()), "wall_seconds_mean": float(wall.mean()),
            "ratio_max": float(ratio.max()), "mean_ratio_squared": float(np.mean(ratio**2)),
            "meets_targets": bool(wall.max() < 60 and ratio.max() <= 1.5)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=3, help="seeds per IMU link (default 3)")
    parser.add_argument("--imu", nargs="+", choices=("serial", "can"), default=["serial", "can"])
    parser.add_argument("--positions", type=int, default=20)
    parser.add_argument("--speed", type=float, default=40.0)
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    args = parser.parse_args()
    figures = [measure(imu, range(1, args.runs + 1), args.positions, args.speed)
               for imu in args.imu]
    if args.json:
        print(json.dumps(figures, indent=2))
        return
    for f in figures:
        print(f"{f['imu']}: {len(f['runs'])} runs of {f['positions']} positions at {f['speed']:g}x")
        for r in f["runs"]:
            print(f"  seed {r['seed']}: {r['wall_seconds']:.1f} s wall, {r['cpu_seconds']:.1f} s "
                  f"CPU, eps/sqrt(tr CRLB) {r['ratio']:.2f}, chi2/dof {r['chi2_per_dof']:.2f}")
        print(f"  max wall {f['wall_seconds_max']:.1f} s (target < 60), max ratio "
              f"{f['ratio_max']:.2f} (target <= 1.5), mean ratio^2 {f['mean_ratio_squared']:.2f}; "
              f"{'meets' if f['meets_targets'] else 'MISSES'} the targets")


if __name__ == "__main__":
    main()
