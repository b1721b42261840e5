"""The sensor output chain shared by all protocols: sensed signal -> integer counts.

Order: scale_nonlinearity, latency (on the sensed signal a^T v), then biases, bias_drift, bias
random walk and white noise, then saturation, then quantisation.
"""

import dataclasses

import numpy as np

from station.model.effects import bias_drift, latency, saturation, scale_nonlinearity
from station.model.unit import SensorUnit

SENSOR_EFFECTS = {"scale_nonlinearity", "latency", "bias_drift", "saturation"}
"""Effects acting on the sensor's output; the others act on the motion (rotary protocol only)."""


def sense(
    unit: SensorUnit, s: np.ndarray, t: np.ndarray, t0: np.ndarray, rate: np.ndarray, effects: dict
) -> np.ndarray:
    """Counts (n, k, m) for the sensed signals s = a^T v (n, k, m) sampled at t (k,) per recording.

    t0 (n,) are the recordings' start times in session time; rate (n, k) is the table rate that
    heats the unit (zeros when nothing spins).
    """
    n, k, m = s.shape
    check_per_sensor(effects, m)
    if "scale_nonlinearity" in effects:
        s = scale_nonlinearity.apply(s, effects["scale_nonlinearity"])
    if "latency" in effects:
        s = latency.apply(s, t, effects["latency"])
    z = unit.noise((n, k, m))
    z += s
    z += unit.bias
    if "bias_drift" in effects:
        z += bias_drift.apply(t0[:, None] + t, rate, effects["bias_drift"])
    if np.any(unit.bias_walk):
        z += unit.walk(n, k, gaps=np.r_[0.0, np.diff(t0) - k / unit.fs])
    if "saturation" in effects:
        z = saturation.apply(z, effects["saturation"], unit.output_range)
    return unit.quantise(z)


def refuse_motion_effects(effects: dict, protocol: str) -> None:
    """Raise for effects that need the rotary table in a protocol without one."""
    extra = sorted(set(effects) - SENSOR_EFFECTS)
    if extra:
        raise ValueError(
            f"effect(s) {', '.join(extra)} need the rotary table; the {protocol} "
            f"protocol supports only {', '.join(sorted(SENSOR_EFFECTS))}"
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
