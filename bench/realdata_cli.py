"""The command-line figures of docs/realdata.md and docs/hand-turns.md (issue 14): imucal's Ferraris
recording through `station import` and `station solve --faces` beside the API path
(`station.reduce.ferraris.calibrate_ferraris`), and the gyros of the Xsens MTi and of the Ferraris
recording and of the five MPU-9150s from the turns between their still poses (`station solve
--stream gyro`).

Data: ../shared/data/real/ (PROVENANCE.md in each folder; never copied into the project). The
sessions are written to a temporary folder by the `station` command itself; the held-out figures
re-solve subsets through the same path (`station.replay.solve_recorded`, as `station replay
--faces --positions ...`).

    .venv/bin/python -P bench/realdata_cli.py [--json] [--data DIR]
"""

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from station.calfiles.calfile import load
from station.cli import main as station
from station.reduce.ferraris import FACE_SECTIONS, calibrate_ferraris, find_sections, read_recording
from station.reduce.imported import carry_samples
from station.replay import ReplaySettings, solve_recorded
from station.session import Session
from station.solve.gyro_carry import calibrate_carry
from station.solve.gyro_turns import gravity_carry_errors

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
G_FERRARIS, FS_FERRARIS = 9.81, 102.4  # imucal's default gravity; PROVENANCE.md
G_XSENS = 9.81744  # Padova, PROVENANCE.md


def run(*argv) -> str:
    """stdout of one `station` command (it must succeed)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = station([str(a) for a in argv])
    if code != 0:
        raise SystemExit(f"station {' '.join(map(str, argv))} exited {code}")
    return out.getvalue()


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def norm_errors(result, M) -> np.ndarray:
    """|a| - g of the readings M (3, P) calibrated by `result`."""
    return np.linalg.norm(result.apply(M), axis=0) - G_FERRARIS


def ferraris(root: Path, work: Path) -> dict:
    """Ferraris: accelerometer with --faces (all poses, leave one out, the API's six faces) and
    the gyro from the turns, beside the API."""
    h5 = work / "fer.h5"
    run("import", "csv", h5, root / "example_ferraris_session.csv", "--no-time", "--fs",
        FS_FERRARIS, "--stream", "acc=acc_x,acc_y,acc_z", "--unit", "acc=m/s^2",
        "--stream", "gyro=gyr_x,gyr_y,gyr_z", "--unit", "gyro=deg/s")
    rec = read_recording(root / "example_ferraris_session.csv")
    found = find_sections(rec.acc, rec.gyro, FS_FERRARIS, gyro_per_rad=180 / np.pi)
    api = calibrate_ferraris(rec.acc, rec.gyro, FS_FERRARIS, found.sections, G_FERRARIS)
    with Session.open(h5) as session:
        settings = ReplaySettings(magnitude=G_FERRARIS, faces=True)
        readings, result = solve_recorded(session, settings)
        poses = readings.M.shape[1]
        loo = [norm_errors(solve_recorded(session, ReplaySettings(
            magnitude=G_FERRARIS, faces=True,
            positions=tuple(k for k in range(poses) if k != j)))[1], readings.M[:, [j]])[0]
            for j in range(poses)]
        starts = readings.windows[:, 0] * FS_FERRARIS
        six = [int(np.argmin(np.abs(starts - found.sections[f][0]))) for f in FACE_SECTIONS]
        _, on_six = solve_recorded(session, ReplaySettings(magnitude=G_FERRARIS, faces=True,
                                                           positions=tuple(six)))
    rest = [k for k in range(poses) if k not in six]
    six_errors = norm_errors(on_six, readings.M)
    gyro = json.loads(run("solve", h5, "--stream", "gyro", "--magnitude", G_FERRARIS, "--faces",
                          "--out", work / "fer-gyro.cal.json", "--json"))
    cal = load(gyro["calibration"])
    rates = cal.apply(np.asarray(rec.gyro, float).T * np.pi / 180).T
    return {
        "poses": poses, "faces": list(readings.faces),
        "scale_factors": result.scale_factors.tolist(),
        "insample_norm_rms": rms(norm_errors(result, readings.M)),
        "leave_one_out_norm_rms": rms(loo), "leave_one_out_norm": np.round(loo, 4).tolist(),
        "six_faces_positions": [k + 1 for k in six],
        "six_faces_insample_norm_rms": rms(six_errors[six]),
        "six_faces_heldout_norm_rms": rms(six_errors[rest]),
        "six_faces_heldout_norm_max": float(np.abs(six_errors[rest]).max()),
        "six_faces_scale_factors": on_six.scale_factors.tolist(),
        "api_scale_factors": api.accel.scale_factors.tolist(),
        "gyro": gyro_figures(cal) | {
            "api_turn_scale_factors": np.linalg.norm(api.gyro.a * np.pi / 180, axis=0).tolist(),
            "full_turns_minus_360_deg": [
                float(np.degrees(np.linalg.norm(rates[slice(*found.sections[k])].sum(0)
                                                / FS_FERRARIS)) - 360)
                for k in ("x_rot", "y_rot", "z_rot")]},
    }


def xsens(root: Path, work: Path) -> dict:
    """The Xsens MTi's gyro from the turns between its still poses."""
    h5 = work / "xsens.h5"
    run("import", "text", h5, "--stream", f"acc={root / 'xsens_acc.mat'}", "--unit",
        "acc=counts:m/s^2", "--stream", f"gyro={root / 'xsens_gyro.mat'}", "--unit",
        "gyro=counts:rad/s")
    out = json.loads(run("solve", h5, "--stream", "gyro", "--rest", "0:50", "--magnitude",
                         G_XSENS, "--out", work / "xsens-gyro.cal.json", "--json"))
    return {"poses": out["poses"], **gyro_figures(load(out["calibration"])),
            **held_out_turns(h5, ReplaySettings(magnitude=G_XSENS, rest=(0.0, 50.0)))}


def mpu9150(root: Path, work: Path) -> dict:
    """The five MPU-9150s' gyros from the turns between their still poses (standard gravity)."""
    figures = {}
    for i in range(5):
        h5, log = work / f"mpu{i}.h5", root / f"imu{i}.log"
        run("import", "text", h5, "--no-time", "--fs", 100, "--stream", f"acc={log}", "--columns",
            "acc=1-3", "--unit", "acc=m/s^2", "--stream", f"gyro={log}", "--columns", "gyro=4-6",
            "--unit", "gyro=rad/s")
        out = json.loads(run("solve", h5, "--stream", "gyro", "--out",
                             work / f"mpu{i}-gyro.cal.json", "--json"))
        figures[f"imu{i}"] = {"poses": out["poses"], **gyro_figures(load(out["calibration"])),
                              **held_out_turns(h5, ReplaySettings())}
    return figures


def held_out_turns(h5: Path, settings: ReplaySettings) -> dict:
    """Two-fold check of the carry: the gyro calibrated on the first half of the still poses
    carries gravity through the turns of the second half, and the reverse (`gravity_carry_errors`
    on turns the fit did not see); RMS and max landing error over both halves' held-out turns."""
    with Session.open(h5) as session:
        readings, acc = solve_recorded(session, settings)
        gyro, z, intervals = carry_samples(session, "gyro", "acc", readings)
        fs = session.specs["acc"].rate_hz
    f = acc.apply(z.T).T
    half = len(intervals) // 2
    errors = []
    for fit, test in ((intervals[: half + 1], intervals[half:]),
                      (intervals[half:], intervals[: half + 1])):
        rates = calibrate_carry(gyro, fs, f, fit).apply(gyro.T).T
        errors += list(gravity_carry_errors(f, rates, fs, test)[:, 2])
    return {"held_out_turns": len(errors), "held_out_error_rms_deg": rms(errors),
            "held_out_error_max_deg": float(np.max(errors))}


def gyro_figures(cal) -> dict:
    """Scale factors, axis angles (deg), biases with their 1-sigma, and the carry's landings."""
    i, k = np.triu_indices(3, 1)
    return {"scale_factors": cal.scale_factors.tolist(),
            "scale_factors_sigma": cal.scale_factors_sigma.tolist(),
            "axis_angles_deg": np.degrees(cal.axis_angles[i, k]).tolist(),
            "axis_angles_sigma_deg": np.degrees(cal.axis_angles_sigma[i, k]).tolist(),
            "bias": cal.bias.tolist(), "bias_sigma": cal.bias_sigma.tolist(),
            **cal.fit["carry"]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument("--data", type=Path, default=DATA, help="the folder of the recordings")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"no real data under {args.data}", file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory() as tmp:
        report = {"ferraris": ferraris(args.data / "imucal-ferraris", Path(tmp)),
                  "xsens": xsens(args.data / "imutk-xsens", Path(tmp)),
                  "mpu9150": mpu9150(args.data / "imucalib-mpu9150x5", Path(tmp))}
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    for name, figures in report.items():
        print(name)
        for key, value in figures.items():
            print(f"  {key}: {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
