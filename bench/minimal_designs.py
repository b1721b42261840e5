"""Minimal pose sets of Rupniewski's Section IV (issue 31): 12 gyros (four triads, Fig. 1), n = 8
random directions, sigma = 0.01, c = 1, solved by `station.calibrate` with sigma given (closed form,
then maximum likelihood, then the identifiability test). Every such design has full rank, so every
one must be accepted; the accepted fits' error against the Cramer-Rao bound of their own directions
is the normalised MSE: eps^2 / trace(CRLB) per trial, averaged (1 for an efficient estimator), with
its standard error, and the ratio of the means.

Prints: trials, refused (with the first refusals' words), weakly determined, nMSE +- s.e., ratio
of the means, seconds. CPU heavy: about 0.1 s a trial on an idle core.

    .venv/bin/python -P bench/minimal_designs.py [--trials 1000] [--seed 31] [--json]
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from layouts import section4_gyros  # noqa: E402

import station  # noqa: E402
from station.errors import CalibrationInputError  # noqa: E402

N, SIGMA = 8, 0.01


def run(trials: int, seed: int) -> dict:
    """The Section IV Monte Carlo at n = N (module docstring)."""
    rng = np.random.default_rng(seed)
    ratio, e2, bound, refusals, weak = [], [], [], [], 0
    for _ in range(trials):
        a, v, readings = section4_gyros(rng, N, SIGMA)
        trace = float(np.trace(station.crlb(a, v, SIGMA)))
        try:
            fit = station.calibrate(readings, 1.0, sigma=SIGMA)
        except CalibrationInputError as exc:
            refusals.append(exc.problem)
            continue
        eps2 = station.eps(a, fit.a) ** 2
        ratio.append(eps2 / trace)
        e2.append(eps2)
        bound.append(trace)
        weak += bool(fit.weakly_determined)
    ratio = np.array(ratio)
    return {"trials": trials, "seed": seed, "n": N, "sigma": SIGMA,
            "accepted": len(ratio), "accepted_fraction": len(ratio) / trials,
            "refused": len(refusals), "refusals": refusals[:3],
            "weakly_determined": weak,
            "nmse": float(ratio.mean()), "nmse_se": float(ratio.std() / np.sqrt(len(ratio))),
            "ratio_of_means": float(np.sum(e2) / np.sum(bound))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=31)
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    report = run(args.trials, args.seed)
    report["seconds"] = time.perf_counter() - start
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"Section IV, 12 gyros, n = {N}, sigma = {SIGMA}: {report['trials']} trials, "
          f"{report['accepted']} accepted ({report['accepted_fraction']:.1%}), "
          f"{report['refused']} refused, {report['weakly_determined']} weakly determined")
    for words in report["refusals"]:
        print(f"  refused: {words}")
    print(f"nMSE (mean eps^2 / trace CRLB over the accepted) {report['nmse']:.3f} +- "
          f"{report['nmse_se']:.3f}; ratio of the means {report['ratio_of_means']:.3f}")
    print(f"{report['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
