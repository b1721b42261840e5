"""Interruption matrix of `station record` + `station resume` on `station twin`.

Per interruption point (signal or lost device, protocol event, position; tests/interruption.py): the
samples found over the samples due in every window after the resume, and the largest deviation of
the Eq. (18) readings from an uninterrupted session of the same twin in units of their combined
1-sigma (acceptance: ratios 1.00, deviations <= 4); for a lost device also whether the table still
turned after `record` gave up. Prints a table, or one JSON object with --json.

    .venv/bin/python -P bench/interruptions.py [--json] [--signals SIGINT,SIGKILL] [--devices imu]

`--signals ""` runs only the lost devices (`--devices ""` only the signals).
"""

import argparse
import contextlib
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import numpy as np  # noqa: E402 - after the harness' folder is on the path
from interruption import LOSSES, STATES, deviation, record  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--signals", default="SIGINT,SIGTERM,SIGKILL")
    parser.add_argument("--devices", default="imu,table", help="devices lost (events: LOSSES)")
    parser.add_argument("--positions", default="0,1", help="0-based positions interrupted")
    parser.add_argument("--keep", type=Path,
                        help="keep the sessions in this folder (default: a temporary one)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    positions = [int(j) for j in args.positions.split(",")]
    points = [(s, kind, j) for s in filter(None, args.signals.split(",")) for kind in STATES
              for j in positions]
    points += [(d, kind, j) for d in filter(None, args.devices.split(",")) for kind in LOSSES[d]
               for j in positions]
    rows = []
    with contextlib.ExitStack() as stack:
        tmp = args.keep or Path(stack.enter_context(tempfile.TemporaryDirectory()))
        reference = record(tmp / "reference")
        for k, point in enumerate(points):
            start = time.perf_counter()
            try:
                run = record(tmp / f"p{k}", point)
            except Exception as exc:
                exc.add_note(f"interruption point {point}: {tmp / f'p{k}'}")
                raise
            ratios = np.array(run["ratios"])
            rows.append({"cause": point[0], "after": point[1], "position": point[2] + 1,
                         "record_exit": run["record_exit"], "resume_exit": run["resume_exit"],
                         "found_over_due_min": float(ratios.min()),
                         "found_over_due_max": float(ratios.max()),
                         "max_abs_deviation_sigma": float(np.abs(deviation(run, reference)).max()),
                         "table_running": run.get("table_running"),
                         "seconds": time.perf_counter() - start})
    summary = {"points": len(rows),
               "worst_ratio": max(abs(r[f"found_over_due_{m}"] - 1) for r in rows
                                  for m in ("min", "max")),
               "worst_deviation_sigma": max(r["max_abs_deviation_sigma"] for r in rows)}
    if args.json:
        print(json.dumps({"points": rows, "summary": summary}, indent=1))
        return
    print(f"{'cause':8} {'after':15} {'pos':>3} {'exits':>8} {'found/due':>15} {'max |dev|':>9} "
          "table turning after record")
    for r in rows:
        turning = {None: "", True: "yes", False: "no"}[r["table_running"]]
        print(f"{r['cause']:8} {r['after']:15} {r['position']:3d} "
              f"{r['record_exit']:>4}/{r['resume_exit']:<3} "
              f"{r['found_over_due_min']:7.4f}-{r['found_over_due_max']:.4f} "
              f"{r['max_abs_deviation_sigma']:9.2f} {turning}")
    print(f"{summary['points']} points: worst |found/due - 1| {summary['worst_ratio']:.4f}, "
          f"worst deviation {summary['worst_deviation_sigma']:.2f} sigma")


if __name__ == "__main__":
    main()
