"""Interval honesty of the calibration's 1-sigma figures (issue 14): over repeated simulated
recordings of an MPU-6050-class triad (tests/posesim.py: 400 ug/sqrt(Hz) at 100 Hz, 3 s poses,
biases ~0.5 m/s^2, scale errors ~3 %, misalignments ~1 deg), the fraction of 95 % intervals
(+-1.96 sigma) of the scale factors, misalignments (axis angles) and biases that hold the truth,
for the total figure (white noise + the estimated per-pose term) and the white-noise figure.

Settings: white noise only; white noise + a per-pose error of 0.3 mg per axis + AR(1) noise of
1 mg (correlation time 0.5 s), at 20 poses and at 12. Each coverage is printed with its standard
error (of the mean of the per-recording fractions; ~1 % at 400 recordings).

Real data (when ../shared/data/real/mimu4444-array is there): the 8 triads of the MIMU4444 array,
each calibrated from its free-static recording (station.reduce.free_static) in exp_1, exp_2 and
exp_3; per parameter class, sqrt(chi2 / dof) of the three estimates about their weighted mean in
units of each figure's 1-sigma (about 1 when the figure is honest across recordings).

    bench/honesty.py [--reps 400] [--seed 2026] [--json] [--data DIR]
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from posesim import CLASSES, G, coverage  # noqa: E402

from station.imports.recordings import import_binary  # noqa: E402
from station.reduce.free_static import calibrate_free_static  # noqa: E402
from station.session import Session  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
MIMU_RATE = 62.5  # Hz, PROVENANCE.md
MIMU_G = 9.81  # the authors' value (PROVENANCE.md)

SETTINGS = {
    "white noise, 20 poses": {"poses": 20},
    "pose 0.3 mg + AR(1) 1 mg, 20 poses": {"poses": 20, "pose_sd": 0.3e-3 * G, "ar_sd": 1e-3 * G},
    "white noise, 12 poses": {"poses": 12},
    "pose 0.3 mg + AR(1) 1 mg, 12 poses": {"poses": 12, "pose_sd": 0.3e-3 * G, "ar_sd": 1e-3 * G},
}


def read_mimu(path: Path) -> np.ndarray:
    """(samples, 8, 6) SI readings of one MIMU4444 recording, decoded by `station import binary`
    (the drivers' frame parser, profile mimu4444)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = import_binary(Path(tmp) / "mimu.h5", path, "mimu4444")
        with Session.open(out) as s:
            return s.stream("imu").to_si().reshape(-1, 8, 6)


def across_recordings(root: Path) -> dict:
    """Per class and figure: sqrt(chi2 / dof) of each triad's three estimates (exp_1..3) about
    their weighted mean, in units of their 1-sigma; and the per-pose terms found."""
    fits = {}
    for exp in (1, 2, 3):
        si = read_mimu(root / f"exp_{exp}.bin")
        for imu in range(8):
            fits[exp, imu] = calibrate_free_static(si[:, imu, :3], MIMU_RATE, MIMU_G,
                                                   gyro=si[:, imu, 3:])
    i, k = np.triu_indices(3, 1)
    pick = {"scale_factors": lambda r, w: (r.scale_factors, r.scale_factors_sigma_white if w
                                           else r.scale_factors_sigma),
            "misalignments": lambda r, w: (r.axis_angles[i, k], (r.axis_angles_sigma_white if w
                                                                 else r.axis_angles_sigma)[i, k]),
            "biases": lambda r, w: (r.bias, r.bias_sigma_white if w else r.bias_sigma)}
    out = {}
    for figure, white in (("total", False), ("white", True)):
        out[figure] = {}
        for name, get in pick.items():
            chi2 = []
            for imu in range(8):
                x, s = (np.array(v) for v in zip(*(get(fits[e, imu].accel, white)
                                                   for e in (1, 2, 3)), strict=True))
                w = 1 / s**2
                chi2.append(np.sum(w * (x - np.sum(w * x, 0) / np.sum(w, 0)) ** 2, 0) / 2)
            out[figure][name] = float(np.sqrt(np.mean(chi2)))
    out["pose_sigma_ms2"] = [fits[e, imu].accel.pose_sigma for e in (1, 2, 3) for imu in range(8)]
    out["poses"] = [len(fits[e, imu].still.intervals) for e in (1, 2, 3) for imu in range(8)]
    return out


def next_session(root: Path) -> dict:
    """Leave one recording out, the command-line way: each of exp_1..3 imported (`station import
    binary`) and solved as one 24-channel array (`station solve`); the other two combined
    (`station.calfiles.combined.combine`, what `station combine` writes) predict the third. Per
    class (biases, scale factors): RMS and median |z| / 0.6745 of z = (x - mean) / sqrt(sigma_next^2
    + s^2) over 24 parameters x 3 held-out recordings (about 1 when the next-session figure is
    honest); beside it the same ratio with one session's own 1-sigma (sigma_next replaced by the
    other two's median sigma)."""
    from station.calfiles.calfile import load
    from station.calfiles.combined import combine

    cals = []
    with tempfile.TemporaryDirectory() as tmp:
        for exp in (1, 2, 3):
            h5, cal = Path(tmp) / f"exp_{exp}.h5", Path(tmp) / f"exp_{exp}.cal.json"
            for argv in (["import", "binary", str(h5), str(root / f"exp_{exp}.bin"),
                          "--profile", "mimu4444"],
                         ["solve", str(h5), "--magnitude", str(MIMU_G), "--accept-suspect"]):
                subprocess.run([sys.executable, "-m", "station", *argv], check=True,
                               capture_output=True)
            cals.append(load(cal))
    out = {}
    for name, value, sigma in (("biases", "bias", "bias_sigma"),
                               ("scale_factors", "scale_factors", "scale_factors_sigma")):
        z_next, z_own = [], []
        for held in range(3):
            rest = [c for k, c in enumerate(cals) if k != held]
            pooled = combine(rest, [f"exp_{k + 1}" for k in range(3) if k != held])
            x, s = getattr(cals[held], value), getattr(cals[held], sigma)
            diff = x - getattr(pooled, value)
            z_next.append(diff / np.hypot(getattr(pooled, sigma), s))
            own = np.median([getattr(c, sigma) for c in rest], axis=0) / np.sqrt(2)
            z_own.append(diff / np.hypot(own, s))
        out[name] = {figure: {"rms": float(np.sqrt(np.mean(np.square(z)))),
                              "median": float(np.median(np.abs(z)) / 0.6745)}
                     for figure, z in (("next_session", z_next), ("one_session", z_own))}
    out["tau"] = {k: v["tau"] for k, v in combine(cals, ["exp_1", "exp_2", "exp_3"])
                  .fit["repeatability"].items()}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=400, help="recordings per setting")
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.add_argument("--data", type=Path, default=DATA, help="the real-data folder")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    results = {name: coverage(args.seed + i, args.reps, **options)
               for i, (name, options) in enumerate(SETTINGS.items())}
    mimu = args.data / "mimu4444-array"
    real = across_recordings(mimu) if (mimu / "exp_3.bin").is_file() else None
    if real is not None:
        real["next_session"] = next_session(mimu)
    report = {"reps": args.reps, "seed": args.seed, "settings": results, "mimu4444": real,
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
    if real is not None:
        pose = np.array(real["pose_sigma_ms2"])
        print(f"\nMIMU4444, 8 triads x 3 recordings ({min(real['poses'])}-{max(real['poses'])} "
              f"poses; per-pose term median {np.median(pose):.2g} m/s^2, zero in "
              f"{np.mean(pose == 0):.0%}): spread across recordings / 1-sigma")
        for figure in ("total", "white"):
            print(f"  {figure:>5}: " + ", ".join(f"{c} {real[figure][c]:.2f}" for c in CLASSES))
        nxt = real["next_session"]
        print("  24-channel array, each recording predicted by the other two combined (station "
              "combine): |z| RMS / median ratio")
        for c in ("biases", "scale_factors"):
            print(f"    {c}: next-session figure {nxt[c]['next_session']['rms']:.2f} / "
                  f"{nxt[c]['next_session']['median']:.2f}; one session's 1-sigma "
                  f"{nxt[c]['one_session']['rms']:.2f} / {nxt[c]['one_session']['median']:.2f}")
    print(f"\n{report['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
