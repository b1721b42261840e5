"""The digital twin replaying a measured rotary session with fitted parameters.

Same timeline, table profile and cumulative table angle as the data; the unit's orientation on
the table is the fitted axis u_j = v_j / |v_j| completed by an arbitrary azimuth (effects tied to
the table's heading carry their own per-position heading or phase). The noise-free expected
series is built in the simulator's order (docs/simulator.md) with each model extension's `apply`,
which calls the simulator's own effect functions: motion (rate_error, axis_wobble, earth_rate) ->
projection a^T omega -> sensed signal (scale_nonlinearity, latency) -> biases (bias_drift,
temperature at the recorded temperature, a jump; one bias per sensor, the mean of the data minus the
rest) -> output (saturation, as an expectation). Its series of the session's size are made a few
positions at a time (`Twin`).
"""

from dataclasses import dataclass, replace

import numpy as np

from station.model import sensing
from station.model.effects import bias_drift

ORDER = ("rate_error", "axis_wobble", "tone", "earth_rate", *sensing.SENSED, *sensing.OFFSETS,
         "temperature", "jump", *sensing.OUTPUT)
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
    """The twin's noise-free series at a few positions (`Twin.part`): rate (p, k) the true table
    rate, mu (p, k, m) the output before clipping, z (p, k, m) the expected output (the same
    array as mu without an output-stage extension)."""

    rate: np.ndarray
    mu: np.ndarray
    z: np.ndarray


@dataclass(frozen=True)
class Twin:
    """The twin of a model, its series of the session's size made a few positions at a time
    (`part`, `parts`; RotaryData.chunks), so that diagnose's memory is bounded by a chunk, not by
    the session: what is (n, k) is made whole (the rate after the rate-stage extensions, the
    heat state of bias_drift, which carries over from one position to the next), what is
    (n, k, m) per chunk.

    sensor : {name: parameters} of the output chain's sensed and offset stages.
    heat : (n, k) bias_drift's heat state, or None without heating.
    b : (m,) the biases, one per sensor: the mean of the data minus that of the rest (`predict`).
    """

    ctx: Context
    fitted: dict
    extensions: dict
    rate: np.ndarray
    sensor: dict
    heat: np.ndarray | None
    b: np.ndarray

    def sensed(self, rows: slice) -> np.ndarray:
        """(p, k, m) the sensed rate a^T omega at the positions `rows`: the motion's extensions
        applied (the extensions' fits read it)."""
        ctx = self.ctx
        rate = self.rate[rows]
        omega = rate[..., None] * ctx.orientation[rows, None, :, 2]
        for name in self._active("motion"):
            omega = self.extensions[name].apply(ctx, self.fitted[name], omega, rate, rows)
        return omega @ ctx.a

    def part(self, rows: slice) -> Prediction:
        """The expected series at the positions `rows`, biases included."""
        z = self._unbiased(rows)
        z += self.b  # in place: z is this function's own array
        mu = z
        for name in self._active("output"):
            z = self.extensions[name].apply(self.ctx, self.fitted[name], z)
        return Prediction(self.rate[rows], mu, z)

    def parts(self):
        """(rows, Prediction) of every chunk of positions, in order."""
        for rows in self.ctx.data.chunks():
            yield rows, self.part(rows)

    def residual(self, rows: slice) -> np.ndarray:
        """(p, k, m) measured minus expected series at the positions `rows`."""
        return self.ctx.data.residual(self.part(rows).z, rows)

    def _unbiased(self, rows: slice) -> np.ndarray:
        """(p, k, m) the expected output at the positions `rows` before the biases and the
        output stage: sensed stage, offsets, the offsets added beside them (temperature,
        jump)."""
        data = self.ctx.data
        z = sensing.sensed(self.sensed(rows), data.t, self.sensor)  # a new array: this one's
        heat = None if self.heat is None else self.heat[rows]
        sensing.offsets(data.session_times(rows), self.rate[rows], self.sensor, out=z,
                        heated=heat)
        for name in self._active("added"):
            z += self.extensions[name].apply(self.ctx, self.fitted[name], rows)
        return z

    def _active(self, stage: str) -> list:
        """The fitted extensions of `stage`, in the twin's ORDER."""
        return [name for name in ORDER
                if name in self.fitted and stage == self.extensions[name].STAGE]


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


def predict(ctx: Context, fitted: dict, extensions: dict, b=None) -> Twin:
    """The twin of the model: nominal plus the `fitted` extensions ({name: Fitted}), each at
    its stage: the rate's and the motion's by extensions[name].apply, the sensor's through the
    output chain's stages (station.model.sensing: sensed, offsets) with extensions[name].params,
    the added offsets' (temperature, jump) and the output's (an expectation over the noise) by
    extensions[name].apply. The biases `b` (m,) are the data's mean minus the rest's, found by
    one pass over the positions unless given (a model keeps its own: Model.b)."""
    data = ctx.data
    rate = np.broadcast_to(data.rate, data.angle.shape)
    for name in (n for n in ORDER if n in fitted and extensions[n].STAGE == "rate"):
        rate = extensions[name].apply(ctx, fitted[name], rate)
    sensor = {name: extensions[name].params(fitted[name]) for name in ORDER
              if name in fitted and extensions[name].STAGE in ("sensed", "offset")}
    drift = sensor.get("bias_drift")
    heat = (bias_drift.heat(data.t_session, rate, drift.heating_tau)
            if drift is not None and np.any(drift.heating) else None)
    twin = Twin(ctx, dict(fitted), extensions, rate, sensor, heat, np.zeros(data.shape[2]))
    if b is None:
        rest = sum(twin._unbiased(rows).sum((0, 1)) for rows in data.chunks())
        b = data.y_mean - rest / (data.shape[0] * data.shape[1])
    return replace(twin, b=np.asarray(b, float))
