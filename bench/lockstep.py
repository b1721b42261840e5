"""Lockstep determinism: the same seed recorded on the virtual bench idle and beside CPU hogs.

Runs `station demo --out FILE --json` (lockstep time, the default) once on an idle host and once
beside `--hogs` processes that spin a core each, then compares the two session files dataset by
dataset (samples, host times, table states, events, stored calibration) and the two summaries'
calibrations. Prints the largest difference of each, the demo's real-time factor in both runs and
the load average; one JSON object with --json. Exit 1 if a sample array differs or a calibration
differs by more than 1e-9.

    .venv/bin/python -P bench/lockstep.py [--hogs 6] [--positions 20] [--imu serial] [--json]
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from under_load import hogging  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CALIBRATION = ("scale_factors", "scale_factors_sigma", "eps", "chi2_per_dof")


def datasets(path) -> dict:
    """{name: array or bytes} of every dataset of an HDF5 file."""
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()])
                     if isinstance(obj, h5py.Dataset) else None)
    return out


def largest_difference(a, b) -> float:
    """Largest absolute difference of two datasets; inf when shapes or non-numbers differ."""
    if isinstance(a, bytes) or not hasattr(a, "dtype") or a.dtype.kind not in "fiub":
        return 0.0 if np.array_equal(a, b) else np.inf
    if a.shape != b.shape:
        return np.inf
    return float(np.max(np.abs(a.astype(float) - b.astype(float)), initial=0.0))


def demo(out: Path, args) -> dict:
    """One `station demo --json` run into `out`; its summary."""
    cmd = [sys.executable, "-m", "station", "demo", "--out", str(out), "--json", "--seed",
           str(args.seed), "--positions", str(args.positions), "--imu", args.imu]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=3600)
    if not done.stdout.strip().startswith("{"):
        raise SystemExit(f"station demo failed (exit {done.returncode}): {done.stderr[-500:]}")
    return json.loads(done.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hogs", type=int, default=6, help="CPU-bound processes beside run 2")
    parser.add_argument("--positions", type=int, default=20)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--imu", choices=("serial", "can"), default="serial")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="lockstep-") as tmp:
        idle_file, busy_file = Path(tmp) / "idle.h5", Path(tmp) / "busy.h5"
        idle = demo(idle_file, args)
        with hogging(args.hogs):
            busy = demo(busy_file, args)
            load = os.getloadavg()[0]
        a, b = datasets(idle_file), datasets(busy_file)
    names = sorted(set(a) | set(b))
    differences = {n: (largest_difference(a[n], b[n]) if n in a and n in b else np.inf)
                   for n in names}
    calibration = {k: float(np.max(np.abs(np.subtract(idle[k], busy[k])))) for k in CALIBRATION}
    samples = {n: d for n, d in differences.items() if n.startswith("streams/")}
    out = {"hogs": args.hogs, "load_average_1min": load, "positions": args.positions,
           "imu": args.imu,
           "real_time_factor": {"idle": idle["real_time_factor"], "busy": busy["real_time_factor"]},
           "record_seconds": {"idle": idle["record_seconds"], "busy": busy["record_seconds"]},
           "largest_difference": {n: d for n, d in differences.items()},
           "calibration_difference": calibration,
           "samples_identical": all(d == 0 for d in samples.values()),
           "calibration_within_1e-9": all(d <= 1e-9 for d in calibration.values())}
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        print(f"{args.imu} demo, {args.positions} positions, seed {args.seed}: idle "
              f"{idle['record_seconds']:.1f} s ({idle['real_time_factor']:.0f}x real time), "
              f"beside {args.hogs} hogs {busy['record_seconds']:.1f} s "
              f"({busy['real_time_factor']:.0f}x; load {load:.1f})")
        for name, d in differences.items():
            print(f"  {name:55s} largest difference {d:.3g}")
        for name, d in calibration.items():
            print(f"  calibration {name:43s} largest difference {d:.3g}")
        print(f"sample arrays identical: {out['samples_identical']}; calibration equal to 1e-9: "
              f"{out['calibration_within_1e-9']}")
    sys.exit(0 if out["samples_identical"] and out["calibration_within_1e-9"] else 1)


if __name__ == "__main__":
    main()
