"""Interval honesty of the calibration's 1-sigma figures (issue 14): over repeated simulated
recordings of an MPU-6050-class triad (tests/posesim.py: 400 ug/sqrt(Hz) at 100 Hz, 3 s poses,
biases ~0.5 m/s^2, scale errors ~3 %, misalignments ~1 deg), the fraction of 95 % intervals
(+-1.96 sigma) of the scale factors, misalignments (axis angles) and biases that hold the truth,
for the total figure (white noise + the estimated per-pose term) and the white-noise figure.

Settings: white noise only; white noise + a per-pose error of 0.3 mg per axis + AR(1) noise of
1 mg (correlation time 0.5 s), at 20 poses and at 12. Each coverage is printed with its standard
error (of the mean of the per-recording fractions; ~1 % at 400 recordings).

    bench/honesty.py [--reps 400] [--seed 2026] [--json]
"""

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from posesim import CLASSES, G, coverage  # noqa: E402

SETTINGS = {
    "white noise, 20 poses": {"poses": 20},
    "pose 0.3 mg + AR(1) 1 mg, 20 poses": {"poses": 20, "pose_sd": 0.3e-3 * G, "ar_sd": 1e-3 * G},
    "white noise, 12 poses": {"poses": 12},
    "pose 0.3 mg + AR(1) 1 mg, 12 poses": {"poses": 12, "pose_sd": 0.3e-3 * G, "ar_sd": 1e-3 * G},
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=400, help="recordings per setting")
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    results = {name: coverage(args.seed + i, args.reps, **options)
               for i, (name, options) in enumerate(SETTINGS.items())}
    report = {"reps": args.reps, "seed": args.seed, "settings": results,
              "seconds": time.perf_counter() - start}
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"coverage of the 95 % intervals, {args.reps} recordings per setting (+- 1 s.e.)")
    for name, res in results.items():
        print(f"\n{name}: median pose sigma {res['pose_sigma_median']:.2g} m/s^2, "
              f"none estimated in {res['pose_sigma_zero_fraction']:.0%} of the fits")
        for figure in ("total", "white"):
            cells = ", ".join(f"{c} {100 * p:.1f} +- {100 * se:.1f} %"
                              for c, (p, se) in ((c, res[figure][c]) for c in CLASSES))
            print(f"  {figure:>5}: {cells}")
    print(f"\n{report['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
