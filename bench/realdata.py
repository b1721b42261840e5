"""Free-static calibration on real recordings (issue 8): the Xsens MTi of imu_tk and five MPU-9150s;
and the iron path on imucal's Ferraris recording (six faces, three turns; bench/peers.py adds
imucal).

Data: ../shared/data/real/ (read each PROVENANCE.md; the data are never copied into the project).
Prints the detector's interval counts (and their robustness to the threshold factor), held-out
|a| - g of our calibration next to the manufacturer's printed one, the result in SI units compared
with the manufacturer's, and the MPU-9150 unit-to-unit spread. Still poses are detected on the
accelerometer (the gyro gives biases only), as `station solve` does for an imported recording by
default: the CLI recipes of docs/realdata.md average the same readings.

    .venv/bin/python bench/realdata.py [--json] [--data DIR]
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from station.imports.tables import read_table
from station.model.constants import STANDARD_GRAVITY
from station.reduce.ferraris import (
    calibrate_ferraris,
    find_sections,
    read_recording,
    read_section_list,
    section_overlap,
)
from station.reduce.free_static import calibrate_free_static, leave_one_out
from station.reduce.stillness import detect_still
from station.solve.gyro_turns import gravity_carry_errors
from station.solve.uncertainty import axis_angles

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
FS = 100.0  # both data sets, PROVENANCE.md
XSENS_G = 9.81744  # local gravity used by the imu_tk authors (Padova), PROVENANCE.md
XSENS_REST = 50.0  # s, the initial rest of the imu_tk protocol (setInitStaticIntervalDuration(50))
# Manufacturer calibration of this unit (PROVENANCE.md): raw = K T a + offset, counts
XSENS_GAIN = np.array([415.0, 413.0, 415.0])  # counts per m/s^2
XSENS_MISALIGNMENT = np.array([[1.00, 0.00, -0.01], [0.01, 1.00, 0.01], [0.02, 0.01, 1.00]])
XSENS_OFFSET = np.array([33123.0, 33276.0, 32360.0])  # counts
XSENS_GYRO_GAIN = np.array([4778.0, 4758.0, 4766.0])  # counts per rad/s
XSENS_GYRO_OFFSET = np.array([32768.0, 32466.0, 32485.0])  # counts
MPU_G = STANDARD_GRAVITY  # the MPU-9150 recordings do not state their location
THRESHOLD_SWEEP = (2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0)  # enter factors, leave = 2 x enter
ACC = {"acc": [0, 1, 2]}  # the accelerometer decides stillness (`--still-channels acc`)
VETO = {"acc": [0, 1, 2], "gyro": [3, 4, 5]}  # the gyro can veto (`--still-channels acc+gyro`)


def manufacturer_magnitudes(readings: np.ndarray) -> np.ndarray:
    """|a_j| of the still means (3, P) under the printed calibration a = (K T)^-1 (raw - offset)."""
    kt = np.diag(XSENS_GAIN) @ XSENS_MISALIGNMENT
    return np.linalg.norm(np.linalg.solve(kt, readings - XSENS_OFFSET[:, None]), axis=0)


def off_diagonal_deg(angles: np.ndarray) -> list:
    """Misalignments (deg): angle(x,y), angle(x,z), angle(y,z) minus 90 degrees."""
    i, k = np.triu_indices(3, 1)
    return (np.degrees(angles[i, k]) - 90.0).tolist()


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def xsens(root: Path) -> dict:
    """Every Xsens figure: detection, held-out accuracy, SI result vs the manufacturer's."""
    acc = read_table(root / "xsens_acc.mat", 4)
    gyro = read_table(root / "xsens_gyro.mat", 4)
    if not np.array_equal(acc[:, 0], gyro[:, 0]):
        raise SystemExit("xsens_acc.mat and xsens_gyro.mat do not share their time stamps")
    acc, gyro = acc[:, 1:], gyro[:, 1:]
    rest = (0, round(XSENS_REST * FS))

    t0 = time.perf_counter()
    fit = calibrate_free_static(acc, FS, XSENS_G, gyro=gyro, rest=rest, groups=ACC)
    t_path = time.perf_counter() - t0
    t0 = time.perf_counter()
    held_out = leave_one_out(fit.readings, XSENS_G)
    t_loo = time.perf_counter() - t0

    both = np.hstack([acc, gyro])
    sweep = {
        str(f): len(detect_still(acc, FS, rest=rest, enter=f, leave=2 * f).intervals)
        for f in THRESHOLD_SWEEP
    }
    no_rest = len(detect_still(acc, FS).intervals)
    veto = len(detect_still(both, FS, rest=rest, groups=VETO).intervals)

    a = fit.accel
    kt = np.diag(XSENS_GAIN) @ XSENS_MISALIGNMENT
    mfr_angles = axis_angles(kt.T)  # sensor axes are the rows of K T (z = a^T v + b)
    lengths = fit.still.lengths / FS
    return {
        "samples": int(acc.shape[0]),
        "intervals": len(fit.still.intervals),
        "intervals_no_rest": no_rest,
        "intervals_gyro_veto": veto,
        "intervals_vs_enter_factor": sweep,
        "first_interval_s": (fit.still.intervals[0] / FS).tolist(),
        "interval_length_s": {"min": lengths.min(), "median": float(np.median(lengths))},
        "overdue_motions": len(fit.still.overdue),
        "noise_counts": fit.still.noise.tolist(),
        "g_local": XSENS_G,
        "heldout_rms_ms2": rms(held_out),
        "heldout_max_ms2": float(np.abs(held_out).max()),
        "fit_rms_ms2": rms(np.linalg.norm(a.apply(fit.readings), axis=0) - XSENS_G),
        "manufacturer_rms_ms2": rms(manufacturer_magnitudes(fit.readings) - XSENS_G),
        "residual_over_white_stderr": rms(a.residuals) / rms(fit.readings_stderr),
        "leave_one_out_refused": {int(j): why for j, why in held_out.refused.items()},
        "accel": {
            "start": a.start,
            "pose_sigma_counts": a.pose_sigma,
            "scale_sigma_white": a.scale_factors_sigma_white.tolist(),
            "bias_sigma_white_counts": a.bias_sigma_white.tolist(),
            "scale_counts_per_ms2": a.scale_factors.tolist(),
            "scale_sigma": a.scale_factors_sigma.tolist(),
            "scale_manufacturer": np.linalg.norm(kt, axis=1).tolist(),
            "misalignment_deg_xy_xz_yz": off_diagonal_deg(a.axis_angles),
            "misalignment_sigma_deg": np.degrees(
                a.axis_angles_sigma[np.triu_indices(3, 1)]
            ).tolist(),
            "misalignment_manufacturer_deg": off_diagonal_deg(mfr_angles),
            "bias_counts": a.bias.tolist(),
            "bias_sigma_counts": a.bias_sigma.tolist(),
            "bias_manufacturer_counts": XSENS_OFFSET.tolist(),
            "bias_minus_manufacturer_ms2": ((a.bias - XSENS_OFFSET) / a.scale_factors).tolist(),
        },
        "gyro": {
            "bias_counts": fit.gyro_bias.tolist(),
            "bias_sigma_counts": fit.gyro_bias_sigma.tolist(),
            "bias_manufacturer_counts": XSENS_GYRO_OFFSET.tolist(),
            "bias_minus_manufacturer_rads": (
                (fit.gyro_bias - XSENS_GYRO_OFFSET) / XSENS_GYRO_GAIN
            ).tolist(),
            "rest_interval_s": (fit.still.intervals[fit.rest_index] / FS).tolist(),
        },
        "time_ms": {"detect_and_calibrate": 1e3 * t_path, "leave_one_out_38_fits": 1e3 * t_loo},
    }


def mpu(root: Path) -> dict:
    """Each MPU-9150's accelerometer by the same path (no declared rest: the robust noise level),
    and the unit-to-unit spread."""
    units = []
    for path in sorted(root.glob("imu*.log")):
        x = read_table(path, 6)
        fit = calibrate_free_static(x[:, :3], FS, MPU_G, gyro=x[:, 3:], groups=ACC)
        units.append(
            {
                "unit": path.stem,
                "intervals": len(fit.still.intervals),
                "heldout_rms_ms2": rms(leave_one_out(fit.readings, MPU_G)),
                "scale": fit.accel.scale_factors.tolist(),
                "misalignment_deg": off_diagonal_deg(fit.accel.axis_angles),
                "bias_ms2": (fit.accel.bias / fit.accel.scale_factors).tolist(),
                "gyro_bias_rads": fit.gyro_bias.tolist(),
            }
        )
    spread = {
        key: np.std([u[key] for u in units], axis=0, ddof=1).tolist()
        for key in ("scale", "misalignment_deg", "bias_ms2", "gyro_bias_rads")
    }
    return {"g_assumed": MPU_G, "units": units, "unit_to_unit_sd": spread}


def imucal_ferraris(root: Path) -> dict:
    """imucal's continuous Ferraris recording: automatic sections and the gravity-carry gyro
    check."""
    fs, g = 102.4, 9.81  # PROVENANCE.md; imucal's default gravity
    rec = read_recording(root / "example_ferraris_session.csv")
    t0 = time.perf_counter()
    found = find_sections(rec.acc, rec.gyro, fs, gyro_per_rad=180 / np.pi)
    cal = calibrate_ferraris(rec.acc, rec.gyro, fs, found.sections, g)
    t_path = time.perf_counter() - t0
    overlap = section_overlap(
        found.sections, read_section_list(root / "example_ferraris_session_list.json")
    )
    acc, rates = cal.apply_acc(rec.acc.T).T, cal.gyro.apply(rec.gyro.T).T
    carry = gravity_carry_errors(acc, rates, fs, found.still.intervals)
    return {
        "min_coverage_of_hand_made_sections": min(c for c, _ in overlap.values()),
        "accel_scale": cal.accel.scale_factors.tolist(),
        "gyro_scale_per_rads": cal.gyro.fit.scale_factors.tolist(),
        "turn_senses": list(cal.gyro.senses),
        "gyro_carry_rms_deg": rms(carry[:, 2]),
        "gyro_carry_max_deg": float(carry[:, 2].max()),
        "time_ms": 1e3 * t_path,
    }


def show(report: dict) -> None:
    """Human-readable summary of the figures."""
    x = report.get("xsens")
    if x:
        print(f"Xsens MTi ({x['samples']} samples at {FS:g} Hz)")
        print(
            f"  still intervals: {x['intervals']} (no declared rest: "
            f"{x['intervals_no_rest']}, "
            f"gyro veto: {x['intervals_gyro_veto']})"
        )
        print(f"  vs enter factor: {x['intervals_vs_enter_factor']}")
        print(
            f"  held-out RMS |a|-g: ours {x['heldout_rms_ms2']:.4f} m/s^2, "
            f"manufacturer {x['manufacturer_rms_ms2']:.4f} m/s^2 (fit {x['fit_rms_ms2']:.4f})"
        )
        a = x["accel"]
        for name, ours, sig, mfr in (
            (
                "scale [counts/(m/s^2)]",
                a["scale_counts_per_ms2"],
                a["scale_sigma"],
                a["scale_manufacturer"],
            ),
            (
                "misalignment [deg]",
                a["misalignment_deg_xy_xz_yz"],
                a["misalignment_sigma_deg"],
                a["misalignment_manufacturer_deg"],
            ),
            (
                "accel bias [counts]",
                a["bias_counts"],
                a["bias_sigma_counts"],
                a["bias_manufacturer_counts"],
            ),
            (
                "gyro bias [counts]",
                x["gyro"]["bias_counts"],
                x["gyro"]["bias_sigma_counts"],
                x["gyro"]["bias_manufacturer_counts"],
            ),
        ):
            pairs = ", ".join(f"{o:.3f}+-{s:.3f} ({m:.3f})"
                              for o, s, m in zip(ours, sig, mfr, strict=False))
            print(f"  {name}: {pairs}   (manufacturer in brackets)")
        print(f"  1 sigma above: white noise + a per-pose error of {a['pose_sigma_counts']:.3g} "
              f"counts ({a['start']} start); white noise alone: scale "
              f"{', '.join(f'{s:.3f}' for s in a['scale_sigma_white'])}, accel bias "
              f"{', '.join(f'{s:.3f}' for s in a['bias_sigma_white_counts'])}; refused "
              f"leave-one-out folds: {len(x['leave_one_out_refused'])}")
        print(f"  time: {x['time_ms']}")
    m = report.get("mpu9150")
    if m:
        print(f"MPU-9150 x{len(m['units'])} (g assumed {m['g_assumed']})")
        for u in m["units"]:
            print(
                f"  {u['unit']}: {u['intervals']} intervals, "
                f"held-out RMS {u['heldout_rms_ms2']:.4f}, "
                f"scale {np.round(u['scale'], 4).tolist()}, "
                f"bias {np.round(u['bias_ms2'], 3).tolist()}"
            )
        print(
            "  unit-to-unit sd: "
            f"{ {k: np.round(v, 4).tolist() for k, v in m['unit_to_unit_sd'].items()} }"
        )
    f = report.get("imucal_ferraris")
    if f:
        print(
            f"imucal Ferraris: sections cover >= "
            f"{f['min_coverage_of_hand_made_sections']:.3f} of the "
            f"hand-made ones, gyro carry RMS {f['gyro_carry_rms_deg']:.2f} deg "
            f"(max {f['gyro_carry_max_deg']:.2f}), {f['time_ms']:.0f} ms"
        )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument("--data", type=Path, default=DATA, help="folder of the real data sets")
    args = parser.parse_args(argv)
    report = {}
    if (args.data / "imutk-xsens").is_dir():
        report["xsens"] = xsens(args.data / "imutk-xsens")
    if (args.data / "imucalib-mpu9150x5").is_dir():
        report["mpu9150"] = mpu(args.data / "imucalib-mpu9150x5")
    if (args.data / "imucal-ferraris").is_dir():
        report["imucal_ferraris"] = imucal_ferraris(args.data / "imucal-ferraris")
    if not report:
        print(f"no real data under {args.data}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(report, indent=1, default=float))
    else:
        show(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
