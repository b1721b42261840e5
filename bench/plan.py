"""Planner benchmark (issue 16, items 3-4): fixture plans against 20 Fibonacci positions.

Units (Rupniewski Section IV noise, sigma = 0.01 per reading, |v| = 1; true layout = nominal +
N(0, 0.01^2) per entry, drawn anew per trial):
- gyros12 : the four gyro triads of a_model on the rotary table (Eq. 18 readings, no bias);
- triad   : one gyro triad on the rotary table;
- acc4    : four accelerometers (a triad and a skew one) in still poses, biases estimated.
Candidates: the 18 up directions of a lettered cube on a 45-degree wedge (`station.model.fixture`).

Per unit:
- the Monte-Carlo median eps (Eq. 19) of 20 Fibonacci positions (`suggested_axes(20)`);
- the smallest count n whose plan (`station.solve.plan.plan`, threshold 0, most n) has a Monte-
  Carlo median eps at or below it, and the plan's median eps at 20 positions (acceptance: n <= 14,
  i.e. >= 30 % fewer, or >= 20 % lower eps at 20);
- the default plan (threshold 0.025): its expected eps sqrt(trace CRLB) against the Monte-Carlo
  RMS eps over the trials the solver did not refuse (acceptance: within 10 %);
- the ceiling: the greedy plan over 200 well-spread directions (no fixture restriction) at 14
  positions, against 20 Fibonacci positions, both by the bound.
And once, the whole chain for the 12-gyro default plan: `station.sim.rotary.simulate_rotary` at the
plan's fixture orientations -> Eq. (18) reduction -> `station.calibrate`, against the expected eps
from the unit's noise density and the windows' lengths.

Every trial uses `station.calibrate` (closed form + ML) with the known sigma; seeds fixed.
`--trials 400 --sessions 150` (default) runs in 2-4 minutes on the shared 2-core machine.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import station  # noqa: E402
from station.errors import CalibrationInputError  # noqa: E402
from station.model.fixture import Fixture  # noqa: E402
from station.model.unit import SensorUnit  # noqa: E402
from station.protocols.rotary import suggested_axes  # noqa: E402
from station.reduce.eq18 import reduce_arrays  # noqa: E402
from station.sim.layouts import A_MODEL, perturbed  # noqa: E402
from station.sim.profile import RotaryTiming  # noqa: E402
from station.sim.rotary import simulate_rotary  # noqa: E402
from station.solve.plan import expected_eps, plan  # noqa: E402

SIGMA = 0.01
ACC4 = np.column_stack([np.eye(3), np.ones(3) / np.sqrt(3)])
UNITS = {"gyros12": (A_MODEL, False), "triad": (np.eye(3), False), "acc4": (ACC4, True)}


def monte_carlo(a_nominal, up, estimate_bias: bool, trials: int, seed: int) -> np.ndarray:
    """eps (Eq. 19) of `trials` calibrations from readings at directions `up` ((n, 3)); inf for a
    trial the solver refuses (counted in the medians as failed, left out of the RMS)."""
    rng = np.random.default_rng(seed)
    v = np.asarray(up, float).T
    m = a_nominal.shape[1]
    out = np.empty(trials)
    for t in range(trials):
        a = perturbed(a_nominal, 0.01, rng)
        bias = 0.05 * rng.standard_normal(m) if estimate_bias else np.zeros(m)
        readings = a.T @ v + bias[:, None] + SIGMA * rng.standard_normal((m, v.shape[1]))
        try:
            fit = station.calibrate(readings, 1.0, sigma=SIGMA,
                                    bias="estimate" if estimate_bias else None)
        except CalibrationInputError:  # the closed form refused the trial: counted as failed
            out[t] = np.inf
            continue
        out[t] = station.eps(a, fit.a)
    return out


def unit_figures(name: str, trials: int, seed: int) -> dict:
    """The figures of one unit (module docstring)."""
    a, bias = UNITS[name]
    up, _ = Fixture(wedge=True).reachable_up()
    fib = suggested_axes(20)
    fib_eps = monte_carlo(a, fib, bias, trials, seed)
    target = float(np.median(fib_eps))
    by_bound = {n: plan(a, up, SIGMA, 1.0, estimate_bias=bias, threshold=0.0, most=n)
                for n in range(10, 31)}
    # Monte Carlo from the count the bound says first reaches the target, downwards and upwards
    first = min((n for n, p in by_bound.items() if p.eps <= expected_eps(a, fib, SIGMA, 1.0, bias)),
                default=30)
    medians, n_needed = {}, None
    for n in sorted({max(10, first - 1), first, min(30, first + 1), 20}):
        medians[n] = float(np.median(monte_carlo(a, up[by_bound[n].chosen], bias, trials, seed)))
    n_needed = min((n for n, e in medians.items() if e <= target), default=None)
    default = plan(a, up, SIGMA, 1.0, estimate_bias=bias)
    mc = monte_carlo(a, up[default.chosen], bias, trials, seed + 1)
    rms = float(np.sqrt(np.mean(mc[np.isfinite(mc)] ** 2)))
    dense = suggested_axes(200)
    ceiling = plan(a, dense, SIGMA, 1.0, estimate_bias=bias, threshold=0.0, most=14)
    return {
        "fibonacci20": {"median_eps": target, "expected_eps": expected_eps(a, fib, SIGMA, 1.0,
                                                                             bias),
                        "failed_trials": int(np.sum(~np.isfinite(fib_eps)))},
        "plan_median_eps_by_count": medians,
        "positions_to_reach_fibonacci20": n_needed,
        "fewer_positions": None if n_needed is None else 1 - n_needed / 20,
        "lower_eps_at_20": 1 - medians[20] / target,
        "default_plan": {"positions": len(default.chosen), "expected_eps": default.eps,
                         "mc_rms_eps": rms, "mc_median_eps": float(np.median(mc)),
                         "mc_failed_trials": int(np.sum(~np.isfinite(mc))),
                         "expected_over_mc": default.eps / rms},
        "ceiling_dense_greedy_14_over_fibonacci20":
            ceiling.eps / expected_eps(a, fib, SIGMA, 1.0, bias),
    }


def whole_chain(sessions: int, seed: int) -> dict:
    """The 12-gyro default plan through simulate -> Eq. (18) -> calibrate, against the expected
    eps computed before the session from the noise density and the windows' lengths."""
    timing = RotaryTiming()
    fixture = Fixture(wedge=True)
    up, poses = fixture.reachable_up()
    density, fs = 0.005, 200.0
    eps, expected = [], None
    for s in range(sessions):
        rng = np.random.default_rng([seed, s])
        unit = SensorUnit(perturbed(A_MODEL, 0.01, rng), bias=0.01 * rng.standard_normal(12),
                          noise_density=density, counts_per_unit=1e6, fs=fs, rng=rng)
        if expected is None:  # the windows' lengths, as the session's reduction will cut them
            probe = reduce_arrays(simulate_rotary(unit, 1, timing).arrays)
            sigma = density * np.sqrt(fs * (1 / probe.n_static[0] + 1 / probe.n_rotating[0]))
            chosen = plan(A_MODEL, up, sigma, timing.rate)
            expected = chosen.eps
            orientations = np.array([poses[k].orientation for k in chosen.chosen])
        red = reduce_arrays(simulate_rotary(unit, orientations, timing).arrays)
        fit = station.calibrate(red.M, timing.rate, sigma=sigma)
        eps.append(station.eps(unit.a, fit.a))
    rms = float(np.sqrt(np.mean(np.square(eps))))
    return {"sessions": sessions, "positions": len(orientations), "reading_sigma": float(sigma),
            "expected_eps": expected, "mc_rms_eps": rms, "expected_over_mc": expected / rms}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=400)
    parser.add_argument("--sessions", type=int, default=150)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    start = time.perf_counter()
    out = {"trials": args.trials, "seed": args.seed, "sigma": SIGMA,
           "units": {name: unit_figures(name, args.trials, args.seed) for name in UNITS},
           "whole_chain_gyros12": whole_chain(args.sessions, args.seed)}
    out["seconds"] = time.perf_counter() - start
    if args.json:
        print(json.dumps(out, indent=2))
        return
    for name, u in out["units"].items():
        d = u["default_plan"]
        print(f"{name}: Fibonacci 20 median eps {u['fibonacci20']['median_eps']:.4g}; plan needs "
              f"{u['positions_to_reach_fibonacci20']} positions, at 20 its median eps is "
              f"{100 * u['lower_eps_at_20']:.1f} % lower; default plan {d['positions']} "
              f"positions, expected {d['expected_eps']:.4g} / MC RMS {d['mc_rms_eps']:.4g} = "
              f"{d['expected_over_mc']:.3f}; dense ceiling at 14 / Fibonacci 20 by the bound "
              f"{u['ceiling_dense_greedy_14_over_fibonacci20']:.3f}")
    w = out["whole_chain_gyros12"]
    print(f"whole chain, gyros12, {w['sessions']} sessions of {w['positions']} positions: "
          f"expected {w['expected_eps']:.4g} / MC RMS {w['mc_rms_eps']:.4g} = "
          f"{w['expected_over_mc']:.3f}; {out['seconds']:.0f} s")


if __name__ == "__main__":
    main()
