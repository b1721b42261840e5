"""Speed of the simulator and the Eq. (18) reduction, and the end-to-end efficiency figure.

Times a 20-position rotary session (10 s static + 25 s moving per position, 12 gyros, 200 Hz;
target: under 2 s) and its reduction, then runs the acceptance experiment of issue 3: over
`--seeds` seeds, mean(eps^2 / trace(CRLB)) of simulate -> reduce -> station.calibrate (target:
within [0.9, 1.1]). Prints a table, or one JSON object with --json.
"""

import argparse
import json
import time

import numpy as np

import station
from station.model.unit import SensorUnit
from station.reduce.eq18 import reduce_arrays
from station.sim.layouts import A_MODEL, perturbed
from station.sim.profile import RotaryTiming
from station.sim.rotary import simulate_rotary


def unit_for(seed: int) -> SensorUnit:
    """The 12-gyro unit of the acceptance test: a_model + N(0, 0.01^2), noisy enough to matter."""
    rng = np.random.default_rng(seed)
    return SensorUnit(
        perturbed(A_MODEL, 0.01, rng),
        bias=0.01 * rng.standard_normal(12),
        noise_density=0.005,
        counts_per_unit=1000.0,
        fs=200.0,
        rng=rng,
    )


def timings(repeats: int) -> dict:
    """Best-of-`repeats` seconds to simulate and to reduce the 20-position session."""
    sim_s, red_s = [], []
    for seed in range(repeats):
        unit = unit_for(seed)
        t0 = time.perf_counter()
        sim = simulate_rotary(unit, 20, RotaryTiming(static=10.0, moving=25.0))
        t1 = time.perf_counter()
        reduce_arrays(sim.arrays)
        red_s.append(time.perf_counter() - t1)
        sim_s.append(t1 - t0)
    return {
        "simulate_s": min(sim_s),
        "simulate_median_s": float(np.median(sim_s)),
        "reduce_s": min(red_s),
        "samples": int(sim.arrays["y"].size),
    }


def efficiency(seeds: int) -> dict:
    """mean and standard error of eps^2 / trace(CRLB) over `seeds` simulated sessions."""
    ratios = []
    for seed in range(seeds):
        unit = unit_for(seed)
        sim = simulate_rotary(unit, 20)
        red = reduce_arrays(sim.arrays)
        sigma = np.sqrt(
            (unit.sigma[0] ** 2 + unit.lsb[0] ** 2 / 12)
            * (1 / red.n_static[0] + 1 / red.n_rotating[0])
        )
        result = station.calibrate(red.M, magnitude=float(sim.arrays["c_cmd"]), d=3, sigma=sigma)
        bound = np.trace(station.crlb(unit.a, sim.truth["v"], sigma))
        ratios.append(station.eps(unit.a, result.a) ** 2 / bound)
    return {
        "seeds": seeds,
        "eps2_over_crlb": float(np.mean(ratios)),
        "eps2_over_crlb_se": float(np.std(ratios) / np.sqrt(seeds)),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--repeats", type=int, default=5, help="timing runs (best is reported)")
    parser.add_argument("--seeds", type=int, default=200, help="seeds of the efficiency figure")
    args = parser.parse_args(argv)
    figures = {**timings(args.repeats), **efficiency(args.seeds)}
    if args.json:
        print(json.dumps(figures))
    else:
        for key, value in figures.items():
            print(f"{key:>20}: {value:.4g}" if isinstance(value, float) else f"{key:>20}: {value}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
