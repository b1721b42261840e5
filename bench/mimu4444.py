"""The MIMU4444BT array's raw packet dumps (../shared/data/real/mimu4444-array/exp_*.bin) through
`station import binary` (the drivers' frame parser, profile drivers/profiles/mimu4444.toml).

Prints, per file: packets decoded, bad packet candidates, resyncs, missing packet numbers, unused
bytes, duration and sample rate from the 64 MHz stamps, and over the still poses found by
station.reduce.stillness: the mean |acc| of each IMU (about 9.8 m/s^2 if the decode is right) and
the mean gyro reading (biases, near 0).

Then the calibrations (issue 14), through the command line's own path (the `import` kind's
still poses, found on the accelerometers, and `calibrate_still`, as `station solve` does), for
the 24 accelerometer channels as one redundant array and for each IMU's triad:
- poses found per recording, chi2/dof, the per-pose error term;
- leave-one-pose-out |a| - g RMS (each pose predicted by the fit on the others);
- each recording's calibration applied to the other two recordings' poses (|a| - g RMS);
- the spread of each triad's scale factors and biases over the three recordings against their
  reported 1-sigma (total and white-noise figures): median ratio, 1 = honest;
- the same ratio with ONE session's figure valid across recordings, without circularity: for
  each recording k, the other two recordings' calibrations combined (`station combine`'s
  `combine`, tau from them only), recording k's calibration given their repeatability
  (`with_repeatability`, what `station solve --repeatability` does), and the spread over the
  three recordings divided by recording k's 1-sigma (per held-out k, and with the mean of the
  three held-out 1-sigma as the figures above use). Tau from 2 recordings rests on 1 dof per
  parameter, pooled over the class (3 for a triad's biases): the figure is widened for it
  (t quantile), and it scatters by itself - read it as honest within the band [0.5, 2], not to
  the second digit;
- the same with the taus of the array's 8 IMUs pooled (one model: `station solve
  --repeatability` of the 8 IMUs' combined files of the other two recordings; 24 dof per class,
  widened by at most 1.05);
- unless --quick: the 24-channel array on the command line: `station solve exp_k.h5
  --repeatability` of `station combine` of the other two, the same ratio over the 24 biases and
  scale factors.

    .venv/bin/python bench/mimu4444.py [--json] [--data DIR] [--quick]
"""

import argparse
import dataclasses
import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from station.imports.recordings import import_binary
from station.reduce.stillness import detect_still
from station.session import Session

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "mimu4444-array"
if not DATA.exists():  # a worktree outside /work
    DATA = Path("/work/shared/data/real/mimu4444-array")
IMUS = 8
G = 9.81  # the authors' local gravity (PROVENANCE.md)


def figures(dump: Path, tmp: Path) -> dict:
    """The figures of one dump (see the module docstring)."""
    out = import_binary(tmp / f"{dump.stem}.h5", dump, "mimu4444")
    with Session.open(out) as s:
        link = s.metadata["import"]["link"]
        data = s.stream("imu")
    x = data.to_si()
    still = detect_still(x, data.spec.rate_hz)
    rest = np.zeros(len(x), bool)
    for start, stop in still.intervals:
        rest[start:stop] = True
    per_imu = x[rest].reshape(-1, IMUS, 6)
    acc_norm = np.linalg.norm(per_imu[:, :, :3], axis=2)
    return {
        "packets": link["frames"], "bad_packets": link["bad_frames"],
        "resyncs": link["resyncs"], "missing_packet_numbers": link["dropped"],
        "unused_bytes": link["unused_bytes"], "duration_s": round(link["duration_s"], 3),
        "rate_hz_from_stamps": round(link["rate_hz"], 4),
        "still_poses": len(still.intervals), "still_s": round(rest.sum() / data.spec.rate_hz, 1),
        "acc_norm_mean_m_s2": np.round(acc_norm.mean(axis=0), 3).tolist(),
        "acc_norm_sd_over_poses_m_s2": np.round(acc_norm.std(axis=0), 3).tolist(),
        "gyro_mean_deg_s": np.round(np.degrees(per_imu[:, :, 3:].mean(axis=0)), 2).tolist(),
    }


def calibrations(sessions: dict) -> dict:
    """The calibration figures of the module docstring, from imported sessions {name: path}."""
    from station.reduce.free_static import leave_one_out
    from station.reduce.imported import imported_readings
    from station.solve.still import calibrate_still

    readings = {}
    for name, path in sessions.items():
        with Session.open(path) as s:
            readings[name] = imported_readings(s, "imu")
    out = {"poses": {n: int(r.M.shape[1]) for n, r in readings.items()}, "array": {},
           "per_imu": {}}
    lot = {}
    for label, rows in [("array", slice(None))] + [(f"imu{i}", slice(3 * i, 3 * i + 3))
                                                   for i in range(IMUS)]:
        fits = {n: calibrate_still(_rows(r, rows), G) for n, r in readings.items()}
        held = {n: leave_one_out(_rows(r, rows).M, G, sigma=_rows(r, rows).sigma)
                for n, r in readings.items()}
        cross = {f"{a}->{b}": _rms(np.linalg.norm(fits[a].apply(_rows(readings[b], rows).M),
                                                  axis=0) - G)
                 for a in readings for b in readings if a != b}
        figures = {"chi2_per_dof": {n: round(f.chi2 / f.dof, 2) for n, f in fits.items()},
                   "pose_sigma_m_s2": {n: f.pose_sigma for n, f in fits.items()},
                   "loo_rms_m_s2": {n: _rms(h) for n, h in held.items()},
                   "loo_refused": {n: len(h.refused) for n, h in held.items()},
                   "applied_to_others_rms_m_s2": cross}
        if label != "array":
            figures["spread_over_sigma"] = _spread(list(fits.values()))
            figures["with_repeatability"] = _with_repeatability(fits, label)
            lot[label] = fits
        (out["array"] if label == "array" else out["per_imu"]).update(
            figures if label == "array" else {label: figures})
    for label, fits in lot.items():
        out["per_imu"][label]["with_lot_repeatability"] = _with_repeatability(fits, label, lot)
    per = out["per_imu"].values()
    out["median_spread_over_sigma"] = {
        f"{what} {fig}": float(np.median([p["spread_over_sigma"][fig][what] for p in per]))
        for what in ("scale_factors", "biases") for fig in ("total", "white")}
    out["median_spread_over_sigma_with_repeatability"] = {
        f"{what} {held}": float(np.median([p["with_repeatability"][held][what] for p in per]))
        for what in ("scale_factors", "biases")
        for held in [*readings, "mean", *(f"{n} unwidened" for n in [*readings, "mean"])]}
    out["median_spread_over_sigma_with_lot_repeatability"] = {
        f"{what} {held}": float(np.median([p["with_lot_repeatability"][held][what] for p in per]))
        for what in ("scale_factors", "biases") for held in [*readings, "mean"]}
    return out


def _with_repeatability(fits: dict, label: str, lot: dict | None = None) -> dict:
    """{held-out recording or "mean": {"scale_factors", "biases": median over the three axes of
    the spread over the recordings / the held-out recording's 1-sigma with the repeatability of
    the other two combined}} ("mean": over the mean of the three held-out 1-sigma, as _spread);
    "unwidened": the same with each 1-sigma divided by its t widening (tau of a triad's class
    rests on 3 dof: t_3(0.975) / 1.96 = 1.6 when tau dominates). `lot` ({label: fits} of every
    IMU): the taus of the other two recordings pooled over all the array's IMUs, one model
    (`station solve --repeatability` of the 8 combined files; 24 dof per class)."""
    from station.calfiles.combined import INCLUDED, combine, with_repeatability

    cals = _cals(fits, label)
    lots = {k: _cals(f, k) for k, f in (lot or {label: fits}).items()}
    honest = {}
    for held in cals:
        rest = [n for n in cals if n != held]
        sources = []
        for k, unit in lots.items():
            pooled = combine([unit[n] for n in rest], rest)
            sources.append((pooled, f"{k}:{'+'.join(rest)}",
                            hashlib.sha256(pooled.dumps().encode()).hexdigest()))
        honest[held] = with_repeatability(cals[held], sources)
    out = {}
    for what, value, sigma in (("scale_factors", "scale_factors", "scale_factors_sigma"),
                               ("biases", "bias", "bias_sigma")):
        sd = np.array([getattr(c, value) for c in cals.values()]).std(axis=0, ddof=1)
        key = "bias" if what == "biases" else what
        for widened in (True, False):
            sigmas = {n: getattr(c, sigma) / (1 if widened else c.fit[INCLUDED]["widening"][key])
                      for n, c in honest.items()}
            sigmas["mean"] = np.mean(list(sigmas.values()), axis=0)
            for held, s in sigmas.items():
                out.setdefault(held if widened else f"{held} unwidened", {})[what] = float(
                    np.median(sd / s))
    return out


def _cals(fits: dict, label: str) -> dict:
    """{recording: the calibration file content of one IMU's fit}."""
    from station.calfiles.calfile import Calibration

    return {n: Calibration.from_result(f, "MIMU4444", [f"{label}_a{c}" for c in "xyz"], "m/s^2",
                                       session={"stream": "imu"}) for n, f in fits.items()}


def array_on_the_command_line(sessions: dict, tmp: Path) -> dict:
    """The 24-channel array through `station solve` / `station combine` / `station solve
    --repeatability` (subprocesses): per held-out recording, the median over the 24 channels of
    the spread over the three recordings / that recording's 1-sigma, without and with the
    repeatability of the other two; and the taus of the combination."""
    from station.calfiles.calfile import load

    def station(*argv):
        subprocess.run([sys.executable, "-m", "station", *map(str, argv)], check=True,
                       capture_output=True)

    own = {}
    for name, h5 in sessions.items():
        station("solve", h5, "--magnitude", G, "--accept-suspect", "--force")
        own[name] = load(h5.with_suffix(".cal.json"))
    out = {}
    for held, h5 in sessions.items():
        rest = [n for n in sessions if n != held]
        combined = tmp / f"without_{held}.cal.json"
        subprocess.run([sys.executable, "-m", "station", "combine",
                        *(str(sessions[n].with_suffix(".cal.json")) for n in rest),
                        "--out", str(combined), "--force"], capture_output=True)  # 1: suspect
        honest_path = tmp / f"{held}.honest.cal.json"
        station("solve", h5, "--magnitude", G, "--accept-suspect", "--force", "--repeatability",
                combined, "--out", honest_path)
        honest = load(honest_path)
        row = {"tau": honest.fit["repeatability_included"]["tau"]}
        for what, value, sigma in (("scale_factors", "scale_factors", "scale_factors_sigma"),
                                   ("biases", "bias", "bias_sigma")):
            sd = np.array([getattr(c, value) for c in own.values()]).std(axis=0, ddof=1)
            row[what] = {"one_session": float(np.median(sd / getattr(own[held], sigma))),
                         "with_repeatability": float(np.median(sd / getattr(honest, sigma)))}
        out[held] = row
    return out


def _rows(readings, rows):
    """The readings of some channels (a triad) of `readings`."""
    return dataclasses.replace(readings, M=readings.M[rows], sigma=readings.sigma[rows])


def _rms(x) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.nanmean(x ** 2)))


def _spread(fits: list) -> dict:
    """Sample SD over the recordings of each scale factor and bias, over their mean reported
    1-sigma (total and white); the median over the three axes."""
    out = {"total": {}, "white": {}}
    for what, value, total, white in (
            ("scale_factors", "scale_factors", "scale_factors_sigma",
             "scale_factors_sigma_white"),
            ("biases", "bias", "bias_sigma", "bias_sigma_white")):
        x = np.array([getattr(f, value) for f in fits])
        sd = x.std(axis=0, ddof=1)
        for fig, attr in (("total", total), ("white", white)):
            sigma = np.array([getattr(f, attr) for f in fits]).mean(axis=0)
            out[fig][what] = float(np.median(sd / sigma))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="one JSON object")
    parser.add_argument("--data", type=Path, default=DATA, help="the mimu4444-array folder")
    parser.add_argument("--quick", action="store_true",
                        help="leave out the 24-channel array on the command line")
    args = parser.parse_args(argv)
    dumps = sorted(args.data.glob("exp_*.bin"))
    if not dumps:
        print(f"no exp_*.bin in {args.data}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        result = {d.name: figures(d, Path(tmp)) for d in dumps}
        sessions = {d.stem: Path(tmp) / f"{d.stem}.h5" for d in dumps}
        result["calibrations"] = calibrations(sessions)
        if not args.quick:
            result["array_command_line"] = array_on_the_command_line(sessions, Path(tmp))
    if args.json:
        print(json.dumps(result))
    else:
        for name, f in result.items():
            print(name)
            for key, value in f.items():
                print(f"  {key}: {json.dumps(value)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
