"""The digital twin replaying a measured rotary session with fitted parameters.

Same timeline, table profile and cumulative table angle as the data; the unit's orientation on
the table is the fitted axis u_j = v_j / |v_j| completed by an arbitrary azimuth (effects tied to
the table's heading carry their own per-position heading or phase). The noise-free expected
series is built in the simulator's order (docs/simulator.md) with each model extension's `apply`,
which calls the simulator's own effect functions: motion (rate_error, axis_wobble, earth_rate) ->
projection a^T omega -> sensed signal (scale_nonlinearity, latency) -> biases (bias_drift,
temperature at the recorded temperature; one bias per sensor, the mean of the data minus the
rest) -> output (saturation, as an expectation).
"""

from dataclasses import dataclass

import numpy as np

from station.model import sensing

ORDER = ("rate_error", "axis_wobble", "earth_rate", *sensing.SENSED, *sensing.OFFSETS,
         "temperature", *sensing.OUTPUT)
"""Names of the model extensions in the order the twin applies them: the motion, then the sensor
output chain's (station.model.sensing)."""


@dataclass(frozen=True)
class Context:
    """What a model extension needs: data, the nominal calibration (a, v), noise and geometry."""

    data: object
    a: np.ndarray  # (d, m)
    v: np.ndarray  # (d, n)
    sigma: np.ndarray  # (m,) per-sample noise
    orientation: np.ndarray  # (n, 3, 3): columns p, q, u (table frame -> unit frame)


@dataclass(frozen=True)
class Prediction:
    """The twin's noise-free series: rate (n, k) true table rate, s = a^T omega (n, k, m) the
    sensed rate, mu (n, k, m) the output before clipping, z (n, k, m) the expected output, b (m,)
    the biases (s None when not asked for: `predict`). Each (n, k, m) array is of the session's
    size: a Prediction is made for one use and dropped (station.diagnose.model.Model recomputes
    its own)."""

    rate: np.ndarray
    s: np.ndarray
    mu: np.ndarray
    z: np.ndarray
    b: np.ndarray


def completion(u: np.ndarray) -> np.ndarray:
    """(n, 3, 3) right-handed frames [p, q, u] with the given unit third columns u (n, 3)."""
    ref = np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    p = ref - np.sum(ref * u, 1, keepdims=True) * u
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return np.stack([p, np.cross(u, p), u], axis=2)


def context(data, a, v, sigma) -> Context:
    """The Context of a calibration (a, v) of `data`."""
    u = (v / np.linalg.norm(v, axis=0)).T
    return Context(data, np.asarray(a, float), np.asarray(v, float), np.asarray(sigma, float),
                   completion(u))


def predict(ctx: Context, fitted: dict, extensions: dict, sensed: bool = True) -> Prediction:
    """The expected series of the model: nominal plus the `fitted` extensions ({name: Fitted}),
    each at its stage: the motion's by extensions[name].apply, the sensor's through the output
    chain's stages (station.model.sensing: sensed, offsets) with extensions[name].params, the
    output's (an expectation over the noise) by extensions[name].apply. Without `sensed` the
    sensed rate s is not kept (None): its array becomes z's, one array of the session's size
    fewer (the extensions' fits read s; the statistics read z and mu)."""
    data = ctx.data
    active = [name for name in ORDER if name in fitted]
    stage = {name: extensions[name].STAGE for name in active}
    rate = np.broadcast_to(data.rate, data.angle.shape)
    for name in active:
        if stage[name] == "rate":
            rate = extensions[name].apply(ctx, fitted[name], rate)
    omega = rate[..., None] * ctx.orientation[:, None, :, 2]
    for name in active:
        if stage[name] == "motion":
            omega = extensions[name].apply(ctx, fitted[name], omega, rate)
    s = omega @ ctx.a
    del omega  # (n, k, d): no extension reads it once s is made
    sensor = {name: extensions[name].params(fitted[name]) for name in active
              if stage[name] in ("sensed", "offset")}
    z = sensing.sensed(s, data.t, sensor)
    if z is s and sensed:
        z = z.copy()  # s is kept
    sensing.offsets(data.t_session, rate, sensor, out=z)  # in place: z is this function's own
    s = s if sensed else None
    for name in active:
        if stage[name] == "temperature":
            z += extensions[name].apply(ctx, fitted[name])
    b = data.y_mean - z.mean((0, 1))
    z += b  # in place: z is this function's own array (the sum above made it)
    mu = z
    for name in active:
        if stage[name] == "output":
            z = extensions[name].apply(ctx, fitted[name], z)
    return Prediction(rate, s, mu, z, b)


def residual(ctx: Context, prediction: Prediction) -> np.ndarray:
    """Measured minus expected series (n, k, m), made in the prediction's z (a prediction is
    made for one use: `RotaryData.residual`)."""
    return ctx.data.residual(prediction.z)
