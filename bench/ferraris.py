"""CPU time of the Ferraris calibration beside imucal's `FerrarisCalibration`, on imucal's own data.

Data: ../shared/data/real/imucal-ferraris (PROVENANCE.md): the annotated raw-count sections at
204.8 Hz and the continuous recording at 102.4 Hz with its hand-made section list, the same
sections for every tool. Five calls alternate in one process, CPU time each (the host is
shared): `calibrate_ferraris` (the closed form of station.solve.iron_faces, from the recording's
samples and its section bounds: the calibration and its checks, the uncertainties made when
read), the same with both results' uncertainties read (`.accel`, `.gyro.fit`: what a report
waits for), the same with `general=True` (station.calibrate's iterative ML, the baseline of
issue 35), imucal's `compute` (its regions cut beforehand, as its API takes them; no
uncertainties) and imucal from the same recording (its own helpers `ferraris_regions_from_df` /
`ferraris_regions_from_section_list` cut the regions, then `compute`: what a user of it waits
for, the input ours gets). Printed: the median CPU time of
each, the median over the rounds of the ratio ours / imucal (target <= 1.0) and the largest
difference between our two paths over every field of both calibrations (relative to the field's
size; residuals to the readings'; the covariance of theta by its eigenvalues, since each path
expresses it at its own estimate; target <= 1e-9).

    .venv/bin/python -P bench/ferraris.py [--rounds 200] [--json] [--data DIR]
"""

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.peers import G, parsed
from station.reduce.ferraris import (
    calibrate_ferraris,
    labelled_sections,
    read_recording,
    read_section_list,
)


def cases(root: Path) -> dict:
    """name -> (acc, gyro, fs, sections, imucal regions, imucal units, cut): cut() makes the
    regions again from the recording as imucal's own helpers do."""
    import pandas as pd
    from imucal import ferraris_regions_from_df, ferraris_regions_from_section_list

    rec = read_recording(root / "annotated_session.csv")
    frame = pd.read_csv(root / "annotated_session.csv", index_col=0)
    out = {"annotated_session": (rec.acc, rec.gyro, 204.8, labelled_sections(rec.labels),
                                 ferraris_regions_from_df(frame), ("a.u.", "a.u."),
                                 lambda: ferraris_regions_from_df(frame))}
    rec = read_recording(root / "example_ferraris_session.csv")
    data = pd.read_csv(root / "example_ferraris_session.csv", index_col=0)
    listed = pd.read_json(root / "example_ferraris_session_list.json").T
    out["example_ferraris_session"] = (
        rec.acc, rec.gyro, 102.4, read_section_list(root / "example_ferraris_session_list.json"),
        ferraris_regions_from_section_list(data, listed), ("m/s^2", "deg/s"),
        lambda: ferraris_regions_from_section_list(data, listed))
    return out


def cpu(call) -> float:
    """CPU seconds of one call."""
    start = time.process_time()
    call()
    return time.process_time() - start


def timings(case, rounds: int) -> dict:
    """Median CPU ms of each call and the median ratios, the calls alternating every round."""
    from imucal import FerrarisCalibration

    acc, gyro, fs, sections, regions, (acc_unit, gyr_unit), cut = case

    def imucal(parts):
        return FerrarisCalibration().compute(parts, fs, from_acc_unit=acc_unit,
                                             from_gyr_unit=gyr_unit)

    calls = {
        "ours": lambda: calibrate_ferraris(acc, gyro, fs, sections, G),
        "ours_uncertainties": lambda: uncertainties(calibrate_ferraris(acc, gyro, fs, sections, G)),
        "ours_general": lambda: calibrate_ferraris(acc, gyro, fs, sections, G, general=True),
        "imucal": lambda: imucal(regions),
        "imucal_from_recording": lambda: imucal(cut()),
    }
    for call in calls.values():
        call()
    t = np.array([[cpu(call) for call in calls.values()] for _ in range(rounds)])
    return {"cpu_ms": {k: 1e3 * float(np.median(t[:, i])) for i, k in enumerate(calls)},
            "ratio_ours_to_imucal": float(np.median(t[:, 0] / t[:, 3])),
            "ratio_ours_uncertainties_to_imucal": float(np.median(t[:, 1] / t[:, 3])),
            "ratio_ours_to_imucal_from_recording": float(np.median(t[:, 0] / t[:, 4])),
            "ratio_general_to_imucal": float(np.median(t[:, 2] / t[:, 3])),
            "speedup_over_general": float(np.median(t[:, 2] / t[:, 0]))}


def uncertainties(cal):
    """Both results of a Ferraris calibration made (their uncertainties: made when read)."""
    return cal.accel, cal.gyro.fit


def largest_difference(fast, general) -> float:
    """The largest difference of any field of two CalibrationResults, relative to its size
    (module notes)."""
    readings = np.abs(general.a.T @ general.v).max()
    worst = 0.0
    for field in dataclasses.fields(fast):
        x, y = getattr(fast, field.name), getattr(general, field.name)
        if field.name == "covariance":
            x, y = np.linalg.eigvalsh(x), np.linalg.eigvalsh(y)
        elif field.name == "axis_angles":  # the diagonal is arccos(1): 0 to about 1e-8
            off = ~np.eye(len(x), dtype=bool)
            x, y = x[off], y[off]
        if isinstance(y, np.ndarray) and y.size:
            size = readings if field.name == "residuals" else np.abs(y).max()
            worst = max(worst, float(np.abs(x - y).max() / max(size, 1e-300)))
    return worst


def differences(case) -> dict:
    """The largest relative difference between the closed form and the iterative path."""
    acc, gyro, fs, sections = case[:4]
    fast = calibrate_ferraris(acc, gyro, fs, sections, G)
    general = calibrate_ferraris(acc, gyro, fs, sections, G, general=True)
    return {"accel": largest_difference(fast.accel, general.accel),
            "gyro": largest_difference(fast.gyro.fit, general.gyro.fit),
            "a_acc": float(np.abs(fast.a_acc - general.a_acc).max() / np.abs(general.a_acc).max()),
            "a_gyro": float(np.abs(fast.gyro.a - general.gyro.a).max()
                            / np.abs(general.gyro.a).max())}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=200, help="rounds of the three calls")
    args = parsed(parser, argv)
    if args is None:
        return 1
    report = {name: {**timings(case, args.rounds), "max_difference": differences(case)}
              for name, case in cases(args.data).items()}
    report["targets"] = {"ratio_ours_to_imucal": 1.0, "max_difference": 1e-9}
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    for name, r in report.items():
        if name == "targets":
            continue
        ms = r["cpu_ms"]
        worst = max(r["max_difference"].values())
        print(f"{name}: CPU ms ours {ms['ours']:.3f} (with the uncertainties read "
              f"{ms['ours_uncertainties']:.3f}: "
              f"{r['ratio_ours_uncertainties_to_imucal']:.2f} x imucal), iterative "
              f"{ms['ours_general']:.3f}, imucal "
              f"{ms['imucal']:.3f}, imucal from the recording {ms['imucal_from_recording']:.3f}; "
              f"ours / imucal {r['ratio_ours_to_imucal']:.2f} (target <= 1: "
              f"{'met' if r['ratio_ours_to_imucal'] <= 1 else 'missed'}), ours / imucal from the "
              f"recording {r['ratio_ours_to_imucal_from_recording']:.2f}, iterative / imucal "
              f"{r['ratio_general_to_imucal']:.1f}; closed form vs iterative: largest relative "
              f"difference {worst:.1e} ({'met' if worst <= 1e-9 else 'missed'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
