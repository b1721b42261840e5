"""The gyro from hand turns through the command line on simulated recordings (docs/hand-turns.md):
`station import csv` (the gyro as 16-bit raw counts, `counts:rad/s` without a nominal scale), then
`station solve --stream gyro`, against the simulation's truth. Prints the landing errors from the
start and calibrated, and how the scale factors' and biases' 1-sigma cover the truth (mean z^2, the
fraction within +-1.96 sigma).

    .venv/bin/python -P bench/carry_cli.py [--recordings N] [--json]
"""

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_gyro_carry import FS, G, hand_recording, true_sensitivity  # noqa: E402

from bench.realdata_cli import run  # noqa: E402
from station.calfiles.calfile import load  # noqa: E402

COUNTS, MID = 4000.0, 32768.0  # counts per rad/s and mid-scale of the simulated gyro
BIAS = np.array([0.02, -0.01, 0.015])  # rad/s, hand_recording's


def one(seed: int, work: Path) -> dict:
    """z-values of the scale factors and biases, and the landing errors, of one recording."""
    a_true = true_sensitivity(100 + seed)
    rates, f, _ = hand_recording(200 + seed, a_true)
    table = np.column_stack([np.arange(len(f)) / FS, f, np.round(COUNTS * rates + MID)])
    csv, h5 = work / f"r{seed}.csv", work / f"r{seed}.h5"
    np.savetxt(csv, table, delimiter=",", header="t,ax,ay,az,gx,gy,gz", comments="")
    run("import", "csv", h5, csv, "--time", "t", "--stream", "acc=ax,ay,az", "--unit",
        "acc=m/s^2", "--stream", "gyro=gx,gy,gz", "--unit", "gyro=counts:rad/s")
    cal = load(json.loads(run("solve", h5, "--stream", "gyro", "--magnitude", G,
                              "--json"))["calibration"])
    return {"scale_z": ((cal.scale_factors - COUNTS * np.linalg.norm(a_true, axis=0))
                        / cal.scale_factors_sigma).tolist(),
            "bias_z": ((cal.bias - MID - COUNTS * BIAS) / cal.bias_sigma).tolist(),
            **cal.fit["carry"]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=int, default=20)
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        runs = [one(seed, Path(tmp)) for seed in range(args.recordings)]
    figures = {"recordings": len(runs),
               "turns": [min(r["turns"] for r in runs), max(r["turns"] for r in runs)],
               "start_error_rms_deg_median": float(np.median([r["error_start_rms_deg"]
                                                              for r in runs])),
               "error_rms_deg_median": float(np.median([r["error_rms_deg"] for r in runs]))}
    for name in ("scale_z", "bias_z"):
        z = np.concatenate([r[name] for r in runs])
        figures[name] = {"mean_z2": float(np.mean(z**2)), "within_1.96": int(np.sum(np.abs(z)
                                                                                    < 1.96)),
                         "of": len(z)}
    print(json.dumps(figures, indent=1) if args.json else
          "\n".join(f"{k}: {v}" for k, v in figures.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
