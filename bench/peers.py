"""Side by side: imucal's Ferraris calibration and this project's iron path, on imucal's own data.

Data: ../shared/data/real/imucal-ferraris (PROVENANCE.md; never copied into the project). imucal is
a benchmark extra (`pip install -e .[bench]`), never a runtime dependency. One run prints, for both
tools: parameters (scale factors, misalignments, biases, handedness), wall time, and on the
continuous recording the face-norm residuals, the held-out residuals (still intervals not used by
either calibration) and the out-of-sample gyro check (gravity carried across each face-to-face
turn).

    .venv/bin/python -P bench/peers.py [--json] [--data DIR]
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from station.reduce.ferraris import (
    FACE_SECTIONS,
    calibrate_ferraris,
    find_sections,
    labelled_sections,
    read_recording,
    read_section_list,
    section_overlap,
)
from station.solve.gyro_turns import gravity_carry_errors, mirrored
from station.solve.uncertainty import axis_angles

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "imucal-ferraris"
G = 9.81  # imucal's default, used for its reference
FS_SECTIONS = 204.8  # annotated_session.csv, PROVENANCE.md
FS_CONTINUOUS = 102.4  # example_ferraris_session.csv, PROVENANCE.md
DEG = 180 / np.pi


def triad(a: np.ndarray, bias: np.ndarray, units_per_si: str) -> dict:
    """Gauge-invariant figures of a triad a (3, 3) with bias (3,) in input units."""
    scale = np.linalg.norm(a, axis=0)
    i, k = np.triu_indices(3, 1)
    return {
        f"scale_{units_per_si}": scale.tolist(),
        "misalignment_deg_xy_xz_yz": (np.degrees(axis_angles(a)[i, k]) - 90).tolist(),
        "bias_si": (bias / scale).tolist(),
        "determinant_sign": float(np.sign(np.linalg.det(a))),
    }


def imucal_model(info) -> dict:
    """imucal's parameters in this project's model z = a^T v + b (gyro a per rad/s)."""
    a_acc = (info.K_a @ info.R_a).T
    a_gyr = (info.K_g @ info.R_g).T * DEG
    return {
        "accel": triad(a_acc, np.asarray(info.b_a), "per_ms2"),
        "gyro": triad(a_gyr, np.asarray(info.b_g), "per_rads"),
        "gyro_mirrored": mirrored(a_acc, a_gyr),
    }


def our_model(cal) -> dict:
    return {
        "accel": triad(cal.a_acc, cal.accel.bias, "per_ms2"),
        "gyro": triad(cal.gyro.a, cal.gyro.bias, "per_rads"),
        "gyro_mirrored": mirrored(cal.a_acc, cal.gyro.a),
    }


def run_imucal(regions, fs: float, acc_unit: str, gyr_unit: str):
    """imucal's FerrarisCalibration with its defaults (grav 9.81, expected_angle -360), timed."""
    from imucal import FerrarisCalibration

    t0 = time.perf_counter()
    info = FerrarisCalibration().compute(
        regions, fs, from_acc_unit=acc_unit, from_gyr_unit=gyr_unit
    )
    return info, time.perf_counter() - t0


def differences(ours: dict, ref: dict) -> dict:
    """Largest relative scale, misalignment (deg) and bias (SI) differences, per sensor kind."""
    out = {}
    for kind, scale in (("accel", "scale_per_ms2"), ("gyro", "scale_per_rads")):
        o, r = ours[kind], ref[kind]
        out[kind] = {
            "scale_rel": float(np.max(np.abs(np.divide(o[scale], r[scale]) - 1))),
            "angle_deg": float(
                np.max(
                    np.abs(
                        np.subtract(o["misalignment_deg_xy_xz_yz"], r["misalignment_deg_xy_xz_yz"])
                    )
                )
            ),
            "bias_si": float(np.max(np.abs(np.subtract(o["bias_si"], r["bias_si"])))),
        }
    return out


def annotated(root: Path) -> dict:
    """The pre-cut raw-count sections: both tools against imucal's stored reference calibration."""
    import pandas as pd
    from imucal import ferraris_regions_from_df

    rec = read_recording(root / "annotated_session.csv")
    t0 = time.perf_counter()
    cal = calibrate_ferraris(rec.acc, rec.gyro, FS_SECTIONS, labelled_sections(rec.labels), G)
    t_ours = time.perf_counter() - t0
    regions = ferraris_regions_from_df(pd.read_csv(root / "annotated_session.csv", index_col=0))
    info, t_imucal = run_imucal(regions, FS_SECTIONS, "a.u.", "a.u.")

    ref = json.loads((root / "reference_annotated_session_calibration.json").read_text())
    reference = imucal_model(
        type("Reference", (), {k: np.array(v) for k, v in ref.items() if k[1] == "_"})
    )
    ours, peer = our_model(cal), imucal_model(info)
    return {
        "ours": ours,
        "imucal": peer,
        "reference": reference,
        "ours_minus_reference": differences(ours, reference),
        "imucal_minus_reference": differences(peer, reference),
        "time_ms": {"ours": 1e3 * t_ours, "imucal": 1e3 * t_imucal},
    }


def stream_figures(acc, rates, fs, faces: dict, still, used) -> dict:
    """Face-norm and held-out |a| - g, and the gravity-carry check, of calibrated streams."""
    face = [np.linalg.norm(acc[slice(*faces[f])].mean(axis=0)) - G for f in FACE_SECTIONS]
    held = [np.linalg.norm(acc[a:b].mean(axis=0)) - G
            for (a, b), u in zip(still, used, strict=True) if not u]
    carry = gravity_carry_errors(acc, rates, fs, still)
    return {
        "face_norm_ms2": face,
        "face_norm_rms_ms2": rms(face),
        "heldout_norm_ms2": held,
        "heldout_norm_rms_ms2": rms(held),
        "gyro_carry_deg": carry[:, 2].tolist(),
        "gyro_carry_turn_deg": carry[:, 1].tolist(),
        "gyro_carry_rms_deg": rms(carry[:, 2]),
        "gyro_carry_max_deg": float(carry[:, 2].max()),
    }


def continuous(root: Path) -> dict:
    """The continuous recording: our automatic sections vs imucal with the hand-made list."""
    import pandas as pd
    from imucal import ferraris_regions_from_section_list

    rec = read_recording(root / "example_ferraris_session.csv")
    hand = read_section_list(root / "example_ferraris_session_list.json")
    t0 = time.perf_counter()
    found = find_sections(rec.acc, rec.gyro, FS_CONTINUOUS, gyro_per_rad=DEG)
    t_find = time.perf_counter() - t0
    cal = calibrate_ferraris(rec.acc, rec.gyro, FS_CONTINUOUS, found.sections, G)
    t_ours = time.perf_counter() - t0
    cal_hand = calibrate_ferraris(rec.acc, rec.gyro, FS_CONTINUOUS, hand, G)

    data = pd.read_csv(root / "example_ferraris_session.csv", index_col=0)
    sections = pd.read_json(root / "example_ferraris_session_list.json").T
    info, t_imucal = run_imucal(
        ferraris_regions_from_section_list(data, sections), FS_CONTINUOUS, "m/s^2", "deg/s"
    )
    acc_i, gyr_i = info.calibrate(rec.acc, rec.gyro, "m/s^2", "deg/s")

    still = found.still.intervals
    used = [any(a <= found.sections[f][0] < b for f in FACE_SECTIONS) for a, b in still]
    overlap = section_overlap(found.sections, hand)
    return {
        "sections_found": found.sections,
        "sections_hand_made": hand,
        "coverage_of_hand_made": {k: v[0] for k, v in overlap.items()},
        "iou_with_hand_made": {k: v[1] for k, v in overlap.items()},
        "still_intervals": len(still),
        "heldout_intervals": int(len(still) - sum(used)),
        "ours": our_model(cal)
        | stream_figures(
            cal.apply_acc(rec.acc.T).T,
            cal.gyro.apply(rec.gyro.T).T,
            FS_CONTINUOUS,
            found.sections,
            still,
            used,
        ),
        "ours_hand_sections": stream_figures(
            cal_hand.apply_acc(rec.acc.T).T,
            cal_hand.gyro.apply(rec.gyro.T).T,
            FS_CONTINUOUS,
            hand,
            still,
            used,
        ),
        "imucal": imucal_model(info)
        | stream_figures(acc_i, gyr_i / DEG, FS_CONTINUOUS, hand, still, used),
        "ours_minus_imucal": differences(our_model(cal), imucal_model(info)),
        "time_ms": {
            "ours_find_sections": 1e3 * t_find,
            "ours_total": 1e3 * t_ours,
            "imucal": 1e3 * t_imucal,
        },
    }


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def show(report: dict) -> None:
    """Human-readable summary."""
    a = report["annotated"]
    print("annotated_session.csv (raw counts, given sections) vs imucal's stored reference:")
    for tool in ("ours", "imucal"):
        d = a[f"{tool}_minus_reference"]
        print(
            f"  {tool:7s} accel: scale {d['accel']['scale_rel']:.1e} rel, "
            f"angles {d['accel']['angle_deg']:.4f} deg, "
            f"bias {d['accel']['bias_si']:.4f} m/s^2 | "
            f"gyro: scale {d['gyro']['scale_rel']:.1e} rel, "
            f"angles {d['gyro']['angle_deg']:.4f} deg | mirrored gyro: {a[tool]['gyro_mirrored']}"
        )
    print(
        f"  reference: mirrored gyro: {a['reference']['gyro_mirrored']}   time ms: {a['time_ms']}"
    )
    c = report["continuous"]
    print("example_ferraris_session.csv (ours: automatic sections, imucal: hand-made list):")
    print(
        f"  coverage of the hand-made sections: min {min(c['coverage_of_hand_made'].values()):.3f}"
    )
    for tool in ("ours", "ours_hand_sections", "imucal"):
        t = c[tool]
        print(
            f"  {tool:18s} face |a|-g RMS {t['face_norm_rms_ms2']:.4f}, "
            f"held-out ({c['heldout_intervals']}) "
            f"{t['heldout_norm_rms_ms2']:.4f} m/s^2, "
            f"gyro carry RMS {t['gyro_carry_rms_deg']:.2f} deg "
            f"(max {t['gyro_carry_max_deg']:.2f}, {len(t['gyro_carry_deg'])} turns)"
        )
    print(f"  time ms: {c['time_ms']}")


def parsed(parser: argparse.ArgumentParser, argv) -> argparse.Namespace | None:
    """The arguments of a bench that compares with imucal: --json and --data DIR added to
    `parser`; None, after saying why on stderr, when imucal cannot run (no such folder, or imucal
    not installed)."""
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument("--data", type=Path, default=DATA, help="the imucal-ferraris folder")
    args = parser.parse_args(argv)
    try:
        import imucal  # noqa: F401
    except ImportError:
        print("imucal is not installed: pip install -e '.[bench]'", file=sys.stderr)
        return None
    if not args.data.is_dir():
        print(f"no imucal data under {args.data}", file=sys.stderr)
        return None
    return args


def main(argv=None) -> int:
    args = parsed(argparse.ArgumentParser(description=__doc__.splitlines()[0]), argv)
    if args is None:
        return 1
    report = {"annotated": annotated(args.data), "continuous": continuous(args.data)}
    if args.json:
        print(json.dumps(report, indent=1, default=float))
    else:
        show(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
