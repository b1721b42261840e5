"""Table I of Hwangbo & Kanade: four accelerometers, magnitude constraints only, biases estimated.

Setup (paper Section V): single-axis accelerometers s1, s2, s3 orthogonal and s4 at 45 degrees
between s1 and s3; gains 1 V/g, biases 2.5 V; 20 random orientations x 10 samples; 10-bit style ADC
of 5 V / 2048 counts, Gaussian noise of 0.7 counts per sample, quantised to counts, averaged per
orientation. The linear factorization (quartic case, Eq. 29) and the maximum-likelihood refinement
(station.solve.ml.refine, started from it) are compared over many trials with the paper's columns
and with the Cramer-Rao bound of each invariant (the 1-sigma of `station.calibrate` on the noiseless
readings of the same orientations, noise = per-sample sigma with quantisation, over sqrt(samples)).
Errors are gauge invariant: biases, gains |a_i| and angles between sensor axes.

`--per-sample` feeds the linear factorization the 200 single samples (the paper's "200 gravity
magnitude constraints") instead of the 20 orientation means; ML always refines on the means (a
sufficient statistic). The JSON also gives the Fisher information of one quantised sample about
its mean (`quantised_information`): the exact likelihood of a rounded Gaussian against the
additive model sigma^2 + 1/12 used for the bound.

Usage: .venv/bin/python bench/factorization.py [--trials 1000] [--seed 0] [--per-sample] [--json]
"""

import argparse
import itertools
import json
import sys
import time

import numpy as np
from scipy.stats import norm

from station.solve.calibrate import calibrate
from station.solve.factorization import factorize
from station.solve.ml import refine

VOLTS_PER_COUNT = 5.0 / 2048
SIGMA_COUNTS = 0.7
ORIENTATIONS, SAMPLES = 20, 10
BIAS_VOLTS = 2.5
PAIRS = list(itertools.combinations(range(4), 2))

# Table I of the paper, sigma = 0.7: (linear, nonlinear) per row.
PAPER = {
    "b1": (0.00063, 0.00019), "b2": (0.00079, 0.00035), "b3": (0.00104, 0.00000),
    "b4": (0.00095, -0.00014),
    "|s1|": (0.00173, 0.00021), "|s2|": (0.00123, 0.00029), "|s3|": (0.00141, 0.00012),
    "|s4|": (0.00198, -0.00034),
    "s1s2": (-0.05283, -0.02079), "s1s3": (-0.22175, -0.02585), "s1s4": (-0.04328, 0.00030),
    "s2s3": (-0.16611, -0.02502), "s2s4": (-0.27205, 0.02135), "s3s4": (-0.00955, -0.02103),
}
GROUPS = {"bias (V)": ["b1", "b2", "b3", "b4"], "gain (V/g)": ["|s1|", "|s2|", "|s3|", "|s4|"],
          "angle (deg)": ["s1s2", "s1s3", "s1s4", "s2s3", "s2s4", "s3s4"]}


def true_layout() -> tuple[np.ndarray, np.ndarray]:
    """Sensitivity (3 x 4, V/g) and biases (V) of the simulated unit."""
    a = np.column_stack([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [2 ** -0.5, 0, 2 ** -0.5]])
    return a, np.full(4, BIAS_VOLTS)


SIGMA_AVERAGED = np.sqrt(SIGMA_COUNTS**2 + 1 / 12) / np.sqrt(SAMPLES) * VOLTS_PER_COUNT
"""Noise of an averaged reading (V): Gaussian plus uniform quantisation, over 10 samples."""


def simulate(rng: np.random.Generator, a: np.ndarray, b: np.ndarray) -> tuple:
    """Samples (4 x 20 x 10, volts) at random orientations, noisy and quantised, and the
    noiseless readings of the same orientations (4 x 20)."""
    g = rng.normal(size=(3, ORIENTATIONS))
    g /= np.linalg.norm(g, axis=0)  # gravity direction uniform on the sphere, 1 g
    volts = a.T @ g + b[:, None]
    noise = SIGMA_COUNTS * rng.normal(size=(a.shape[1], ORIENTATIONS, SAMPLES))
    counts = np.clip(np.round(volts[:, :, None] / VOLTS_PER_COUNT + noise), 0, 2047)
    return counts * VOLTS_PER_COUNT, volts


def quantised_information(sigma: float = SIGMA_COUNTS, offsets: int = 64) -> dict:
    """Fisher information (1 / counts^2) of one rounded N(mu, sigma^2) sample about mu, averaged
    over the offset of mu within a count, against the additive model's 1 / (sigma^2 + 1/12) and
    the unquantised 1 / sigma^2."""
    k = np.arange(-12, 13)[:, None]
    mu = (np.arange(offsets) + 0.5) / offsets
    lo, hi = (k - 0.5 - mu) / sigma, (k + 0.5 - mu) / sigma
    p = norm.cdf(hi) - norm.cdf(lo)
    dp = (norm.pdf(lo) - norm.pdf(hi)) / sigma
    exact = np.sum(np.divide(dp**2, p, out=np.zeros_like(p), where=p > 0), axis=0).mean()
    return {"exact": float(exact), "additive": 1 / (sigma**2 + 1 / 12), "unquantised": sigma**-2}


def bound(noiseless: np.ndarray) -> np.ndarray:
    """Cramer-Rao 1-sigma of biases, gains and angles (degrees), order of PAPER."""
    fit = calibrate(noiseless, 1.0, bias="estimate", sigma=SIGMA_AVERAGED)
    i, k = np.array(PAIRS).T
    return np.concatenate([fit.bias_sigma, fit.scale_factors_sigma,
                           np.degrees(fit.axis_angles_sigma[i, k])])


def invariants(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Biases, gains and pairwise axis angles (degrees), in the order of PAPER."""
    gains = np.linalg.norm(a, axis=0)
    unit = a / gains
    angles = [np.degrees(np.arccos(np.clip(unit[:, i] @ unit[:, k], -1, 1))) for i, k in PAIRS]
    return np.concatenate([b, gains, angles])


def table1(trials: int, seed: int, per_sample: bool = False) -> dict:
    """Errors of the linear factorization (on the orientation means, or on every sample with
    `per_sample`) and of the ML refinement over `trials` simulations."""
    a, b = true_layout()
    truth = invariants(a, b)
    rng = np.random.default_rng(seed)
    lin, ml = np.empty((trials, len(truth))), np.empty((trials, len(truth)))
    crlb = np.empty((trials, len(truth)))
    t_lin = t_ml = 0.0
    for t in range(trials):
        samples, noiseless = simulate(rng, a, b)
        readings = samples.mean(axis=2)
        crlb[t] = bound(noiseless)
        t0 = time.perf_counter()
        # magnitude constraints only: quartic, Eq. 29
        fact = factorize(samples.reshape(len(b), -1) if per_sample else readings, magnitude=1.0)
        t1 = time.perf_counter()
        v0 = fact.v.reshape(3, ORIENTATIONS, SAMPLES).mean(axis=2) if per_sample else fact.v
        fit = refine(readings, fact.a, v0, bias0=fact.bias, estimate_bias=True, magnitude=1.0)
        t2 = time.perf_counter()
        t_lin, t_ml = t_lin + t1 - t0, t_ml + t2 - t1
        lin[t] = invariants(fact.a, fact.bias) - truth
        ml[t] = invariants(fit.a, fit.bias) - truth
    rms_lin, rms_ml = np.sqrt(np.mean(lin**2, axis=0)), np.sqrt(np.mean(ml**2, axis=0))
    rms_crlb = np.sqrt(np.mean(crlb**2, axis=0))
    rows = [{"name": name, "truth": float(truth[i]),
             "paper_linear": PAPER[name][0], "paper_nonlinear": PAPER[name][1],
             "linear_rms": float(rms_lin[i]), "linear_mean": float(lin[:, i].mean()),
             "ml_rms": float(rms_ml[i]), "ml_mean": float(ml[:, i].mean()),
             "crlb_rms": float(rms_crlb[i])}
            for i, name in enumerate(PAPER)]
    groups = {}
    for group, names in GROUPS.items():
        idx = [list(PAPER).index(n) for n in names]
        paper = float(np.sqrt(np.mean([PAPER[n][0] ** 2 for n in names])))
        linear, refined, best = (float(np.sqrt(np.mean(r[idx] ** 2)))
                                 for r in (rms_lin, rms_ml, rms_crlb))
        groups[group] = {"paper_linear_rms": paper, "linear_rms": linear, "ml_rms": refined,
                         "crlb_rms": best, "linear_over_paper": linear / paper,
                         "linear_over_ml": linear / refined, "ml_over_crlb": refined / best,
                         "paper_linear_over_ml": paper / refined}
    return {
        "trials": trials, "seed": seed, "linear_input": "samples" if per_sample else "means",
        "quantised_information": quantised_information(),
        "setup": {"orientations": ORIENTATIONS, "samples": SAMPLES, "sigma_counts": SIGMA_COUNTS,
                  "volts_per_count": VOLTS_PER_COUNT, "bias_volts": BIAS_VOLTS},
        "rows": rows, "groups": groups,
        "ms_per_trial": {"linear": 1e3 * t_lin / trials, "ml": 1e3 * t_ml / trials},
        "acceptance": {
            "linear_within_2x_of_paper": all(0.5 <= g["linear_over_paper"] <= 2
                                             for g in groups.values()),
            "ml_3x_better_than_linear": all(g["linear_over_ml"] >= 3 for g in groups.values()),
        },
    }


def _print(result: dict) -> None:
    """Human-readable table: paper columns beside the measured RMS errors."""
    print(f"Hwangbo & Kanade Table I, {result['trials']} trials, seed {result['seed']}, "
          f"sigma {SIGMA_COUNTS} counts/sample, linear on the {result['linear_input']}")
    info = result["quantised_information"]
    print(f"Fisher information of a quantised sample (1/count^2): exact {info['exact']:.4f}, "
          f"additive model {info['additive']:.4f}, unquantised {info['unquantised']:.4f}")
    print(f"{'':6} {'truth':>7} {'paper lin':>10} {'lin RMS':>10} {'lin mean':>10} "
          f"{'paper NL':>10} {'ML RMS':>10} {'ML mean':>10}")
    for r in result["rows"]:
        print(f"{r['name']:6} {r['truth']:7.3f} {r['paper_linear']:10.5f} {r['linear_rms']:10.5f} "
              f"{r['linear_mean']:10.5f} {r['paper_nonlinear']:10.5f} {r['ml_rms']:10.5f} "
              f"{r['ml_mean']:10.5f}")
    print(f"\n{'group':12} {'paper lin':>10} {'lin RMS':>10} {'ML RMS':>10} {'CRLB':>10} "
          f"{'lin/paper':>10} {'lin/ML':>8} {'ML/CRLB':>8}")
    for name, g in result["groups"].items():
        print(f"{name:12} {g['paper_linear_rms']:10.5f} {g['linear_rms']:10.5f} "
              f"{g['ml_rms']:10.5f} {g['crlb_rms']:10.5f} {g['linear_over_paper']:10.2f} "
              f"{g['linear_over_ml']:8.2f} {g['ml_over_crlb']:8.2f}")
    ms = result["ms_per_trial"]
    print(f"\ntime per trial: linear {ms['linear']:.3f} ms, ML {ms['ml']:.3f} ms")
    for name, ok in result["acceptance"].items():
        print(f"{name}: {'yes' if ok else 'NO'}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--per-sample", action="store_true",
                        help="linear factorization on the 200 samples, not the 20 means")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)
    result = table1(args.trials, args.seed, args.per_sample)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        _print(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
