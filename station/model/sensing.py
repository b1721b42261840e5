"""The one sensor output chain: sensed signal -> effects -> integer counts (docs/simulator.md).

Order: the sensed signal s = a^T v goes through `sensed` (scale_nonlinearity, scale_asymmetry,
polynomial, then latency); the unit's white noise, its biases, the `offsets` (bias_drift) and the
bias random walk are added; `spiked` adds spikes (outliers); `saturate` clips (saturation); the
unit quantises. `sense` runs the whole chain for the batch simulator (station.sim: n recordings
of k samples) and, through `SensorUnit.sample`, for the live twins (one block of samples at a
time). The diagnosis' twins (station.diagnose.prediction, and station.diagnose.static) build
their noise-free expectation from the same stage functions.
"""

import dataclasses

import numpy as np

from station.model.effects import (
    bias_drift,
    latency,
    outliers,
    polynomial,
    saturation,
    scale_asymmetry,
    scale_nonlinearity,
)

SENSED = ("scale_nonlinearity", "scale_asymmetry", "polynomial", "latency")
"""Effects on the sensed signal a^T v, in the order applied."""
OFFSETS = ("bias_drift",)
"""Effects added to the output beside the biases."""
OUTPUT = ("outliers", "saturation")
"""Effects on the output before quantisation, in the order applied."""
SENSOR_EFFECTS = {*SENSED, *OFFSETS, *OUTPUT}
"""Effects acting on the sensor's output; the others act on the motion (rotary protocol only)."""
LIVE_EFFECTS = {"scale_nonlinearity", "scale_asymmetry", "polynomial", "bias_drift", "saturation"}
"""Sensor effects a live twin can apply block by block: latency interpolates within a recording
and bias_drift's heating integrates the table rate over the whole session (batch only)."""


def sensed(s: np.ndarray, t: np.ndarray, effects: dict) -> np.ndarray:
    """The sensed signals s (n, k, m) at times t (k,) after scale_nonlinearity, scale_asymmetry,
    polynomial, then latency."""
    if "scale_nonlinearity" in effects:
        s = scale_nonlinearity.apply(s, effects["scale_nonlinearity"])
    if "scale_asymmetry" in effects:
        s = scale_asymmetry.apply(s, effects["scale_asymmetry"])
    if "polynomial" in effects:
        s = polynomial.apply(s, effects["polynomial"])
    if "latency" in effects:
        s = latency.apply(s, t, effects["latency"])
    return s


def offsets(t_session: np.ndarray, rate: np.ndarray, effects: dict, out=None, heated=None):
    """Bias offsets (n, k, m) of bias_drift at session times (n, k) for the table rate (n, k),
    or 0 without it; with `out` (n, k, m), `out` plus them, added in place; `heated` the heat
    state (n, k) when already made (`bias_drift.apply`)."""
    if "bias_drift" in effects:
        return bias_drift.apply(t_session, rate, effects["bias_drift"], out, heated)
    return 0.0 if out is None else out


def spiked(z: np.ndarray, effects: dict, rng: np.random.Generator) -> np.ndarray:
    """Outputs z (..., m) with the spikes of outliers (drawn from `rng`), unchanged without it."""
    if "outliers" in effects:
        return outliers.apply(z, effects["outliers"], rng)
    return z


def saturate(z: np.ndarray, effects: dict, output_range: np.ndarray) -> np.ndarray:
    """Outputs z (..., m) clipped by saturation (at the unit's output_range unless it has its own
    range), unchanged without it."""
    if "saturation" in effects:
        return saturation.apply(z, effects["saturation"], output_range)
    return z


def sense(unit, s: np.ndarray, t: np.ndarray, t0: np.ndarray, rate: np.ndarray, effects: dict,
          walk=None, noise=None) -> np.ndarray:
    """Counts (n, k, m) of `unit` (a station.model.unit.SensorUnit) for the sensed signals
    s = a^T v (n, k, m) sampled at t (k,) per recording.

    t0 (n,) are the recordings' start times in session time; rate (n, k) is the table rate that
    heats the unit (zeros when nothing spins). `walk` () -> (n, k, m) draws the bias random walk
    (default: the batch walk of n recordings, continuing between them); `noise` () -> (n, k, m)
    the white noise (default: `unit.noise`).
    """
    n, k, m = s.shape
    check_per_sensor(effects, m)
    s = sensed(s, t, effects)
    z = unit.noise((n, k, m)) if noise is None else noise()
    z += s
    z += unit.bias
    z += offsets(t0[:, None] + t, rate, effects)
    if np.any(unit.bias_walk):
        z += walk() if walk is not None else unit.walk(
            n, k, gaps=np.r_[0.0, np.diff(t0) - k / unit.fs])
    return unit.quantise(saturate(spiked(z, effects, unit.rng), effects, unit.output_range))


def refuse_motion_effects(effects: dict, protocol: str) -> None:
    """Raise for effects that need the rotary table in a protocol without one."""
    extra = sorted(set(effects) - SENSOR_EFFECTS)
    if extra:
        raise ValueError(
            f"effect(s) {', '.join(extra)} need the rotary table; the {protocol} "
            f"protocol supports only {', '.join(sorted(SENSOR_EFFECTS))}"
        )


def refuse_batch_effects(effects: dict) -> None:
    """Raise for effects a live twin cannot apply block by block (LIVE_EFFECTS)."""
    extra = sorted(set(effects) - LIVE_EFFECTS)
    if "bias_drift" in effects and np.any(effects["bias_drift"].heating):
        extra.append("bias_drift heating")
    if extra:
        raise ValueError(
            f"effect(s) {', '.join(extra)} need the whole "
            f"session (station simulate); a live twin supports {', '.join(sorted(LIVE_EFFECTS))} "
            "(bias_drift without heating)"
        )


def check_per_sensor(effects: dict, m: int) -> None:
    """Raise unless every per-sensor parameter (a tuple) of a sensor effect has one value per
    sensor (the motion effects' tuples, e.g. g_sensitivity's matrix, are not per sensor)."""
    for name, params in effects.items():
        if name not in SENSOR_EFFECTS:
            continue
        for field in dataclasses.fields(params):
            value = getattr(params, field.name)
            if isinstance(value, tuple) and len(value) != m:
                raise ValueError(
                    f"effect {name}: {field.name} has {len(value)} values but the "
                    f"unit has {m} sensors; give one value or {m}"
                )
