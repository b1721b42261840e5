"""Acceptance statistics of `station diagnose` on simulated rotary sessions (issue 7).

Sessions hide one effect each (or none), with magnitudes of a few noise sigma in the effect's own
signature, m in {3, 6, 12}, n = 20. Prints, per effect, how often the right effect (or `none`)
is named, the gap before and after, and for rate_error, scale_nonlinearity and bias_drift the
eps of the calibration before and after against sqrt(trace(CRLB)) (for rate_error also against
the bound of the random-effects model at the true spread, `crlb(..., spread=s)`, which is the
smallest eps possible when the table's rate scatters unseen; with the table's encoder,
`rate_error_encoder`, the nominal bound applies); then the time of one full 20-position,
12-channel, 200 Hz session. Run as `.venv/bin/python -P bench/diagnose.py [--json]
[--effects rate_error none] [--no-timing] [--leave-one-out] [--none-variants] [--pairs]`.

`--coloured [CASE ...]` (issue 32, patterns 1-2) runs instead the COLOURED sessions (m = 3): a
library effect beside a bias random walk or flicker, warm-ups between the bias_drift grid's
points, effect-free sessions with coloured noise; per case the counts named / partial / not
named / other name / nothing named / unexplained, the share of its gap the effect closes, eps.

`--temperature` (issue 15) runs instead the sessions that record the unit's temperature
(`WARM`, `station.sim.warm_rotary`): heat-driven drift (the right call `temperature`, not
`bias_drift`), time-driven drift (`bias_drift`, not `temperature`) and effect-free ones (`none`),
with 95 % Clopper-Pearson intervals of the rates right.
"""

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
from scipy.stats import binomtest

from station.diagnose import data as session_data
from station.diagnose import diagnose
from station.diagnose.effects import EXTENSIONS
from station.model.earth import OMEGA_EARTH
from station.model.effects import parse
from station.model.effects.saturation import Saturation
from station.model.effects.temperature import Temperature
from station.model.frames import eps
from station.sim.layouts import A_MODEL, TRIAD, gyro_array
from station.sim.noise import flicker, simulated_noise
from station.sim.profile import RotaryTiming
from station.sim.rotary import simulate_rotary
from station.sim.warm_rotary import chamber_hump, motor_heating, simulate_warm_rotary, slow_ramp
from station.solve.noise import allan_curve, fit_noise
from station.solve.uncertainty import crlb

SHORT = RotaryTiming(static=4.0, moving=10.0)
"""A short position (4 s static, 10 s moving) for the acceptance suite, at 100 Hz."""

CASES = {
    "none": "none",
    "bias_drift": "bias_drift=warmup=0.004,heating=0.0006",
    "scale_nonlinearity": "scale_nonlinearity=k2=2e-4",
    "scale_asymmetry": "scale_asymmetry=k=2e-4",
    "rate_error": "rate_error=spread=1.5e-4",
    "rate_error_encoder": "rate_error=scale=1e-4,spread=1.5e-4,encoder=1",
    "earth_rate": "earth_rate",
    "axis_wobble": "axis_wobble=angle_deg=0.004",
    "latency": "latency=delay=3e-4",
    "saturation": "saturation",
}
"""Case -> simulator spec of the hidden effect for the short sessions; the right call is the spec's
effect name (or, issue 32 pattern 5, `AMBIGUOUS` with it: scale_asymmetry and scale_nonlinearity,
both even in the signal, correlate by about 0.97 at one rate magnitude, and k = 2e-4 is 3-5 x the
asymmetry's detection limit on m = 3, where the difference of the two is rarely significant).
`rate_error`: the table reports the commanded angle; `rate_error_encoder`: its angle reads the
shaft. The saturation range is set per session 2 noise sigma below the largest steady output
(`rail_below_peak`)."""

LAYOUTS = {3: TRIAD, 6: A_MODEL[:, :6], 12: A_MODEL}

WALK, FLICKER = 3e-5, 5e-5
"""Coloured noise of the issue 32 cases (`COLOURED`): a bias random walk of 3e-5 rad/s/sqrt(s)
(370 deg/h/sqrt(h), a poor MEMS gyro: the static means of a short session drift by 4 x their
white noise) and flicker of bias instability 5e-5 rad/s (10 deg/h; station.sim.noise), against
the default gyro's 8.7e-5 rad/s white noise of a 4 s static mean."""
COLOURED = {
    "latency_walk": ("latency=delay=3.5e-4", WALK, 0.0),
    "latency_flicker": ("latency=delay=3.5e-4", 0.0, FLICKER),
    "warmup_200s": ("bias_drift=warmup=7e-4,warmup_tau=200", 0.0, 0.0),
    "warmup_200s_walk": ("bias_drift=warmup=7e-4,warmup_tau=200", WALK, 0.0),
    "warmup_200s_beside_walk": ("bias_drift=warmup=6e-3,warmup_tau=200", WALK, 0.0),
    "warmup_200s_strong": ("bias_drift=warmup=0.05,warmup_tau=200", 0.0, 0.0),
    "none_walk": ("none", WALK, 0.0),
    "none_walk_flicker": ("none", WALK / 10, FLICKER),
}
"""Issue 32, patterns 1-2 (`--coloured`): case -> (hidden effect, bias random walk, flicker).
A latency of 3.5e-4 s is about 4 x its detection limit on m = 3 (white noise: LR - dof over the
noncentrality whose median LR reaches the first step's threshold, 3.3-3.8 x at 3e-4 s); the
warm-up of tau 200 s (a few minutes, between the bias_drift grid's points) at 7e-4 rad/s, about 4 x
its limit, and at 0.05 rad/s, far above (log10 p below -1e5); effect-free with the walk alone
and with a ten times smaller walk beside flicker."""

OPEN = {"tone_1.7x": 1.7, "tone_2.5x": 2.5, "tone_against_2.2x": -2.2}
"""Issue 32, pattern 6 (`--open`): case -> the frequency, in multiples of the table rate
(negative: turning against the table), of a coning off the table rate (a loose mount: the
simulator's axis_wobble with a frequency in Hz) of half-angle `OPEN_ANGLE`, which no named
effect has; the right call is the open family `tone`."""
OPEN_ANGLE = 0.006
"""deg: 2.5-4.4 x the tone's detection limit on m = 3 (LR - dof over the noncentrality whose
median LR reaches the first step's threshold, the Bonferroni factor of the frequencies searched
included; seeds 3000, 3001 at 1.7 and 2.5 x the table rate)."""


JUMPS = {"jump": 2.5e-4}
"""Issue 32, the open family `jump` (`--open`): case -> the size (rad/s) of a step of every
sensor's bias (signs drawn per sensor) at an instant drawn uniformly between the third position's
start and the third last's end (gaps between positions included), on a gyro with counts 16 times
finer than the default (the step, below a default count, would vanish in the rounding: the
simulator has no step to add before it quantises). About 2-5 x its limit on m = 3 (LR - dof over
the noncentrality whose median LR reaches the first step's threshold, the Bonferroni factor of
the instants searched included: 1.3-3.5 x at 2e-4 rad/s, 3.6-8.4 x at 3e-4, seeds 3600-3603; it
depends on the instant: a step near the end moves few positions)."""
FINE = {"counts_per_unit": 16 * 16.4 / np.radians(1.0)}

POLYNOMIALS = {"polynomial_cubic": "polynomial=c3=3e-4", "polynomial_quartic": "polynomial=c4=2e-4",
               "polynomial_quintic": "polynomial=c5=2e-4"}
"""Issue 32, the open family `polynomial` (`--open`): case -> the simulator spec of a bend of the
output no named effect has (a cubic term, c3 s^3 with s the sensed rate in rad/s); about 3-4 x
its limit on m = 3 (LR - dof over the noncentrality whose median LR reaches the first step's
threshold, the Bonferroni factor of the orders searched included: 1.7 x at 2e-4, seed 3001).
A quartic and a quintic term (c4, c5 = 2e-4) the family's orders (2, 3) do not hold: seeds
3600-3609 name scale_nonlinearity for the quartic 10 / 10 and `polynomial` of order 3 for the
quintic 7 / 10 (3 with rate_error first); orders up to 5 (session 26, tried: a nested test
beside the straight line) named them 7 / 10 and 10 / 10 but took 2 / 12 true quadratics from
scale_nonlinearity and named a left-out rate error `polynomial` once (eps worse by > 1 sd)."""


def spec(case: str) -> str:
    """The simulator spec of one case of CASES or OPEN."""
    if case in OPEN:
        hz = OPEN[case] * SHORT.rate / (2 * np.pi)
        return f"axis_wobble=angle_deg={OPEN_ANGLE},freq={hz:.6g}"
    if case in QUANTISED:
        return CASES[QUANTISED[case][0]]
    return POLYNOMIALS.get(case) or CASES[case]


QUIET = 2e-4 / OMEGA_EARTH
QUANTISED = {"quantised_6sigma": ("none", 10), "quantised_2.5sigma": ("none", 4),
             "bias_drift_quantised": ("bias_drift", 10), "rate_error_quantised": ("rate_error", 10)}
UNITS = {"earth_rate": {"noise_density": np.radians(0.01) / QUIET,
                        "counts_per_unit": QUIET * 16.4 / np.radians(1.0)},
         **{case: {"counts_per_unit": 16.4 / np.radians(1.0) / coarser}
            for case, (_, coarser) in QUANTISED.items()}}
"""Unit overrides per case: the Earth's own rate (a physical one, station.diagnose.plausibility)
on a gyro 2.7 x quieter than the MEMS default (and counts 2.7 x finer, so that the noise keeps
its size in counts), the signal-to-noise of 2e-4 rad/s on the default one. Issue 32, pattern 4
(`QUANTISED`, run by `--effects` only: case -> (the case of CASES it hides, how many times
coarser than the default MEMS gyro's its counts are)): a step of 0.0106 rad/s, about 6 sigma, or
of about 2.5 sigma, effect-free or beside a library effect (whose signals, 0.004 rad/s of
warm-up, 1.5e-4 of the rate, lie within a step: the right call is still the effect's name, when
the quantiser lets it be seen)."""


PAIRS = ("bias_drift+latency", "scale_nonlinearity+latency", "bias_drift+scale_nonlinearity",
         "axis_wobble+latency", "bias_drift+axis_wobble")
"""Sessions hiding two effects of CASES at once (`--pairs`; the right call: both named), each pair
with signatures in different statistics (static means and trends, the rotating level, the
spectrum at the table rate, the ramps)."""


def hidden(case: str) -> list:
    """The effect names a case hides: one, or two for a pair ("a+b")."""
    return [parse(spec(c))[0] for c in case.split("+")]


def session(case: str, m: int, seed: int, timing=SHORT, fs: float = 100.0, n: int = 20):
    """(RotaryData, truth) of one simulated session hiding the effect(s) of `case` (with its
    coloured noise for a case of COLOURED)."""
    if case in COLOURED:
        return coloured_session(case, m, seed, timing, fs, n)
    if case in JUMPS:
        return jump_session(case, m, seed, timing, fs, n)
    effects = {}
    for one in case.split("+"):
        name, params = parse(spec(one))
        if one == "saturation":
            params = Saturation(rail_below_peak(m, seed, timing, fs, n))
        if params is not None:
            effects[name] = params
    rng = np.random.default_rng(seed)
    unit = gyro_array(rng, LAYOUTS[m], fs=fs, **UNITS.get(case, {}))
    sim = simulate_rotary(unit, n, timing, effects=effects, a_nominal=LAYOUTS[m])
    return session_data.from_arrays(sim.arrays), sim.truth


def jump_session(case: str, m: int, seed: int, timing, fs: float, n: int):
    """(RotaryData, truth) of a JUMPS case: the step added to the counts of the samples at or
    after its instant (truth["jump"]: size per sensor, instant)."""
    rng = np.random.default_rng(seed)
    unit = gyro_array(rng, LAYOUTS[m], fs=fs, **FINE)
    sim = simulate_rotary(unit, n, timing, a_nominal=LAYOUTS[m])
    arrays = dict(sim.arrays)
    y = np.asarray(arrays["y"])
    lsb = np.broadcast_to(np.asarray(arrays["lsb"], float), (m,))
    times = np.asarray(arrays["t0"], float)[:, None] + np.arange(y.shape[1]) / fs
    draw = np.random.default_rng(seed + 7)
    t0 = float(draw.uniform(times[2, 0], times[-3, -1]))
    delta = JUMPS[case] * draw.choice([-1.0, 1.0], m)
    arrays["y"] = y + np.round((times >= t0)[..., None] * delta / lsb).astype(y.dtype)
    return session_data.from_arrays(arrays), {**sim.truth, "jump": {"delta": delta, "t0": t0}}


def coloured_session(case: str, m: int, seed: int, timing, fs: float, n: int):
    """(RotaryData, truth) of a COLOURED case: the unit's bias random walk (continuing between
    positions) and flicker added to the counts as one stream over the positions' samples (the
    pauses between them left out), the counts then 100 x finer than the default gyro's
    (`FLICKER_COUNTS`): rounded again on the default grid (a step of 1.1e-3 rad/s, the white
    noise already in the rounded counts), flicker of 5e-5 rad/s mostly vanished (until session
    26)."""
    spec, walk, bias_instability = COLOURED[case]
    name, params = parse(spec)
    rng = np.random.default_rng(seed)
    unit = gyro_array(rng, LAYOUTS[m], fs=fs, bias_walk=walk,
                      **(FLICKER_COUNTS if bias_instability else {}))
    sim = simulate_rotary(unit, n, timing, effects={} if params is None else {name: params},
                          a_nominal=LAYOUTS[m])
    arrays = dict(sim.arrays)
    if bias_instability:
        y = np.asarray(arrays["y"])
        lsb = np.broadcast_to(np.asarray(arrays["lsb"], float), (m,))
        noise = np.stack([flicker(y[..., 0].size, bias_instability, rng) for _ in range(m)], 1)
        arrays["y"] = np.round(y + noise.reshape(y.shape) / lsb).astype(y.dtype)
    return session_data.from_arrays(arrays), sim.truth


FLICKER_COUNTS = {"counts_per_unit": 100 * 16.4 / np.radians(1.0)}
"""The counts of a session with flicker (`coloured_session`): a step of 1.1e-5 rad/s, whose
rounding of the flicker leaves at most 5e-6 rad/s a sample (a mean keeps under 1e-3 of its white
noise's variance)."""


def open_family(seeds: int, cases=(*OPEN, *JUMPS, *POLYNOMIALS), layouts=(3,)) -> dict:
    """Per OPEN or JUMPS case over m in `layouts` and `seeds` seeds (1000 m + 600 + s):
    sessions with the family (`tone`, `jump`) named first, another name, nothing named,
    unexplained; the fitted frequency's error in its sigma (tone), or whether the true instant
    lies in the fitted one's 2-sigma span and the sizes' errors in their sigmas (jump); the
    family's own gap before and after; eps worse than before by more than 1 sd."""
    out = {}
    for case in cases:
        family = "jump" if case in JUMPS else "polynomial" if case in POLYNOMIALS else "tone"
        runs = [run_case(case, m, 1000 * m + 600 + s) for m in layouts for s in range(seeds)]
        if family == "tone":
            check = {"frequency_z": [(r["tone_multiple"][0] - OPEN[case]) / r["tone_multiple"][1]
                                     for r in runs if r["tone_multiple"]]}
        elif family == "polynomial":
            check = {"order": [r["polynomial_order"] for r in runs]}
        else:
            check = {"instant_in_span": [r["jump"]["in_span"] for r in runs if r["jump"]],
                     "delta_z": [z for r in runs if r["jump"] for z in r["jump"]["delta_z"]]}
        own = {"jump": "static", "polynomial": "averaged"}.get(family, "harmonics")
        out[case] = {
            "sessions": len(runs),
            "named_first": sum(r["first"] == family for r in runs),
            "other_named": sum(any(e != family for e in r["named"]) for r in runs),
            "nothing_named": sum(not r["named"] for r in runs),
            "unexplained": sum(bool(r["unexplained"]) for r in runs),
            **check,
            "gap_before": [r["gap"][0][own] for r in runs],
            "gap_after": [r["gap"][-1][own] for r in runs],
            "worse_by_more_than_1sd": sum(r["eps_after"] > r["eps_before"] + r["eps_sd_at_bound"]
                                          for r in runs),
            "named": [r["named"] for r in runs],
        }
    return out


def coloured(seeds: int, cases=tuple(COLOURED), layouts=(3,), noise_model: bool = False) -> dict:
    """Per COLOURED case over m in `layouts` and `seeds` seeds (1000 m + 500 + s): sessions
    with the hidden effect named (and named first), named as partial, not named though found
    (`not_named`), another effect named, nothing named; unexplained; the share of its gap the
    hidden effect closes; eps worse than before by more than 1 sd at the bound."""
    out = {}
    for case in cases:
        effect = parse(COLOURED[case][0])[0]
        runs = [run_case(case, m, 1000 * m + 500 + s, noise_model=noise_model)
                for m in layouts for s in range(seeds)]
        out[case] = {
            "sessions": len(runs),
            "named": sum(effect in r["named"] for r in runs),
            "named_first": sum(r["first"] == effect for r in runs),
            "partial": sum(bool(r["closes"].get(effect, {}).get("partial")) for r in runs),
            "not_named": sum(effect in r["not_named"] for r in runs),
            "other_named": sum(any(e != effect for e in r["named"]) for r in runs),
            "nothing_named": sum(not r["named"] for r in runs),
            "unexplained": sum(bool(r["unexplained"]) for r in runs),
            "closes": [r["closes"].get(effect, {}).get("fraction") for r in runs],
            "worse_by_more_than_1sd": sum(r["eps_after"] > r["eps_before"] + r["eps_sd_at_bound"]
                                          for r in runs),
            "eps_before_over_bound_rms": rms_ratio(runs, "eps_before", "crlb"),
            "eps_after_over_bound_rms": rms_ratio(runs, "eps_after", "crlb"),
            "runs": [{k: r[k] for k in ("m", "seed", "named", "not_named", "unexplained",
                                        "closes", "eps_before", "eps_after", "eps_sd_at_bound",
                                        "noise_model")}
                     for r in runs],
        }
    return out


TEMPCO = 1e-4
"""rad/s per K: size of the simulated bias tempcos (0.006 deg/s/K, below a MEMS datasheet's
0.01-0.05); each sensor's is TEMPCO times a random sign and a factor in [0.5, 1.5]."""
WARM = {
    "temperature_hump": ("temperature", chamber_hump(3.0), "none", True),
    "temperature_motor": ("temperature", motor_heating(4.0, tau=30.0), "none", True),
    "bias_drift_ramp": ("bias_drift", slow_ramp(1.0), CASES["bias_drift"], False),
    "bias_drift_flat": ("bias_drift", slow_ramp(0.0), CASES["bias_drift"], False),
    "none_flat": ("none", slow_ramp(0.0), "none", False),
    "none_ramp": ("none", slow_ramp(2.0), "none", False),
}
"""Case -> (right call, temperature history (K), other hidden effect, bias tempcos or not), on
the default MEMS gyro (short sessions as CASES): heat-driven drift with a chamber going up 3 K
and back down (not monotone in time) or with the table's motor heating the unit while it spins
(4 K per rad/s, tau 30 s); time-driven drift (CASES' bias_drift) with the temperature rising 1 K
over the session, unrelated, or flat; no effect with the temperature flat or rising 2 K."""
WRONG = {"temperature": "bias_drift", "bias_drift": "temperature"}
"""Right call -> the name it must not be confused with."""


def warm_session(case: str, m: int, seed: int, timing=SHORT, fs: float = 100.0, n: int = 20):
    """(RotaryData, truth) of one simulated session recording the unit's temperature."""
    _, history, other, tempco = WARM[case]
    name, params = parse(other)
    rng = np.random.default_rng(seed)
    unit = gyro_array(rng, LAYOUTS[m], fs=fs)
    bias = TEMPCO * rng.choice([-1.0, 1.0], m) * rng.uniform(0.5, 1.5, m) if tempco else 0.0
    sim = simulate_warm_rotary(unit, n, timing, history, Temperature(bias=tuple(np.ravel(bias))
                                                                     if tempco else 0.0),
                               effects={} if params is None else {name: params},
                               a_nominal=LAYOUTS[m])
    return session_data.from_arrays(sim.arrays), sim.truth


def warm_case(case: str, m: int, seed: int) -> dict:
    """Diagnose one session of `warm_session`: the names, and the fitted tempcos against the
    truth (z-scores) when `temperature` is named."""
    d, truth = warm_session(case, m, seed)
    result = diagnose(d)
    fitted = result.final.fitted.get("temperature")
    z = None
    if fitted is not None:
        true = np.broadcast_to(np.asarray(truth["temperature"]["bias"], float), (m,))
        z = ((fitted.value("bias") - true) / fitted.sigma["bias"]).tolist()
    return {"case": case, "m": m, "seed": seed, "named": result.effects,
            "unexplained": [u["statistic"] for u in result.unexplained],
            "offered": "temperature" in result.steps[0].evidence, "tempco_z": z}


def warm_acceptance(seeds: int, cases=tuple(WARM), first: int = 0) -> dict:
    """Per WARM case over m in {3, 6, 12} and `seeds` seeds (1000 m + s, s from `first`): right
    (the right call first and the name it is confused with absent; `none`: nothing named), the
    interval, and how often `temperature` was offered."""
    out = {}
    for case in cases:
        want = WARM[case][0]
        runs = [warm_case(case, m, 1000 * m + s) for m in LAYOUTS
                for s in range(first, first + seeds)]
        right = [(not r["named"]) if want == "none" else
                 (r["named"][:1] == [want] and WRONG[want] not in r["named"]) for r in runs]
        k = int(sum(right))
        out[case] = {"sessions": len(runs), "right": k, "right_rate": k / len(runs),
                     "interval_95": interval(k, len(runs)),
                     "offered": int(sum(r["offered"] for r in runs)),
                     "named": [r["named"] for r in runs],
                     "unexplained": [r["unexplained"] for r in runs],
                     "tempco_z_max": max((max(map(abs, r["tempco_z"])) for r in runs
                                          if r["tempco_z"]), default=None)}
    return out


def rail_below_peak(m, seed, timing, fs, n, sigmas: float = 2.0) -> float:
    """A range `sigmas` sample sigma below the largest steady |output| of the same session
    without the effect (the saturation draws nothing from the generator)."""
    unit = gyro_array(np.random.default_rng(seed), LAYOUTS[m], fs=fs)
    truth = simulate_rotary(unit, n, timing, a_nominal=LAYOUTS[m]).truth
    steady = np.asarray(truth["a"]).T @ np.asarray(truth["v"]) + unit.bias[:, None]
    return float(np.abs(steady).max() - sigmas * unit.sigma.max())


REST_SAMPLES = 2**19
"""Samples of the rest recording of `--noise-model` (87 min at 100 Hz, a noise run before a
campaign): long enough for the Allan fit to resolve the bias random walk `WALK` (its Allan
variance passes the white noise's at tau = sqrt(3) N / K = 10 s) and the flicker `FLICKER` for
every sensor (2^17 samples resolved it for one of three)."""


def rest_terms(channels: int, fs: float, white: float, bias_instability: float,
               random_walk: float, rng) -> dict:
    """{term: (channels,)} the bias instability and random walk `station noise` finds on a rest
    recording of `channels` sensors (the Allan fit of REST_SAMPLES samples of this white noise,
    flicker and walk, station.solve.noise) where it resolves them for every sensor (a
    calibration file holds no other)."""
    rest = np.stack([simulated_noise(REST_SAMPLES, fs, white=white,
                                     bias_instability=bias_instability, random_walk=random_walk,
                                     rng=rng) for _ in range(channels)], 1)
    fit = fit_noise(allan_curve(rest, fs))
    return {term: fit.value[k] for k, term in ((1, "bias_instability"), (2, "random_walk"))
            if fit.resolved[k].all()}


def rest_noise(case: str, m: int, seed: int, fs: float = 100.0) -> dict:
    """{term: (m,)} the coloured noise of the unit of a session from a rest recording of it
    (`rest_terms`: its white noise, and the walk and flicker of its COLOURED case)."""
    walk, bias_instability = COLOURED[case][1:] if case in COLOURED else (0.0, 0.0)
    return rest_terms(m, fs, np.radians(0.01), bias_instability, walk,
                      np.random.default_rng([seed, 17]))


def run_case(case: str, m: int, seed: int, leave_out: bool = False, noise_model: bool = False,
             **kwargs) -> dict:
    """Diagnose one session; the named effects, the verdict, gaps and calibration errors.
    leave_out: the hidden effect is also removed from the candidates; noise_model: the unit's
    coloured noise from a rest recording (`rest_noise`) is in the noise model."""
    d, truth = session(case, m, seed, **kwargs)
    if noise_model:
        d = dataclasses.replace(d, **rest_noise(case, m, seed))
    left_out = hidden(case) if leave_out else ()
    result = diagnose(d, candidates=tuple(e for e in EXTENSIONS if e not in left_out))
    a_true, v_true = np.asarray(truth["a"]), np.asarray(truth["v"])
    cov = crlb(a_true, v_true, d.sigma_m)
    bound = float(np.sqrt(np.trace(cov)))
    spread = truth["effects"].get("rate_error", {}).get("spread")
    rate = result.final.fitted.get("rate_error")
    return {
        "case": case,
        "m": m,
        "seed": seed,
        "leave_out": leave_out,
        "noise_model": [t for t in ("random_walk", "bias_instability")
                        if getattr(d, t) is not None],
        "named": result.effects,
        "first": result.effects[0] if result.effects else "none",
        "ambiguous": [g["effects"] for g in result.ambiguous],
        "unexplained": [u["statistic"] for u in result.unexplained],
        "resembles": [r["effect"] for r in result.resembles],
        "not_named": [r["effect"] for r in result.not_named],
        "closes": result.closes,
        "correction_applied": None if result.correction is None else result.correction["applied"],
        "gap": [step.gap for step in result.steps],
        "eps_before": eps(a_true, result.steps[0].model.calibration.a),
        "eps_after": eps(a_true, result.calibration.a),
        "crlb": bound,
        # 1 sd of eps at the bound: eps^2 = |e|^2, e ~ N(0, C): var 2 tr C^2, d eps = d(eps^2)/2eps
        "eps_sd_at_bound": float(np.sqrt(2 * np.trace(cov @ cov)) / (2 * bound)),
        "crlb_random": float(np.sqrt(np.trace(crlb(a_true, v_true, d.sigma_m, spread=spread)))),
        "spread_true": spread,
        "spread_fitted": _estimate(rate, "spread"),
        "gain_fitted": _estimate(rate, "gain"),  # with the table's encoder
        "tone_multiple": _estimate(result.final.fitted.get("tone"), "table_rate_multiple"),
        "jump": _jump(result.final.fitted.get("jump"), truth.get("jump")),
        "polynomial_order": (result.final.fitted["polynomial"].values["order"]
                             if "polynomial" in result.final.fitted else None),
    }


def _jump(fitted, truth) -> dict | None:
    """Whether the true instant lies in the fitted jump's 2-sigma span and its sizes' errors in
    their sigmas; None when no jump was fitted or none hidden."""
    if fitted is None or truth is None:
        return None
    lo, hi = fitted.values["t0_span"]
    z = (fitted.value("delta") - truth["delta"]) / fitted.sigma["delta"]
    return {"in_span": bool(lo <= truth["t0"] <= hi), "delta_z": z.tolist()}


def _estimate(fitted, key: str):
    """(value, 1-sigma) of a fitted extension's parameter, None when it has no such estimate."""
    if fitted is None or key not in fitted.values or not np.isfinite(fitted.sigma[key]):
        return None
    return float(fitted.values[key]), float(fitted.sigma[key])


def rms_ratio(runs, key: str, bound: str) -> float:
    """Root mean square of eps / bound over the runs."""
    return float(np.sqrt(np.mean([(r[key] / r[bound]) ** 2 for r in runs])))


def verdicts(runs, effect: str) -> dict:
    """Counts over the runs: right (the effect named first, or `none` with nothing unexplained
    for an effect-free case), nothing named but the effect in an ambiguous pair (and any
    ambiguous pair without it), unexplained with no name (nor ambiguity), a wrong name (another
    effect named first), silence (nothing named nor unexplained), sessions whose calibration
    after is worse than before by more than 1 sd of eps at the bound, sessions with an
    out-of-range fit."""
    first = [r["first"] for r in runs]
    among = [any(effect in g for g in r["ambiguous"]) for r in runs]
    return {
        "right": sum(f == effect and (effect != "none" or not r["unexplained"])
                     for f, r in zip(first, runs, strict=True)),
        "ambiguous_with_it": sum(f == "none" and a for f, a in zip(first, among, strict=True)),
        "ambiguous_without_it": sum(bool(r["ambiguous"]) and not a
                                    for r, a in zip(runs, among, strict=True)),
        "unexplained_unnamed": sum(f == "none" and bool(r["unexplained"]) and not a
                                   for f, r, a in zip(first, runs, among, strict=True)),
        "wrong_name": sum(f not in ("none", effect) for f in first),
        "silent": sum(f == "none" and not r["unexplained"] for f, r in zip(first, runs,
                                                                           strict=True)),
        "worse_by_more_than_1sd": sum(r["eps_after"] > r["eps_before"] + r["eps_sd_at_bound"]
                                      for r in runs),
        "out_of_range_not_named": sum(bool(r["resembles"]) for r in runs),
    }


def acceptance(seeds: int, cases=tuple(CASES), leave_out: bool = False, first: int = 0,
               **kwargs) -> dict:
    """Per case: the verdicts, gaps and eps over m in {3, 6, 12} and `seeds` seeds (1000 m +
    first + s); leave_out: the hidden effect is removed from the candidates too (then
    `unexplained` is the right verdict); kwargs: the sessions' timing, fs, n (`session`)."""
    out = {}
    for case in cases:
        effect = parse(spec(case))[0]
        runs = [run_case(case, m, 1000 * m + first + s, leave_out, **kwargs) for m in LAYOUTS
                for s in range(seeds)]
        right = [r["first"] == effect and len(r["named"]) <= 1 + (effect != "none")
                 and (effect != "none" or not r["unexplained"]) for r in runs]
        out[case] = {
            "sessions": len(runs),
            "right_rate": float(np.mean(right)),
            "right_interval_95": interval(sum(right), len(right)),
            "verdicts": verdicts(runs, effect),
            "named": [r["named"] for r in runs],
            "ambiguous": [r["ambiguous"] for r in runs],
            "unexplained": [r["unexplained"] for r in runs],
            "resembles": [r["resembles"] for r in runs],
            "correction_applied": [r["correction_applied"] for r in runs],
            "gap_before_max": {k: float(np.median([r["gap"][0][k] for r in runs]))
                               for k in runs[0]["gap"][0]},
            "gap_after_max": {k: float(max(r["gap"][-1][k] for r in runs))
                              for k in runs[0]["gap"][-1]},
            "eps_before_over_bound_rms": rms_ratio(runs, "eps_before", "crlb"),
            "eps_after_over_bound_rms": rms_ratio(runs, "eps_after", "crlb"),
            "eps_before_over_random_bound_rms": rms_ratio(runs, "eps_before", "crlb_random"),
            "eps_after_over_random_bound_rms": rms_ratio(runs, "eps_after", "crlb_random"),
            "random_bound_over_bound_rms": rms_ratio(runs, "crlb_random", "crlb"),
            "spread_fitted": [r["spread_fitted"] for r in runs],
            "gain_fitted": [r["gain_fitted"] for r in runs],
        }
    return out


VARIANTS = {
    "n12_200Hz": {"n": 12, "fs": 200.0, "first": 100},
    "n8_long": {"n": 8, "timing": RotaryTiming(), "first": 200},
    "fast_2turns": {"timing": RotaryTiming(rate=np.pi, max_accel=2.0, static=4.0, moving=10.0),
                    "first": 300},
}
"""Other sessions for the effect-free rate (`--none-variants`): 12 positions at 200 Hz; 8
positions of the default timeline (10 s static, 25 s moving: 5 whole turns); twice the rate
(2 whole turns in the short timeline). Seeds from 1000 m + first: a session of the same length
and seed draws the same unit and noise, so the variants do not reuse the short sessions' seeds."""


def pairs(seeds: int, first: int = 400) -> dict:
    """Per pair of PAIRS: how often both hidden effects are the first two named (nothing else
    before them), over m in {3, 6, 12} and `seeds` seeds (1000 m + first + s), with the sessions
    whose calibration got worse by more than 1 sd of eps at the bound."""
    out = {}
    for case in PAIRS:
        runs = [run_case(case, m, 1000 * m + first + s) for m in LAYOUTS for s in range(seeds)]
        both = [set(r["named"][:2]) == set(hidden(case)) for r in runs]
        out[case] = {"sessions": len(runs), "both_named_rate": float(np.mean(both)),
                     "both_named_interval_95": interval(sum(both), len(both)),
                     "named": [r["named"] for r in runs],
                     "unexplained": [r["unexplained"] for r in runs],
                     "worse_by_more_than_1sd": sum(r["eps_after"] > r["eps_before"]
                                                   + r["eps_sd_at_bound"] for r in runs)}
    return out


def interval(k: int, n: int) -> list:
    """Clopper-Pearson 95 % interval of a rate k / n."""
    ci = binomtest(k, n).proportion_ci(0.95, method="exact")
    return [float(ci.low), float(ci.high)]


def timing() -> dict:
    """Wall time of one 20-position, 12-channel, 200 Hz session (10 s static, 25 s moving)."""
    d, _ = session("earth_rate", 12, 7, timing=RotaryTiming(), fs=200.0)
    start = time.perf_counter()
    result = diagnose(d)
    return {"seconds": time.perf_counter() - start, "named": result.effects,
            "samples": int(np.prod(d.shape))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--seeds", type=int, default=4, help="sessions per case and m")
    parser.add_argument("--effects", nargs="+", choices=[*CASES, *QUANTISED],
                        default=list(CASES), help="cases (hidden effects) to run (default: all "
                        "of CASES)")
    parser.add_argument("--no-timing", action="store_true", help="skip the full-session timing")
    parser.add_argument("--leave-one-out", action="store_true",
                        help="also hide each effect AND remove it from the candidates")
    parser.add_argument("--none-variants", action="store_true",
                        help="also the effect-free case at the other timelines and rates "
                        "(VARIANTS)")
    parser.add_argument("--pairs", action="store_true",
                        help="also sessions hiding two effects at once (PAIRS)")
    parser.add_argument("--temperature", nargs="*", choices=list(WARM), default=None,
                        help="only the sessions recording the unit's temperature (issue 15): "
                        "these cases (default: all)")
    parser.add_argument("--coloured", nargs="*", choices=list(COLOURED), default=None,
                        help="only the issue 32 cases beside coloured noise (COLOURED; default: "
                        "all), m = 3")
    parser.add_argument("--noise-model", action="store_true",
                        help="--coloured: the unit's bias random walk and flicker, from the "
                        "Allan fit of a rest recording of it (rest_noise), in the diagnosis' "
                        "noise model")
    parser.add_argument("--open", nargs="*", choices=[*OPEN, *JUMPS, *POLYNOMIALS], default=None,
                        help="only the issue 32 cases of an effect no list names, the open "
                        "families' (OPEN; default: all), m = 3")
    parser.add_argument("--first-seed", type=int, default=0,
                        help="--temperature: seeds s from this one (1000 m + s)")
    args = parser.parse_args()
    if args.temperature is not None:
        warm = warm_acceptance(args.seeds, args.temperature or tuple(WARM), args.first_seed)
        if args.json:
            print(json.dumps({"temperature": warm}, indent=1))
            return
        for case, r in warm.items():
            lo, hi = r["interval_95"]
            print(f"{case:18s} right {r['right']} / {r['sessions']} (95 % {lo:.2f}-{hi:.2f}), "
                  f"offered {r['offered']}, max |z| tempco {r['tempco_z_max']}")
        return
    if args.open is not None:
        found = open_family(args.seeds, args.open or (*OPEN, *JUMPS, *POLYNOMIALS))
        if args.json:
            print(json.dumps({"open": found}, indent=1, default=float))
            return
        for case, r in found.items():
            print(f"{case:19s} " + ", ".join(f"{k} {v}" for k, v in r.items() if k != "named"))
        return
    if args.coloured is not None:
        found = coloured(args.seeds, args.coloured or tuple(COLOURED),
                         noise_model=args.noise_model)
        if args.json:
            print(json.dumps({"coloured": found}, indent=1, default=float))
            return
        for case, r in found.items():
            print(f"{case:19s} " + ", ".join(f"{k} {v}" for k, v in r.items()
                                             if k not in ("runs", "closes")))
        return
    out = {"acceptance": acceptance(args.seeds, args.effects)}
    if args.pairs:
        out["pairs"] = pairs(args.seeds)
    if args.none_variants:
        out["none_variants"] = {k: acceptance(args.seeds, ["none"], **v)["none"]
                                for k, v in VARIANTS.items()}
    if args.leave_one_out:
        out["leave_one_effect_out"] = acceptance(
            args.seeds, [c for c in args.effects if c not in ("none", "rate_error_encoder")],
            leave_out=True)
    if not args.no_timing:
        out["timing_full_session"] = timing()
    if args.json:
        print(json.dumps(out, indent=1))
        return
    if not args.no_timing:
        print(f"full session: {out['timing_full_session']['seconds']:.1f} s")
    for case, r in out.get("none_variants", {}).items():
        print(f"none {case:14s} right {r['right_rate']:.2f} of {r['sessions']} "
              f"(95 % {r['right_interval_95']})")
    for case, r in out.get("pairs", {}).items():
        print(f"pair {case:30s} both named {r['both_named_rate']:.2f} of {r['sessions']} "
              f"(95 % {r['both_named_interval_95']})")
    for case, r in out.get("leave_one_effect_out", {}).items():
        print(f"left out {case:19s} {r['verdicts']}")
    for case, r in out["acceptance"].items():
        print(f"{case:19s} {r['verdicts']}")
        print(f"{case:19s} right {r['right_rate']:.2f} of {r['sessions']}  eps/bound "
              f"{r['eps_before_over_bound_rms']:.2f} -> {r['eps_after_over_bound_rms']:.2f}  "
              f"eps/random-effects bound {r['eps_before_over_random_bound_rms']:.2f} -> "
              f"{r['eps_after_over_random_bound_rms']:.2f}")


if __name__ == "__main__":
    main()
