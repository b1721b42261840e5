"""Acceptance statistics of `station diagnose` on free-static sessions (issue 7), and its
findings on the real recordings.

Simulated sessions (20 poses, 4 s still, 2 s turns, 100 Hz, accelerometer triad + gyro; the gyro
of station.sim.static.static_gyro) hide one effect each, or none: per hidden effect, how often the
right effect is named first (and nothing else beside one extra), over seeds; for g_sensitivity
the z-scores of the 9 entries of G against their 1-sigma, for the Earth rates the fitted rate.
Real recordings (when /work/shared, ../shared from the repository, is present): the named
effects, each step's log10 p, the final parameters with 1-sigma, the white-noise gap and the
wall time. Run as `.venv/bin/python -P bench/diagnose_static.py [--json] [--seeds N]
[--no-real]`.
"""

import argparse
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from bench.diagnose import rest_terms
from station.diagnose import quantisation
from station.diagnose.static import CANDIDATES, base, diagnose_static, from_arrays, untestable
from station.diagnose.static_report import load
from station.imports.recordings import import_csv, import_text
from station.model.constants import STANDARD_GRAVITY
from station.model.effects import parse_all
from station.model.frames import eps
from station.report.diagnosis import static_to_dict as to_dict
from station.sim.layouts import accelerometer_triad
from station.sim.noise import simulated_noise
from station.sim.static import simulate_static, static_gyro
from station.solve.uncertainty import crlb

ROOT = Path(__file__).resolve().parents[1]
FS = 100.0
G_TRUE = np.array([[2.0, -1.0, 0.5], [1.0, 3.0, -2.0], [0.0, 1.5, -1.0]]) * 1e-5
"""Hidden g-sensitivity, rad/s per m/s^2 (0.006-0.017 deg/s per g)."""
CASES = {
    "none": ((), (), 2e-3),
    "bias_drift": (("bias_drift=warmup=0.005,warmup_tau=40",), (), 2e-3),
    "scale_nonlinearity": (("scale_nonlinearity=k2=1.5e-4",), (), 2e-3),
    "earth_rate": ((), ("earth_rate=rate=3e-4",), 2e-3),
    "earth_rate_sidereal": ((), ("earth_rate",), 2e-4),
    "g_sensitivity": ((), ("g_sensitivity=matrix=" + ":".join(f"{x:g}" for x in G_TRUE.ravel()),),
                      2e-3),
    "none_coloured": ((), (), 2e-3),
    "outliers_20sigma": (("outliers=rate=2e-3,size=0.2",), (), 2e-3),
    "outliers_40sigma": (("outliers=rate=2e-3,size=0.4",), (), 2e-3),
    "quantised_6sigma": ((), (), 2e-3),
    "quantised_12sigma": ((), (), 2e-3),
    "g_sensitivity_walk": ((), ("g_sensitivity=matrix=" + ":".join(f"{x:g}" for x in
                                                            G_TRUE.ravel()),), 2e-3),
    "none_walk": ((), (), 2e-3),
    "warmup_180s": (("bias_drift=warmup=0.05,warmup_tau=180",), (), 2e-3),
    "pose_bias_1x": ((), (), 2e-3),
    "pose_bias_2.5x": ((), (), 2e-3),
}
"""Case -> (accelerometer effects, gyro effects, gyro sigma per sample in rad/s). The sidereal
Earth rate (7.29e-5 rad/s) is hidden on a gyro 10 x quieter (interval means 1e-5 rad/s). The
outliers (spikes of 0.2 and 0.4 m/s^2 on 0.2 % of the accelerometer's samples) are 20 and 40 x
the accelerometer's noise (0.0098 m/s^2), 2.4 and 4.8 x the detection limit (a spike beyond 8
robust sigma of its neighbours' reference, whose scatter is about 1.05 x the noise)."""
STEP = {"quantised_6sigma": 6.0, "quantised_12sigma": 12.0}
"""Case -> the accelerometer's quantisation step in noise sigmas (0.0098 m/s^2): 2.1 and 4.3 x
the step at which the error a pose's mean keeps (station.diagnose.quantisation.kept) equals the
white noise of a mean of 400 samples (2.8 sigma)."""
POSE_SHIFTS = {"pose_bias_1x": 1e-4, "pose_bias_2.5x": 2.5e-4}
"""Case -> rad/s: the gyro's bias moves at each turn by a normal draw of this standard deviation
per axis (a shock, a cable's pull; issue 32 pattern 5: no law of the orientation): 1 and 2.5 x
the interval means' white noise (1e-4 rad/s), about 1 and 2.5 x the limit of the `gyro` gap
(57 dof). The right call: neither earth_rate nor g_sensitivity named (each fits part of it),
the gap `gyro` unexplained when it is seen."""
COLOURED = {"none_coloured": ((2e-4, 1e-5), (2e-5, 1e-6)),
            **dict.fromkeys(("g_sensitivity_walk", "none_walk"), ((0.0, 1e-4), (0.0, 3e-5)))}
"""Case -> coloured noise added to the (accelerometer, gyro) samples: (bias instability B, random
walk K) (station.sim.noise; docs/noise.md's terms), in m/s^2 and m/s^2/sqrt(s), rad/s and
rad/s/sqrt(s). Added to the accelerometer's quantised output without rounding it again: its white
noise (4 steps) dithers the grid, so a sensor that quantises after all its noise keeps no error in a
mean; rounded again (until session 26) the walk alone was quantised undithered and each pose mean
kept up to half a step of it (0.0012 m/s^2, var step^2 / 12 = 2.5 x the white noise of a pose mean:
the `between` gap read 1.48 on average over 30 effect-free sessions with the walk's own K in the
model, the successive poses' differences 3.5 x the walk's variance), and the flicker, below half a
step, mostly vanished. Flicker floors of 0.7 and 0.07 x the interval means' white noise, random
walks of 0.2 and 0.02 x it over a pose. Issue 32's strong walks (`*_walk`): 1e-4 m/s^2/sqrt(s) and
3e-5 rad/s/sqrt(s), 0.5 and 0.7 x the interval means' noise from one pose to the next and 2-3 x over
the session; its g-sensitivity is 2-3 x its detection limit (white noise: log10 p -17 to -27 on 9
dof). `warmup_180s`: a warm-up of 0.05 m/s^2, tau 180 s beyond the 2-minute session (pattern 2: far
above its limit)."""
REAL = [ROOT.parent / "shared" / "data" / "real", Path("/work/shared/data/real")]


def session(case: str, seed: int, poses: int = 20, still: float = 4.0, move: float = 2.0):
    """(StaticData, truth) of one simulated free-static session hiding `case`: `poses` still
    intervals of `still` s, turns of `move` s between them."""
    acc_fx, gyro_fx, sigma = CASES[case]
    noise = 100e-6 * STANDARD_GRAVITY * np.sqrt(FS)  # accelerometer_triad's, per sample
    coarse = {"counts_per_unit": 1 / (STEP[case] * noise)} if case in STEP else {}
    unit = accelerometer_triad(np.random.default_rng(seed), fs=FS, **coarse)
    sim = simulate_static(unit, poses, still, move, effects=parse_all(list(acc_fx)))
    lsb = sim.arrays["lsb"]
    acc = sim.arrays["y"][0] * lsb
    rng = np.random.default_rng(seed + 1000)
    gyro = static_gyro(sim.truth, len(acc), rng, sigma=sigma, effects=parse_all(list(gyro_fx)))
    for a, z in sim.truth["still"] if case in POSE_SHIFTS else ():
        gyro[a:z] += POSE_SHIFTS[case] * rng.standard_normal(3)
    if case in COLOURED:
        (b_acc, k_acc), (b_gyro, k_gyro) = COLOURED[case]
        acc = acc + coloured(acc.shape, b_acc, k_acc, rng)  # not rounded again (`COLOURED`)
        gyro = gyro + coloured(gyro.shape, b_gyro, k_gyro, rng)
    n = round(still * FS)
    kept = quantisation.kept(unit.sigma, unit.lsb)
    truth = {**sim.truth, "sigma_mean": np.sqrt((unit.sigma**2 + unit.lsb**2 / 12 - kept) / n
                                                + kept)}
    return from_arrays(acc, FS, gyro=gyro, gravity=sim.truth["gravity"]), truth


def coloured(shape: tuple, bias_instability: float, random_walk: float, rng) -> np.ndarray:
    """(K, c) flicker and random walk, independent per channel (station.sim.noise)."""
    return np.stack([simulated_noise(shape[0], FS, bias_instability=bias_instability,
                                     random_walk=random_walk, rng=rng)
                     for _ in range(shape[1])], 1)


def calibration_errors(result, truth: dict) -> dict:
    """eps (Eq. 19) of the accelerometer calibration before (the nominal one) and after the
    diagnosis, the bound sqrt(trace(CRLB)) of the poses' interval means with the unit's white and
    quantisation noise (the part a mean keeps, station.diagnose.quantisation), and 1 sd of eps
    at the bound."""
    a, v = np.asarray(truth["a"]), np.asarray(truth["v"])
    cov = crlb(a, v, truth["sigma_mean"], estimate_bias=True)
    bound = float(np.sqrt(np.trace(cov)))
    before, after = result.steps[0].model.calibration, result.calibration
    return {"eps_before": eps(a, before.a), "eps_after": eps(a, after.a), "bound": bound,
            # eps^2 = |e|^2, e ~ N(0, C): var 2 tr C^2, d eps = d(eps^2) / 2 eps
            "eps_sd_at_bound": float(np.sqrt(2 * np.trace(cov @ cov)) / (2 * bound))}


def rest_noise(case: str, seed: int, m: int = 3) -> dict:
    """{term: (c,)} the coloured noise of a session's unit from a rest recording of each stream
    (bench/diagnose.py's `rest_terms`): a term a stream's fit resolves for every channel, 0 on the
    other stream's channels; {} when neither resolves any (a calibration file holds no other)."""
    (b_acc, k_acc), (b_gyro, k_gyro) = COLOURED.get(case, ((0.0, 0.0), (0.0, 0.0)))
    rng = np.random.default_rng([seed, 17])
    streams = [(100e-6 * STANDARD_GRAVITY, b_acc, k_acc, m),
               (CASES[case][2] / np.sqrt(FS), b_gyro, k_gyro, 3)]
    found = [(channels, rest_terms(channels, FS, white, b, k, rng))
             for white, b, k, channels in streams]
    out = {t: np.concatenate([terms.get(t, np.zeros(channels)) for channels, terms in found])
           for t in ("bias_instability", "random_walk")}
    return {t: v for t, v in out.items() if np.any(v)}


def run_case(case: str, seed: int, leave_out: bool = False, noise_model: bool = False) -> dict:
    """Diagnose one session: named effects, verdict, first-step evidence, G z-scores, Earth
    rate; leave_out: the hidden effect is removed from the candidates too; noise_model: the
    unit's coloured noise from a rest recording (`rest_noise`) is in the noise model."""
    data, truth = session(case, seed)
    if noise_model:
        data = replace(data, **rest_noise(case, seed, data.m))
    start = time.perf_counter()
    hidden = HIDDEN[case]
    result = diagnose_static(data, candidates=tuple(
        c for c in CANDIDATES if c not in untestable(data, base(data))
        and not (leave_out and c == hidden)))
    out = {"named": result.effects, "seconds": time.perf_counter() - start,
           "ambiguous": [g["effects"] for g in result.ambiguous],
           "not_named": [p["effect"] for p in result.not_named], "closes": result.closes,
           "drift_or_walk": bool(result.caveats),
           "unexplained": [u["statistic"] for u in result.unexplained],
           "resembles": [r["effect"] for r in result.resembles],
           "log10_p_first": {k: e["log10_p"] for k, e in result.steps[0].evidence.items()},
           "intervals": len(data.intervals), "outliers": data.outlier_test(result.alpha),
           "quantised": bool(data.quantisation()["coarse"].any()),
           **calibration_errors(result, truth)}
    fitted = result.final.fitted
    if "g_sensitivity" in fitted:
        f = fitted["g_sensitivity"]
        out["G_z"] = ((f.value("G") - G_TRUE) / f.sigma["G"]).tolist()
    if "earth_rate" in fitted:
        f = fitted["earth_rate"]
        out["earth_rate"] = (float(f.values["rate"]), float(f.sigma["rate"]))
    return out


HIDDEN = {"none": "none", "bias_drift": "bias_drift", "scale_nonlinearity": "scale_nonlinearity",
          **dict.fromkeys(STEP, "quantised"), "earth_rate": "earth_rate",
          "earth_rate_sidereal": "earth_rate", "g_sensitivity": "g_sensitivity",
          "none_coloured": "none", "outliers_20sigma": "outliers", "outliers_40sigma": "outliers",
          "g_sensitivity_walk": "g_sensitivity", "none_walk": "none", "warmup_180s": "bias_drift",
          **dict.fromkeys(POSE_SHIFTS, "pose_bias")}
"""Case -> the effect it hides (outliers, quantised: the samples' law, reported beside the named
effects)."""


def expected(case: str) -> str:
    """The right call: the hidden effect, except for 4 x the Earth's rate (`earth_rate`), which
    no physics allows: its right call is anything but earth_rate (station.diagnose.
    plausibility); its vertical part is a diagonal g-sensitivity, so that name is right too. A
    bias moving from pose to pose (`POSE_SHIFTS`, no name in the library): no gyro law named."""
    return "not earth_rate" if case == "earth_rate" else HIDDEN[case]


def _right(want: str, r: dict) -> bool:
    """Whether a run's verdict is the right one for `want` (see `expected`)."""
    first = r["named"][0] if r["named"] else "none"
    if r["outliers"]["detected"] != (want == "outliers") or r["quantised"] != (
            want == "quantised"):
        return False
    if want in ("outliers", "quantised"):
        return not r["named"] and not r["unexplained"]
    if want == "not earth_rate":
        return "earth_rate" not in r["named"]
    if want == "pose_bias":  # outside the library: no gyro law named for it
        return not {"earth_rate", "g_sensitivity"} & set(r["named"])
    if want == "none":
        return first == "none" and not r["unexplained"]
    return first == want and len(r["named"]) <= 2


def acceptance(seeds: int, cases=tuple(CASES), leave_out: bool = False,
               noise_model: bool = False) -> dict:
    """Per case: rate of the right call over `seeds` seeds, the verdict counts, and the runs;
    leave_out: the hidden effect is removed from the candidates (right: `unexplained` with no
    name)."""
    out = {}
    for case in cases:
        runs = [run_case(case, 100 + s, leave_out, noise_model) for s in range(seeds)]
        want = expected(case)
        right = [_right(want, r) for r in runs]
        entry = {"sessions": len(runs), "right_rate": float(np.mean(right)),
                 "verdicts": {
                     "unexplained_unnamed": sum(not r["named"] and bool(r["unexplained"])
                                                for r in runs),
                     "wrong_name": sum(bool(r["named"]) and not _right(want, r) for r in runs),
                     "silent": sum(not r["named"] and not r["unexplained"] for r in runs),
                     "ambiguous_with_it": sum(not r["named"] and any(
                         HIDDEN[case] in g for g in r["ambiguous"]) for r in runs),
                     "out_of_range_not_named": sum(bool(r["resembles"]) for r in runs)},
                 "unexplained": [r["unexplained"] for r in runs],
                 "resembles": [r["resembles"] for r in runs],
                 "exact_rate": float(np.mean([r["named"] == ([] if want == "none" else [want])
                                              for r in runs])),
                 "named": [r["named"] for r in runs],
                 "ambiguous": [r["ambiguous"] for r in runs],
                 "not_named": [r["not_named"] for r in runs],
                 "closes": [r["closes"] for r in runs],
                 "seconds_median": float(np.median([r["seconds"] for r in runs]))}
        z = [np.abs(r["G_z"]).max() for r in runs if "G_z" in r]
        if z:
            entry["G_max_abs_z"] = [float(x) for x in z]
        rates = [r["earth_rate"] for r in runs if "earth_rate" in r]
        if rates:
            entry["earth_rate_fitted"] = rates
        entry["log10_p_first"] = [r["log10_p_first"] for r in runs]
        entry["outliers_detected"] = sum(r["outliers"]["detected"] for r in runs)
        entry["quantised_reported"] = sum(r["quantised"] for r in runs)
        entry["drift_or_walk_said"] = sum(r["drift_or_walk"] for r in runs)
        entry["outlier_rate"] = [float(r["outliers"]["rate"].max()) for r in runs]
        entry["intervals"] = [r["intervals"] for r in runs]
        entry["eps_before_over_bound"] = [r["eps_before"] / r["bound"] for r in runs]
        entry["eps_after_over_bound"] = [r["eps_after"] / r["bound"] for r in runs]
        entry["worse_by_more_than_1sd"] = sum(r["eps_after"] > r["eps_before"]
                                              + r["eps_sd_at_bound"] for r in runs)
        out[case] = entry
    return out


SPEED = {"poses": 40, "still": 12.0, "move": 3.0}
"""The speed session of issue 21: 40 poses in 10 min at 100 Hz, accelerometer triad + gyro."""


SPEED_CASES = ("none", "bias_drift", "g_sensitivity")
"""Effect-free, and hiding effects that the loop names in one or more steps."""


def speed(seeds: int) -> dict:
    """Wall time of `diagnose_static` (every candidate) on 10-minute sessions of 40 poses, 6
    channels at 100 Hz, beside its baseline in the same run: the calibration without effects
    that the diagnosis starts from (`station.diagnose.static.base`), best of 3."""
    runs = []
    for case in SPEED_CASES:
        for s in range(seeds):
            data, _ = session(case, 300 + s, **SPEED)
            base_s = min(_timed(base, data)[1] for _ in range(3))
            result, seconds = _timed(diagnose_static, data)
            runs.append({"case": case, "samples": int(data.x.shape[0]), "channels": data.c,
                         "diagnose_s": seconds, "baseline_s": base_s, "named": result.effects})
    return {**SPEED, "fs": FS, "limit_s": 60.0, "runs": runs}


def _timed(f, *args):
    """(f(*args), wall seconds)."""
    start = time.perf_counter()
    out = f(*args)
    return out, time.perf_counter() - start


def recordings(root: Path, tmp: Path) -> dict:
    """{unit: session file} of the three real recordings imported into sessions."""
    xs = root / "imutk-xsens"
    out = {"xsens": import_text(tmp / "xsens.h5", {"accel": xs / "xsens_acc.mat",
                                                   "gyro": xs / "xsens_gyro.mat"},
                                {"accel": "counts:m/s^2", "gyro": "counts:rad/s"})}
    x = np.loadtxt(root / "imucalib-mpu9150x5" / "imu0.log")  # no time column: 100 Hz
    t = np.arange(len(x)) / 100.0
    for name, cols in (("acc", x[:, :3]), ("gyr", x[:, 3:])):
        np.savetxt(tmp / f"{name}.txt", np.column_stack([t, cols]), fmt="%.8g")
    out["mpu9150_imu0"] = import_text(tmp / "mpu.h5", {"acc": tmp / "acc.txt",
                                                       "gyr": tmp / "gyr.txt"},
                                      {"acc": "m/s^2", "gyr": "rad/s"}, fs=100.0)
    out["imucal_ferraris"] = import_csv(
        tmp / "ferraris.h5", root / "imucal-ferraris" / "example_ferraris_session.csv",
        {"acc": ["acc_x", "acc_y", "acc_z"], "gyr": ["gyr_x", "gyr_y", "gyr_z"]},
        {"acc": "m/s^2", "gyr": "deg/s"}, index_column="n_samples", fs=102.4)
    return out


def real() -> dict | None:
    """Findings of the free-static diagnose on the real recordings, or None without them."""
    root = next((r for r in REAL if r.is_dir()), None)
    if root is None:
        return None
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for unit, path in recordings(root, Path(tmp)).items():
            data = load(path)
            start = time.perf_counter()
            result = diagnose_static(data)
            seconds = time.perf_counter() - start
            doc = to_dict(result, data, unit)
            out[unit] = {
                "seconds": seconds,
                "intervals": doc["intervals"],
                "effects": doc["effects"],
                "steps": [{"chosen": s["chosen"],
                           "log10_p": {k: e["log10_p"] for k, e in s["evidence"].items()},
                           "log10_p_quasi": {k: e["log10_p_quasi"]
                                             for k, e in s["evidence"].items()}}
                          for s in doc["steps"]],
                "parameters": doc["steps"][-1]["parameters"],
                "unexplained": [{k: u[k] for k in ("statistic", "gap", "dof", "log10_p")}
                                for u in doc["unexplained"]],
                "resembles": doc["resembles"],
                "white_noise_within": doc["white_noise"]["within"],
                "white_noise_holds": doc["white_noise"]["holds"],
                "caveats": list(result.caveats),
                "correction": result.correction,
            }
    return out


def show(out: dict) -> None:
    for case, r in out["acceptance"].items():
        extra = ""
        if "G_max_abs_z" in r:
            extra += f"  max|z| of G {np.round(r['G_max_abs_z'], 2).tolist()}"
        if "earth_rate_fitted" in r:
            extra += "  rate " + ", ".join(f"{v:.2e}+-{s:.1e}" for v, s in r["earth_rate_fitted"])
        print(f"{case:20s} right {r['right_rate']:.2f} (exact {r['exact_rate']:.2f}) of "
              f"{r['sessions']}  {r['seconds_median']:.1f} s{extra}  {r['verdicts']}")
        print(f"{'':20s} quantised {r['quantised_reported']}, bias_drift 'may be a walk' "
              f"{r['drift_or_walk_said']}, outliers reported "
              f"{r['outliers_detected']} (largest rate "
              f"{max(r['outlier_rate']):.2%}), poses {min(r['intervals'])}-"
              f"{max(r['intervals'])}, eps/bound before "
              f"{np.round(r['eps_before_over_bound'], 2).tolist()} after max "
              f"{max(r['eps_after_over_bound']):.2f}, worse by > 1 sd: "
              f"{r['worse_by_more_than_1sd']}")
    for case, r in out.get("leave_one_effect_out", {}).items():
        print(f"left out {case:20s} {r['verdicts']}")
    if "speed" in out:
        sp = out["speed"]
        for r in sp["runs"]:
            print(f"speed, {r['case']}: {sp['poses']} poses, {r['samples']} samples x "
                  f"{r['channels']} channels: diagnose {r['diagnose_s']:.1f} s (limit "
                  f"{sp['limit_s']:.0f} s), baseline "
                  f"calibration {r['baseline_s']:.2f} s, named {r['named']}")
    for unit, r in (out.get("real") or {}).items():
        print(f"\n{unit}: {r['effects']}  ({r['intervals']} intervals, {r['seconds']:.1f} s, "
              f"within gap {r['white_noise_within']:.2f})")
        print("   unexplained", [(u["statistic"], round(u["gap"], 2)) for u in r["unexplained"]],
              " resembles", [(x["effect"], x["reason"]) for x in r["resembles"]])
        for s in r["steps"]:
            print("  ", s["chosen"], {k: round(v, 1) for k, v in s["log10_p"].items()})
        for name, params in r["parameters"].items():
            for k, v in params.items():
                print(f"    {name}.{k} = {np.round(v['value'], 6).tolist()} "
                      f"+- {np.round(v['sigma'], 6).tolist() if v['sigma'] is not None else None}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--seeds", type=int, default=4, help="sessions per hidden effect")
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    parser.add_argument("--no-real", action="store_true", help="skip the real recordings")
    parser.add_argument("--noise-model", action="store_true",
                        help="the unit's bias random walk and flicker, from the Allan fit of a "
                        "rest recording of each stream (rest_noise), in the noise model")
    parser.add_argument("--leave-one-out", action="store_true",
                        help="also hide each effect AND remove it from the candidates")
    parser.add_argument("--speed", action="store_true",
                        help="also time the diagnosis of 10-minute sessions of 40 poses")
    args = parser.parse_args()
    out = {"acceptance": acceptance(args.seeds, args.cases, noise_model=args.noise_model)}
    if args.speed:
        out["speed"] = speed(args.seeds)
    if args.leave_one_out:
        out["leave_one_effect_out"] = acceptance(
            args.seeds, [c for c in args.cases if c not in ("none", "earth_rate")], True)
    if not args.no_real:
        out["real"] = real()
    if args.json:
        print(json.dumps(out, indent=1, default=float))
    else:
        show(out)


if __name__ == "__main__":
    main()
