"""Does the 1-sigma "for the next session" cover the next session? Leave-one-out over the MIMU4444
array's recordings (../shared/data/real/mimu4444-array/exp_*.bin; issue 31).

Each recording is imported (`station import binary`, profile mimu4444) and each of the 8 IMUs'
accelerometer triads solved on its still poses the command line's way (`station solve
--channels imuK_ax,imuK_ay,imuK_az --magnitude 9.81 --accept-suspect`: `solve_session`). For every
recording held out and every IMU, the other recordings' files are combined (`station combine`:
`station.calfiles.combined.combine`) and the held-out recording's estimates x checked against them:

- "combined": z = (x - mean) / sqrt(sigma_next^2 + s^2), sigma_next the combined file's 1-sigma
  for the next session, s the held-out session's own 1-sigma (its estimation noise);
- "solve --repeatability": z = (x - mean) / sqrt(sigma^2 + mean_sigma^2), sigma the held-out
  session's 1-sigma with the combined file's repeatability (`with_repeatability`), mean_sigma the
  combined mean's own (tau left out: it is in sigma already).

z RMS about 1 when the figures are honest (within [0.7, 1.4] for 24 parameters x 3 held-out
recordings of a class; below 1 when the sessions agree within their noise: a tau that does not
collapse over-covers then, 0.66 for simulated triads from two sessions without spread). Also
printed: every combined file's tau of the biases and scale factors
and the sessions it rests on (a tau of 0 would be a variance taken as known at its boundary).

    .venv/bin/python -P bench/next_session.py [--json] [--data DIR]
"""

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "mimu4444-array"
if not DATA.exists():  # a worktree outside /work
    DATA = Path("/work/shared/data/real/mimu4444-array")
IMUS = 8
G = 9.81  # the authors' local gravity (PROVENANCE.md)
CLASSES = {"biases": ("bias", "bias_sigma"),
           "scale_factors": ("scale_factors", "scale_factors_sigma")}


def calibrations(root: Path, tmp: Path) -> list:
    """[recording][imu] the calibration files' content (`station.calfiles.calfile.Calibration`) of
    each IMU's accelerometer triad in each recording exp_*.bin, solved as `station solve` does."""
    from station.commands.solve import solve_session
    from station.imports.recordings import import_binary

    out = []
    for dump in sorted(root.glob("exp_*.bin")):
        h5 = import_binary(tmp / f"{dump.stem}.h5", dump, "mimu4444")
        out.append([solve_session(h5, magnitude=G, accept_suspect=True,
                                  channels=tuple(f"imu{k}_a{x}" for x in "xyz"))
                    for k in range(IMUS)])
    return out


def leave_one_out(cals: list) -> dict:
    """z of every held-out recording against the others combined (module docstring), per class
    and figure; the combined files' taus and session counts."""
    from station.calfiles.combined import combine, with_repeatability

    z = {(c, f): [] for c in CLASSES for f in ("combined", "solve_repeatability")}
    taus = []
    for held in range(len(cals)):
        rest = [k for k in range(len(cals)) if k != held]
        for imu in range(IMUS):
            pooled = combine([cals[k][imu] for k in rest], [f"exp_{k + 1}" for k in rest])
            digest = hashlib.sha256(pooled.dumps().encode()).hexdigest()
            honest = with_repeatability(cals[held][imu], [(pooled, "combined", digest)])
            taus.append({"held_out": held + 1, "imu": imu, "sessions": len(rest),
                         **{c: pooled.fit["repeatability"][value]["tau"]
                            for c, (value, _) in CLASSES.items()}})
            for c, (value, sigma) in CLASSES.items():
                diff = getattr(cals[held][imu], value) - getattr(pooled, value)
                own = getattr(cals[held][imu], sigma)
                z[c, "combined"].append(diff / np.hypot(getattr(pooled, sigma), own))
                mean_sigma = pooled.fit["repeatability"][value]["mean_sigma"]
                z[c, "solve_repeatability"].append(
                    diff / np.hypot(getattr(honest, sigma), mean_sigma))
    rms = {f"{c} {f}": float(np.sqrt(np.mean(np.square(v)))) for (c, f), v in z.items()}
    return {"z_rms": rms, "taus": taus,
            "zero_taus": sum(t[c] == 0 for t in taus for c in CLASSES)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.add_argument("--data", type=Path, default=DATA, help="the mimu4444-array folder")
    args = parser.parse_args(argv)
    if not (args.data / "exp_2.bin").is_file():
        print(f"no recordings in {args.data}: nothing to measure", file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory() as tmp:
        cals = calibrations(args.data, Path(tmp))
    report = {"recordings": len(cals), "imus": IMUS, **leave_one_out(cals)}
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"{report['recordings']} recordings x {IMUS} IMUs, each recording held out in turn "
          "against the others combined: z RMS (honest: about 1)")
    for key, value in report["z_rms"].items():
        print(f"  {key}: {value:.2f}")
    taus = report["taus"]
    for c in CLASSES:
        values = np.array([t[c] for t in taus])
        print(f"  tau of the {c.replace('_', ' ')}: median {np.median(values):.3g}, min "
              f"{values.min():.3g} (zero in {np.sum(values == 0)} of {len(values)} combined "
              f"files of {taus[0]['sessions']} sessions)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
