"""Noise characterisation (issue 19): do the fitted N, B, K lie within their reported bands?

- coverage : --seeds simulated static streams (station.sim.noise: white noise of density N,
             Kasdin-Walter flicker of bias instability B, random walk K; 100 Hz, 2^20 samples =
             2.9 h) with N = 2e-4 u sqrt(s), B = 2e-4 u, K = 2e-5 u/sqrt(s)
             (white noise dominates below 2.3 s, the random walk above 132 s). Per term the
             fraction of seeds whose fit lies within +-2 sigma of the true value (nominal 95.4 %;
             a term left unresolved counts as a miss), within +-1 sigma (nominal 68.3 %), and the
             spread of the z-scores (fit - true) / sigma (1 for an honest sigma).
             Target: >= 90 % within 2 sigma for each term, and not above 99 % (an honest band).
- baseline : in the same run, the textbook slope-line readings (IEEE 952 C.1, El-Sheimy et al.
             2008): N = Allan deviation at tau = 1 s, K = Allan deviation at tau = 3 s (the +1/2
             line reads K there), B = the minimum of the Allan deviation (octaves) /
             sqrt(2 ln 2 / pi); their relative RMS error against the fit's.
- scale    : wall time and peak memory of `allan_curve` + `fit_noise` on 1 hour of 12 channels
             at 2 kHz (int32 counts, white noise and random walk: the cost does not depend on
             the noise), the counts held by the caller (7.2e6 x 12 x 4 bytes = 346 MB) not
             counted; peak memory is the tracemalloc peak of the Python and numpy allocations.
             --quick: 1 minute. Target: < 60 s, < 1 GB. The verdict (PASS/FAIL) needs 100 seeds
             and the hour; --quick (20 seeds) prints the figures only.

Prints a table, or one JSON object with --json.
"""

import argparse
import json
import math
import sys
import time
import tracemalloc
from pathlib import Path

import allantools
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from station.sim.noise import simulated_noise  # noqa: E402
from station.solve.noise import FLOOR, TERMS, allan_curve, fit_noise  # noqa: E402

RATE = 100.0
TRUE = np.array([2e-4, 2e-4, 2e-5])
TARGETS = {"within_2_sigma": (0.90, 0.99), "scale_s": 60.0, "scale_bytes": 1e9}


def textbook(y, rate: float) -> np.ndarray:
    """(N, B, K) read off the Allan deviation as the textbook does: sigma(1 s), min sigma /
    sqrt(FLOOR), sigma(3 s)."""
    taus = 2.0 ** np.arange(int(math.log2(len(y) / rate / 4)) + 1) / rate * 1.0
    taus = np.unique(np.r_[taus, 1.0, 3.0])
    tau, dev, _, _ = allantools.oadev(y - y.mean(), rate=rate, data_type="freq", taus=taus)
    return np.array([dev[tau == 1.0][0], dev.min() / math.sqrt(FLOOR), dev[tau == 3.0][0]])


def coverage(seeds: int, k: int) -> dict:
    """Coverage of the fitted terms' bands over `seeds` streams of k samples, and the textbook
    baseline's error beside the fit's."""
    z = np.full((seeds, 3), np.nan)
    fit_err, book_err = np.zeros((seeds, 3)), np.zeros((seeds, 3))
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        y = simulated_noise(k, RATE, white=TRUE[0], bias_instability=TRUE[1],
                            random_walk=TRUE[2], rng=rng)
        fit = fit_noise(allan_curve(y[:, None], RATE))
        z[seed] = (fit.value[:, 0] - TRUE) / fit.sigma[:, 0]
        fit_err[seed] = fit.value[:, 0] / TRUE - 1
        book_err[seed] = textbook(y, RATE) / TRUE - 1
    inside2, inside1 = np.abs(z) <= 2.0, np.abs(z) <= 1.0  # NaN (unresolved): outside

    def per_term(values):
        return {t: float(v) for t, v in zip(TERMS, values, strict=True)}

    return {"seeds": seeds, "samples": k, "rate_hz": RATE, "seconds": k / RATE,
            "true": per_term(TRUE), "band": "fit +- 2 sigma (nominal 95.4 %)",
            "within_2_sigma": per_term(inside2.mean(axis=0)),
            "within_1_sigma": per_term(inside1.mean(axis=0)),
            "unresolved": per_term(np.isnan(z).mean(axis=0)),
            "z_spread": per_term(np.nanstd(z, axis=0)),
            "fit_rms_relative_error": per_term(np.sqrt(np.nanmean(fit_err**2, axis=0))),
            "textbook_rms_relative_error": per_term(np.sqrt(np.mean(book_err**2, axis=0)))}


def scale(seconds: float, rate: float = 2000.0, channels: int = 12) -> dict:
    """Wall time and tracemalloc peak of the Allan curve and fit of `channels` int32 channels."""
    k = int(seconds * rate)
    rng = np.random.default_rng(0)
    counts = np.empty((k, channels), np.int32)
    for c in range(channels):
        y = simulated_noise(k, rate, white=2e-4, random_walk=2e-5, rng=rng)
        counts[:, c] = np.round(y * 1e6)
    tracemalloc.start()
    start = time.perf_counter()
    fit = fit_noise(allan_curve(counts, rate, np.full(channels, 1e6)))
    wall = time.perf_counter() - start
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return {"seconds_of_data": seconds, "rate_hz": rate, "channels": channels,
            "input_bytes": counts.nbytes, "wall_s": wall, "peak_bytes": peak,
            "white_fitted": float(np.mean(fit.value[0]))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=int, help="streams simulated (default 100; --quick: 20)")
    p.add_argument("--quick", action="store_true", help="20 seeds and a 1 min scale run")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    cov = coverage(args.seeds or (20 if args.quick else 100), 2**20)
    sc = scale(60.0 if args.quick else 3600.0)
    passed = all(TARGETS["within_2_sigma"][0] <= v <= TARGETS["within_2_sigma"][1]
                 for v in cov["within_2_sigma"].values()) \
        and sc["wall_s"] < TARGETS["scale_s"] and sc["peak_bytes"] < TARGETS["scale_bytes"]
    if cov["seeds"] < 100 or args.quick:
        passed = None  # 20 seeds put +-7 % on a coverage, 1 min is not the hour: no verdict
    out = {"coverage": cov, "scale": sc, "targets": TARGETS, "pass": passed,
           "quick": args.quick}
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    print(f"coverage: {cov['seeds']} seeds of {cov['seconds']:.0f} s at {RATE:g} Hz, band "
          f"{cov['band']}")
    print(f"{'term':<18}{'true':>10}{'in 2 sd':>9}{'in 1 sd':>9}{'z sd':>7}{'unres':>7}"
          f"{'fit rms':>9}{'textbook':>10}")
    for t in TERMS:
        print(f"{t:<18}{cov['true'][t]:>10.3g}{cov['within_2_sigma'][t]:>9.2f}"
              f"{cov['within_1_sigma'][t]:>9.2f}{cov['z_spread'][t]:>7.2f}"
              f"{cov['unresolved'][t]:>7.2f}{cov['fit_rms_relative_error'][t]:>9.3f}"
              f"{cov['textbook_rms_relative_error'][t]:>10.3f}")
    print(f"scale: {sc['seconds_of_data']:g} s x {sc['channels']} channels at {sc['rate_hz']:g}"
          f" Hz: {sc['wall_s']:.1f} s, peak {sc['peak_bytes'] / 1e6:.0f} MB (input "
          f"{sc['input_bytes'] / 1e6:.0f} MB not counted)")
    print({True: "PASS", False: "FAIL", None: "no verdict: --quick, or fewer than 100 seeds"}
          [passed])
    return 0


if __name__ == "__main__":
    sys.exit(main())
