"""`station diagnose` on a free-static session: still intervals, their twin, the named effects a
static session can show (docs/diagnose.md, "Free-static sessions").

Data: the accelerometer stream (m >= 3 channels) and optionally a gyro stream (3 channels), SI
units, its outliers replaced (station.diagnose.outliers), cut into still intervals
(station.reduce.stillness.detect_still: on all channels, or as the user's `StillOptions` say: the
command line's default is the accelerometer with the gyro's veto) and each interval into bins of
about `BIN_S` seconds. Noise sigma_i = the pooled scatter of the samples within the bins
(white-noise assumption) and the part of the quantisation error a mean keeps
(station.diagnose.quantisation: 0 unless the channel is quantised coarser than its noise).

Nominal model (the free-static calibration, station.reduce.free_static): accelerometer bin means
a^T v_j + b with |v_j| = g in interval j (ellipsoid closed form + ML, station.calibrate), gyro
bin means = one bias per channel. The twin predicts every bin of every still interval; the
model's deviance is the chi2 of the bin means (white noise: var = sigma_i^2 / samples; a pose
mean keeps the quantisation error common to its bins: `StaticData.whiten`) plus the
rail pile-up deviance (station.diagnose.rails). Every extension is fitted jointly with the
calibration (v_j, a upper triangular, b) by weighted nonlinear least squares on the bins; its
evidence is the deviance decrease (station.diagnose.select).
"""

import itertools
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import f as f_law

from station.diagnose import (
    coloured,
    goodness,
    heldout,
    outliers,
    plausibility,
    quantisation,
    rails,
)
from station.diagnose.effects import Fitted, tone_null
from station.diagnose.effects import saturation as saturation_ext
from station.diagnose.select import Diagnosis, greedy, settle
from station.errors import CalibrationInputError
from station.model import measurement, sensing
from station.model.constants import STANDARD_GRAVITY
from station.model.earth import OMEGA_EARTH
from station.model.effects import earth_rate, g_sensitivity
from station.model.effects.bias_drift import BiasDrift
from station.model.effects.earth_rate import EarthRate
from station.model.effects.g_sensitivity import GSensitivity
from station.model.effects.scale_nonlinearity import ScaleNonlinearity
from station.reduce.stillness import StillOptions, detect_still
from station.solve.calibrate import calibrate

BIN_S = 1.0
"""Target bin length, s: each still interval is cut into floor(T / BIN_S) bins (at least 1)."""
SCALES_S = (0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0)
"""Block lengths of the white-noise check (scatter of block means against sigma^2 / samples)."""
CANDIDATES = ("bias_drift", "scale_nonlinearity", "saturation", "earth_rate", "g_sensitivity")
NOT_TESTABLE = {
    "rate_error": "needs the table's commanded rate (rotary sessions only)",
    "axis_wobble": "needs the table turning (a tone at the table rate)",
    "latency": "needs a known motion to delay (spin-up and spin-down of the table)",
}
TAU_GRID = np.geomspace(1 / 30, 1.0, 7)
"""Warm-up time constants of `bias_drift`, as fractions of the session length."""


@dataclass(frozen=True)
class StaticData:
    """A free-static session as the diagnosis sees it.

    x : (K, c) samples, SI units (or raw counts of them); the first m channels are the
        accelerometer, the others (0 or 3) the gyro.  t : (K,) s from the first sample.
    intervals : (P, 2) still intervals [start, stop).  bins : (B, 2) [start, stop) inside them;
    bin_interval : (B,) interval of each bin.  lsb : (c,) quantisation step of each channel.
    outliers : (K, c) the samples found to be outliers (station.diagnose.outliers): x holds their
        neighbours' median instead.
    """

    x: np.ndarray
    t: np.ndarray
    fs: float
    m: int
    gravity: float
    intervals: np.ndarray
    bins: np.ndarray
    bin_interval: np.ndarray
    lsb: np.ndarray
    outliers: np.ndarray
    units: tuple = ()
    notes: tuple = ()
    random_walk: np.ndarray | None = None
    bias_instability: np.ndarray | None = None

    @property
    def coloured(self) -> bool:
        """Whether a bias random walk or flicker ((c,) per channel, 0 where a channel has none:
        a calibration file's noise figures) is in the noise model: the poses' means are then
        judged by generalised least squares against it (`whiten`)."""
        return self.random_walk is not None or self.bias_instability is not None

    @property
    def c(self) -> int:
        return self.x.shape[1]

    @property
    def gyro(self) -> bool:
        return self.c > self.m

    @cached_property
    def still(self) -> np.ndarray:
        """Sample indices of the bins, in order."""
        return np.concatenate([np.arange(a, z) for a, z in self.bins])

    def outlier_test(self, alpha: float) -> dict:
        """The outliers of the still samples against Gaussian noise (station.diagnose.outliers)."""
        return outliers.test(self.outliers[self.still], alpha)

    @cached_property
    def lengths(self) -> np.ndarray:
        """(B,) samples per bin."""
        return self.bins[:, 1] - self.bins[:, 0]

    def binmean(self, y: np.ndarray) -> np.ndarray:
        """(B, ...) means of per-sample values y (K, ...) over the bins."""
        return self._binsum(y[self.still]) / self.lengths.reshape((-1,) + (1,) * (y.ndim - 1))

    def _binsum(self, values: np.ndarray) -> np.ndarray:
        """(B, ...) sums over the bins of values (still samples, ...) given in `still`'s order."""
        return np.add.reduceat(values, np.concatenate([[0], np.cumsum(self.lengths)[:-1]]),
                               axis=0)

    @cached_property
    def z(self) -> np.ndarray:
        """(B, c) measured bin means."""
        return self.binmean(self.x)

    @cached_property
    def bin_squares(self) -> np.ndarray:
        """(B, c) each bin's sum of its samples' squared deviations from its mean."""
        return self._binsum((self.x[self.still] - np.repeat(self.z, self.lengths, axis=0)) ** 2)

    @cached_property
    def scatter(self) -> np.ndarray:
        """(c,) the samples' scatter about their bin means, pooled over the bins."""
        return np.sqrt(self.bin_squares.sum(0) / (self.still.size - len(self.bins)))

    @cached_property
    def analog(self) -> np.ndarray:
        """(c,) noise sigma before quantisation (station.diagnose.quantisation)."""
        return quantisation.analog_sigma(self.scatter, self.lsb)

    @cached_property
    def kept(self) -> np.ndarray:
        """(c,) variance of the quantisation error that a mean keeps (0 when the noise dithers
        the grid; up to step^2 / 12 for a channel quieter than its step)."""
        return quantisation.kept(self.analog, self.lsb)

    @cached_property
    def sigma(self) -> np.ndarray:
        """(c,) noise sigma of a sample: the scatter within the bins and the quantisation error
        that the means keep (the scatter alone when the noise dithers the grid)."""
        return np.sqrt(self.scatter**2 + self.kept)

    @cached_property
    def coarse(self) -> np.ndarray:
        """(c,) channels quantised coarser than their noise (station.diagnose.quantisation)."""
        return quantisation.coarse(self.lsb, self.analog)

    def mean_sigma(self, n) -> np.ndarray:
        """(..., c) sigma of a mean of n (...,) samples: scatter^2 / n + kept."""
        n = np.asarray(n, float)[..., None]
        return np.sqrt(self.scatter**2 / n + self.kept)

    def whiten(self, r: np.ndarray) -> np.ndarray:
        """(B, c) bin residuals r whitened: their part about their interval's mean by the
        samples' sigma, that mean by its own (`mean_sigma`, which keeps the quantisation error
        common to the interval's bins); with white noise sqrt(samples) r / sigma. With coloured
        noise the intervals' means are whitened together (`mean_whitening`), each whitened mean
        spread over its bins as the white one is (sum of squares and interval sums kept)."""
        n = self.interval_means[1]
        w = self.lengths[:, None]
        means = self.interval_mean(r)
        whitened = (np.stack([f @ means[:, i] for i, f in enumerate(self.mean_whitening)], 1)
                    if self.coloured else means / self.mean_sigma(n))
        mean = means[self.bin_interval]
        return (np.sqrt(w) * (r - mean) / self.bin_sigma
                + np.sqrt(w / n[self.bin_interval, None]) * whitened[self.bin_interval])

    @cached_property
    def bin_sigma(self) -> np.ndarray:
        """(B, c) the sample sigma a bin's part about its interval's mean is judged by: `sigma`,
        and on a channel quantised coarser than its noise (`coarse`) its own interval's scatter,
        at least the noise before quantisation (`sigma` where no sample departs from its
        channel's values and that noise reads 0): there most poses read one value and the few
        whose level sits at a step's edge flip between two, so the pooled scatter misjudges
        both (a 12-sigma step: `within` and `trend` unexplained, warm-up and saturation named)."""
        out = np.broadcast_to(self.sigma, (len(self.bins), self.c)).copy()
        if not self.coarse.any():
            return out
        squares = self.interval_sum(self.bin_squares)
        dof = np.maximum(self.interval_sum((self.lengths - 1)[:, None])[:, 0], 1)
        floor = np.where(self.analog > 0, self.analog, self.sigma)  # every sample one value: sigma
        own = np.maximum(np.sqrt(squares / dof[:, None]), floor)[self.bin_interval]
        out[:, self.coarse] = own[:, self.coarse]
        return out

    @cached_property
    def mean_whitening(self) -> list:
        """Per channel (P, P) L^-1, L the Cholesky factor of the intervals' means' covariance:
        `mean_sigma` and the coloured terms over the intervals' time spans with the free level
        the bias gives (station.diagnose.coloured.level_covariance)."""
        n = self.interval_means[1]
        spans = np.stack([self.t[self.intervals[:, 0]], self.t[self.intervals[:, 1] - 1]],
                         1) + np.array([-0.5, 0.5]) / self.fs
        spans -= spans[0, 0]
        shapes = [(scale, coloured.level_covariance(spans, term))
                  for term, scale in coloured.present(self)]
        return [np.linalg.inv(np.linalg.cholesky(cov))
                for cov in coloured.sensor_covariances(self.mean_sigma(n).T ** 2, shapes)]

    def bin_weights(self) -> np.ndarray:
        """(B, c) each bin's weight in its interval's mean over that mean's variance: summed
        over an interval, the information of its mean (white noise: samples / sigma^2)."""
        n = self.interval_means[1][self.bin_interval]
        return self.lengths[:, None] / n[:, None] / self.mean_sigma(n) ** 2

    def quantisation(self, names=(), units=()) -> dict:
        """The step, noise and coarseness of each channel (station.diagnose.quantisation)."""
        return quantisation.report(self.lsb, self.analog, names or [""] * self.c,
                                   units or [""] * self.c)

    @cached_property
    def interval_means(self) -> tuple:
        """(P, c) means of each still interval and (P,) their samples."""
        return self.interval_mean(self.z), np.bincount(self.bin_interval, self.lengths)

    def interval_mean(self, y: np.ndarray) -> np.ndarray:
        """(P, k) each still interval's mean of the bin values y (B, k), bins weighted by their
        samples."""
        return (self.interval_sum(self.lengths[:, None] * y)
                / np.bincount(self.bin_interval, self.lengths, len(self.intervals))[:, None])

    def interval_sum(self, y: np.ndarray) -> np.ndarray:
        """(P, k) each still interval's sum of the bin values y (B, k)."""
        return np.stack([np.bincount(self.bin_interval, y[:, i], len(self.intervals))
                         for i in range(y.shape[1])], 1)


def from_arrays(accel, fs: float, *, gyro=None, gravity: float = STANDARD_GRAVITY,
                units=(), notes=(), still: StillOptions | None = None, **detector) -> StaticData:
    """StaticData of accelerometer samples (K, m) and optional gyro samples (K, 3) at fs Hz;
    `still`: the user's detector settings (`StillOptions`; channels unless given: the
    accelerometer with the gyro's veto when there is a gyro, whose still means the diagnosis
    models too; None: every channel decides), `detector`: options of
    station.reduce.stillness.detect_still."""
    acc = np.asarray(accel, float)
    if acc.ndim != 2 or acc.shape[1] < 3 or acc.shape[0] < 10:
        raise CalibrationInputError(f"accelerometer samples have shape {acc.shape}.",
                                    "Give a (samples, m >= 3) accelerometer stream.")
    x = acc
    if gyro is not None:
        g = np.asarray(gyro, float)
        if g.shape != (acc.shape[0], 3):
            raise CalibrationInputError(
                f"gyro samples have shape {g.shape}, accelerometer {acc.shape}.",
                "Give a 3-axis gyro on the same time base (or no gyro).")
        x = np.hstack([acc, g])
    if still is not None:
        m = acc.shape[1]
        default = "acc" if gyro is None else "acc+gyro"
        detector = {**still.detector(fs, range(m), range(m, x.shape[1]), default=default),
                    **detector}
    lsb = quantisation.step(x)
    cleaned = outliers.clean(x, lsb)
    x = cleaned.x
    found = detect_still(x, fs, floor=lsb**2 / 12, **detector)
    if len(found.intervals) < 9 + 1:
        vetoed = "gyro" in detector.get("groups", {})
        raise CalibrationInputError(
            f"only {len(found.intervals)} still intervals found"
            f"{' (the gyro vetoing)' if vetoed else ''}; {len(found.rejected)} candidates "
            f"rejected{': ' + found.rejected[0][2] + ', ...' if found.rejected else ''}.",
            "A free-static diagnosis needs at least 10 poses (9 calibration parameters)"
            + ("; --still-channels acc lets the accelerometer alone decide (the gyro effects are "
               "then judged on poses where it may still move)" if vetoed else
               "; --threshold, --min-still or --rest may keep more") + ".")
    still = found
    bins, owner = _bins(still.intervals, round(BIN_S * fs))
    return StaticData(x, np.arange(len(x)) / fs, float(fs), acc.shape[1], float(gravity),
                      still.intervals, bins, owner, lsb, cleaned.flags, tuple(units),
                      tuple(notes))


def _bins(intervals: np.ndarray, n: int):
    """(B, 2) bins of about n samples covering each interval, and their interval index."""
    bins, owner = [], []
    for j, (a, z) in enumerate(intervals):
        k = max((z - a) // n, 1)
        edges = a + np.round(np.linspace(0, z - a, k + 1)).astype(int)
        bins += list(itertools.pairwise(edges))
        owner += [j] * k
    return np.array(bins), np.array(owner)


# ------------------------------------------------------------------------------------- model


@dataclass(frozen=True)
class Base:
    """What every model of a session starts from: the nominal calibration and fixed geometry.

    cal : the nominal calibration (station.calibrate, canonical frame), or None when the poses
          do not determine the ellipsoid (e.g. six faces, each visited by hand several times):
          the accelerometer's nominal model is then one free mean per interval (`pose`: (P,)
          the mean each interval uses).
    tangents : (P, 3, 2) orthonormal tangents of the nominal v_j (the v_j are moved in them).
    up : (P, 3) gravity direction of each interval in the accelerometer's own axes (the frame
         nearest the nominal layout: a gyro triad on the same board shares it to ~1 deg).
    horizontal : (P, 3, 2) orthonormal basis perpendicular to up.
    rails : (2, c) lowest and highest value of the still samples; lsb (c,).
    """

    cal: object
    pose: np.ndarray
    tangents: np.ndarray
    up: np.ndarray
    horizontal: np.ndarray
    rails: np.ndarray


def _perp(u: np.ndarray) -> np.ndarray:
    """(P, 3, 2) orthonormal bases of the planes perpendicular to the unit vectors u (P, 3)."""
    q = np.linalg.svd(np.eye(3)[None] - u[:, :, None] * u[:, None, :])[0]
    return q[:, :, :2]


def base(data: StaticData) -> Base:
    """Nominal calibration of the interval means (weighted by sigma_i / sqrt(samples))."""
    means, n = data.interval_means
    m = data.m
    sigma = data.mean_sigma(n)[:, :m].T
    pose = np.arange(len(means))
    rail = np.stack([data.x[data.still].min(0), data.x[data.still].max(0)])
    try:
        cal = calibrate(means[:, :m].T, data.gravity, d=3, bias="estimate", sigma=sigma)
    except CalibrationInputError:
        up = means[:, :3] / np.linalg.norm(means[:, :3], axis=1, keepdims=True)
        return Base(None, pose, None, up, _perp(up), rail)
    v = cal.v if m != 3 else calibrate(means[:, :m].T, data.gravity, d=3, bias="estimate",
                                       sigma=sigma, nominal=np.eye(3)).v
    up = (v / np.linalg.norm(v, axis=0)).T
    vc = (cal.v / np.linalg.norm(cal.v, axis=0)).T
    return Base(cal, pose, _perp(vc), up, _perp(up), rail)


@dataclass(frozen=True)
class Layout:
    """Packing of the parameter vector: name -> slice, for a set of extensions."""

    slices: dict = field(default_factory=dict)

    @classmethod
    def of(cls, data: StaticData, b0: Base, names) -> "Layout":
        m, p, q = data.m, len(data.intervals), data.c - data.m
        if b0.cal is None:
            sizes = {"mu": m * (b0.pose.max() + 1), "b": data.c}
        else:
            sizes = {"a": 3 * m - 3, "b": data.c, "v": 2 * p}
        if "scale_nonlinearity" in names:
            sizes["k2"] = m
        if "bias_drift" in names:
            sizes["warmup"] = sizes["slope"] = data.c
        if "g_sensitivity" in names and q:
            sizes["gsens"] = 9
        if "earth_rate" in names and q:  # the vertical part is in G's trace when G is fitted
            sizes["earth"] = 1 if "gsens" in sizes else 2
        out, i = {}, 0
        for k, s in sizes.items():
            out[k] = slice(i, i + s)
            i += s
        return cls(out)

    @property
    def size(self) -> int:
        return max(s.stop for s in self.slices.values())

    def unpack(self, theta) -> dict:
        return {k: theta[s] for k, s in self.slices.items()}


def _a_matrix(values: np.ndarray, m: int) -> np.ndarray:
    """(3, m) sensitivity, upper triangular in its first three columns (the canonical frame)."""
    a = np.zeros((3, m))
    a[np.triu_indices(3, 0, m)] = values
    return a


def _a_values(a: np.ndarray) -> np.ndarray:
    return a[np.triu_indices(3, 0, a.shape[1])]


def predict(data: StaticData, b0: Base, names, p: dict, basis=None) -> np.ndarray:
    """(B, c) bin means the model predicts (the twin), for parameters p (Layout.unpack) and the
    drift basis of bias_drift's time constant (`drift_basis`)."""
    out = np.zeros(data.z.shape)
    if "mu" in p:
        out[:, :data.m] = p["mu"].reshape(-1, data.m)[b0.pose][data.bin_interval]
        s = None
    else:
        a = _a_matrix(p["a"], data.m)
        v = b0.cal.v / np.linalg.norm(b0.cal.v, axis=0)
        v = v + np.einsum("pik,pk->ip", b0.tangents, p["v"].reshape(-1, 2))
        v = data.gravity * v / np.linalg.norm(v, axis=0)
        s = measurement.forward(a, v).T[data.bin_interval]
    if s is not None:
        sensed = {"scale_nonlinearity": ScaleNonlinearity(tuple(p["k2"]))} if "k2" in p else {}
        out[:, :data.m] = sensing.sensed(s, None, sensed)  # bin means: no latency here
    out += p["b"]
    if "warmup" in p:
        warm, slope = basis
        out += warm[:, None] * p["warmup"] + slope[:, None] * p["slope"]
    if "gsens" in p:
        out[:, data.m:] = g_sensitivity.apply(out[:, data.m:], specific_force(data, b0)[
            data.bin_interval], GSensitivity(tuple(p["gsens"])))
    if "earth" in p:
        u, north = earth_parts(p)
        out[:, data.m:] += earth_rates(b0, u, north, headings(data, b0, u, out))[
            data.bin_interval]
    if "saturation" in names:
        out = clipped(out, b0.rails, data.analog)
    return out


def specific_force(data: StaticData, b0: Base) -> np.ndarray:
    """(P, 3) specific force of each interval in the accelerometer's own axes: g up_j."""
    return data.gravity * b0.up


def gsens(p: dict) -> np.ndarray:
    """The 3 x 3 g-sensitivity G of the parameters (row-major), gyro output per m/s^2."""
    return p["gsens"].reshape(3, 3)


def earth_parts(p: dict) -> tuple:
    """(vertical U, horizontal N) of the Earth-rate parameters; U = 0 when G is fitted too (the
    vertical part U up_j = (U / g) I f_j is then one direction of G)."""
    e = p["earth"]
    return (0.0, e[0]) if e.size == 1 else (e[0], e[1])


def earth_rates(b0: Base, u: float, north: float, h: np.ndarray) -> np.ndarray:
    """(P, 3) Earth rate of each interval in the unit's axes: vertical part u along up_j,
    horizontal part north at heading h_j (P,) in the horizontal plane: the simulator's
    station.model.effects.earth_rate with the interval's frame [horizontal, up] as the table's and
    latitude atan2(u, north)."""
    frames = np.concatenate([b0.horizontal, b0.up[:, :, None]], axis=2)
    p = EarthRate(latitude_deg=float(np.degrees(np.arctan2(u, north))), heading_deg=0.0,
                  rate=float(np.hypot(u, north)))
    return earth_rate.apply(np.zeros((len(h), 1, 3)), frames, -h[:, None], p)[:, 0]


def headings(data: StaticData, b0: Base, u: float, rest: np.ndarray) -> np.ndarray:
    """(P,) heading of the Earth rate's horizontal part in each interval, profiled out: the
    direction of the free 2-D weighted fit of the horizontal gyro residual net of the vertical
    part u and the rest of the model `rest` (B, c) (station.diagnose.effects.tone_null's phase)."""
    w = data.bin_weights()[:, data.m:]
    r = (data.z - rest)[:, data.m:] - u * b0.up[data.bin_interval]
    g = np.stack([np.bincount(data.bin_interval, (w * r)[:, i], len(data.intervals))
                  for i in range(data.c - data.m)], 1)
    wp = np.stack([np.bincount(data.bin_interval, w[:, i], len(data.intervals))
                   for i in range(data.c - data.m)], 1)
    h = np.einsum("pik,pi,pil->pkl", b0.horizontal, wp, b0.horizontal)
    theta = np.linalg.solve(h, np.einsum("pik,pi->pk", b0.horizontal, g)[..., None])[..., 0]
    return np.arctan2(theta[:, 1], theta[:, 0])


def drift_basis(data: StaticData, tau: float):
    """Two (B,) bin means: of the unit warm-up exp(-t / tau) (station.model.effects.bias_drift,
    through the output chain's offsets) and of t / T (a linear drift over the session of length
    T)."""
    span = data.t[-1]
    warm = sensing.offsets(data.t[None], np.zeros((1, data.t.size)),
                           {"bias_drift": BiasDrift(warmup=1.0, warmup_tau=tau)})[0, :, 0]
    return data.binmean(warm), data.binmean(data.t / span)


def clipped(z: np.ndarray, rail: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """E[clip(z + e, low, high)], e ~ N(0, sigma^2): the saturation extension's expected output
    (station.diagnose.effects.saturation about the rails' centre)."""
    centre, half = rail.mean(0), (rail[1] - rail[0]) / 2
    ctx = _Sigma(sigma)
    fit = Fitted("saturation", {"range": half}, {}, 1)
    return centre + saturation_ext.apply(ctx, fit, z - centre)


@dataclass(frozen=True)
class _Sigma:
    sigma: np.ndarray


# ----------------------------------------------------------------------------- fit and loop


@dataclass(frozen=True)
class Model:
    """A fitted model of a free-static session: extensions {name: Fitted} in the order added."""

    fitted: dict
    params: dict  # Layout.unpack of the joint fit
    tau: float
    prediction: np.ndarray  # (B, c) the twin's bin means
    chi2: float
    rails: float
    calibration: object  # accelerometer calibration of the interval means net of the extensions
    base: Base

    @property
    def names(self) -> tuple:
        return tuple(self.fitted)

    @property
    def deviance(self) -> float:
        return self.chi2 + self.rails


def rail_deviance(data: StaticData, b0: Base, prediction: np.ndarray, clip: bool) -> float:
    """Poisson deviance of the still samples at each channel's lowest and highest value against
    the twin's expectation (station.diagnose.rails); not on coarse channels, whose poses read a
    few values each: the twin's means, fitted to the quantised ones, do not place the poses
    within a step, and a pose read at the rail is quantisation as much as a clip."""
    keep = ~data.coarse
    x = data.x[data.still][:, keep]
    mu = np.repeat(prediction, data.lengths, axis=0)[:, keep]
    low, high, lsb, sigma = b0.rails[0, keep], b0.rails[1, keep], data.lsb[keep], data.analog[keep]
    obs = np.stack([(x == low).sum(0), (x == high).sum(0)])
    exp = np.stack([
        rails.pile_up((mu - low - lsb / 2) / sigma, lsb / sigma, clip).sum(0),
        rails.pile_up((high - lsb / 2 - mu) / sigma, lsb / sigma, clip).sum(0),
    ])
    return rails.deviance(obs, exp)


def _start(data: StaticData, b0: Base, layout: Layout, start) -> np.ndarray:
    """Initial parameters: those of `start` where shared, else the nominal calibration."""
    theta = np.zeros(layout.size)
    p = layout.unpack(theta)  # views into theta
    if start is not None:
        for k, v in start.params.items():
            if k in p and p[k].size == v.size:
                p[k][:] = v
        if "gsens" in p and "earth" in start.params and start.params["earth"].size == 2:
            u, north = start.params["earth"]  # G on top of the Earth rate: U moves into G
            p["gsens"][:] = (u / data.gravity) * np.eye(3).ravel()
            p["earth"][:] = north
        if not ("earth" in p and "earth" not in start.params):
            return theta
    else:
        means, n = data.interval_means
        p["b"][data.m:] = means[:, data.m:].T @ n / n.sum()
        if b0.cal is None:
            p["mu"][:] = np.concatenate([means[b0.pose == k, :data.m].T @ n[b0.pose == k]
                                         / n[b0.pose == k].sum()
                                         for k in range(b0.pose.max() + 1)])
        else:
            p["a"][:] = _a_values(b0.cal.a)
            p["b"][:data.m] = b0.cal.bias
    if "earth" in p:  # from the gyro interval means net of the bias (and of G f)
        r = data.interval_means[0][:, data.m:] - p["b"][data.m:]
        if "gsens" in p:
            r = r - specific_force(data, b0) @ gsens(p).T
        north = np.mean(np.linalg.norm(np.einsum("pik,pi->pk", b0.horizontal, r), 1))
        p["earth"][:] = [north] if p["earth"].size == 1 else [
            np.mean(np.einsum("pi,pi->p", b0.up, r)), north]
    return theta


def _solve(data: StaticData, b0: Base, names, start, basis):
    """Weighted least squares of the bin means on the model with extensions `names`."""
    layout = Layout.of(data, b0, names)

    def residual(theta):
        return data.whiten(data.z - predict(data, b0, names, layout.unpack(theta),
                                             basis)).ravel()

    sol = least_squares(residual, _start(data, b0, layout, start), method="trf",
                        jac=_jacobian(residual, _touched(data, b0, layout)), x_scale="jac",
                        xtol=1e-12, ftol=1e-12, gtol=1e-10, max_nfev=200)
    cov = np.linalg.pinv(sol.jac.T @ sol.jac)
    return layout, sol.x, cov, float(2 * sol.cost)


def _touched(data: StaticData, b0: Base, layout: Layout) -> list:
    """For each parameter, the residuals (bin x channel, row-major) it moves."""
    m, c = data.m, data.c
    idx = np.arange(len(data.bins) * c).reshape(-1, c)
    mine = [np.flatnonzero(data.bin_interval == j) for j in range(len(data.intervals))]
    cols = []
    for name, sl in layout.slices.items():
        n = sl.stop - sl.start
        if name == "a":
            cols += [idx[:, i] for i in np.triu_indices(3, 0, m)[1]]
        elif name == "v":
            cols += [idx[mine[k // 2], :m].ravel() for k in range(n)]
        elif name == "mu":
            cols += [idx[np.isin(data.bin_interval, np.flatnonzero(b0.pose == k // m)), k % m]
                     for k in range(n)]
        elif name == "earth":
            cols += [idx[:, m:].ravel()] * n
        elif name == "gsens":  # G[i, k] moves gyro channel i
            cols += [idx[:, m + k // 3] for k in range(n)]
        else:  # one per channel: b, k2, warmup, slope
            cols += [idx[:, i] for i in range(n)]
    if data.coloured:  # the poses' means are whitened together: a parameter moves its channels
        cols = [idx[:, np.unique(rows % c)].ravel() for rows in cols]
    return cols


def _jacobian(fun, cols: list):
    """Forward-difference Jacobian of fun, perturbing together the parameters that move
    disjoint residuals (the pose and heading parameters of different intervals). scipy's own
    grouping (`least_squares(jac_sparsity=...)`) would force the inexact `lsmr` trust-region
    solver; this keeps the dense `exact` one."""
    groups, used = [], []
    size = 1 + max(int(r.max()) for r in cols)
    for k, rows in enumerate(cols):
        for g, u in zip(groups, used, strict=True):
            if not u[rows].any():
                g.append(k)
                u[rows] = True
                break
        else:
            groups.append([k])
            used.append(np.zeros(size, bool))
            used[-1][rows] = True

    def jac(theta):
        f0 = fun(theta)
        out = np.zeros((f0.size, theta.size))
        for g in groups:
            step = 1.49e-8 * np.maximum(1.0, np.abs(theta[g]))
            t = theta.copy()
            t[g] += step
            df = fun(t) - f0
            for k, h in zip(g, step, strict=True):
                out[cols[k], k] = df[cols[k]] / h
        return out

    return jac


def fit(data: StaticData, b0: Base, names=(), start=None) -> Model:
    """The model with extensions `names` fitted jointly with the calibration (the warm-up time
    constant of bias_drift on a grid, the smallest deviance kept)."""
    taus = data.t[-1] * TAU_GRID if "bias_drift" in names else [np.inf]
    best = None
    for tau in taus:
        basis = drift_basis(data, tau) if np.isfinite(tau) else None
        layout, theta, cov, chi2 = _solve(data, b0, names, start, basis)
        pred = predict(data, b0, names, layout.unpack(theta), basis)
        rail = rail_deviance(data, b0, pred, "saturation" in names)
        if best is None or chi2 + rail < best[0]:
            best = (chi2 + rail, layout, theta, cov, chi2, rail, pred, tau, basis)
    _, layout, theta, cov, chi2, rail, pred, tau, basis = best
    p = {k: v.copy() for k, v in layout.unpack(theta).items()}
    sig = {k: np.sqrt(np.maximum(np.diag(cov)[s], 0)) for k, s in layout.slices.items()}
    fitted = {name: _fitted(name, data, b0, p, sig, tau, taus, names) for name in names}
    return Model(fitted, p, tau, pred, chi2, rail, _calibration(data, b0, names, p, basis), b0)


CALIBRATION = {"d": 3, "bias": "estimate"}
"""Options of station.calibrate for the accelerometer's interval means."""


def _calibration(data: StaticData, b0: Base, names, p: dict, basis):
    """The accelerometer calibration of the interval means once the extensions' part of the
    twin is taken off (before the extensions: the nominal calibration)."""
    if not names or b0.cal is None:
        return b0.cal
    means, sigma = readings(data, b0, names, p, basis)
    return calibrate(means, data.gravity, sigma=sigma, **CALIBRATION)


def readings(data: StaticData, b0: Base, names, p: dict, basis) -> tuple:
    """((m, P) accelerometer interval means less what the extensions `names` (parameters p)
    add to the twin, their (m, P) standard errors)."""
    means, n = data.interval_means
    sigma = data.mean_sigma(n)[:, :data.m].T
    if not names:
        return means[:, :data.m].T, sigma
    bare = {k: np.zeros_like(v) if k in ("k2", "warmup", "slope") else v for k, v in p.items()}
    added = predict(data, b0, names, p, basis) - predict(data, b0, (), bare, basis)
    return (means[:, :data.m] - data.interval_mean(added[:, :data.m])).T, sigma


def correction(data: StaticData, model: Model) -> dict | None:
    """The held-out check of the final model's accelerometer correction (station.diagnose.
    heldout, an interval left out at a time); None without extensions or calibration."""
    if not model.fitted or model.base.cal is None:
        return None
    basis = drift_basis(data, model.tau) if np.isfinite(model.tau) else None
    scores = []
    for names in ((), model.names):
        means, sigma = readings(data, model.base, names, model.params, basis)
        scores.append(heldout.score(means, data.gravity, sigma, CALIBRATION))
    before, after = scores
    return {"held_out_chi2_before": before, "held_out_chi2_after": after,
            "positions": len(data.intervals), "applied": bool(after < before)}


def _fitted(name: str, data: StaticData, b0: Base, p: dict, sig: dict, tau, taus,
            names) -> Fitted:
    """The Fitted record of one extension from the joint fit's parameters and 1-sigma."""
    if name == "bias_drift":
        span = data.t[-1]
        return Fitted(name, {"warmup": p["warmup"], "warmup_tau": tau,
                             "drift_per_s": p["slope"] / span},
                      {"warmup": sig["warmup"], "drift_per_s": sig["slope"] / span,
                       "warmup_tau": np.nan},
                      dof=2 * data.c + 1,
                      notes=f"offset warmup_i exp(-t / tau) + drift_i t per channel (accelerometer "
                      f"then gyro); tau from the grid {np.round(taus, 1).tolist()} s")
    if name == "scale_nonlinearity":
        peak = np.abs(data.x[:, :data.m]).max(0)
        return Fitted(name, {"k2": p["k2"], "peak_signal": peak},
                      {"k2": sig["k2"], "peak_signal": np.full(data.m, np.nan)}, dof=data.m,
                      notes="output s + k2 s^2 per accelerometer channel, s = a_i . v in output "
                      "units; k2 in 1 / output unit")
    if name == "saturation":
        return Fitted(name, {"low": b0.rails[0], "high": b0.rails[1]},
                      {"low": data.lsb / 2, "high": data.lsb / 2}, dof=1,
                      notes="rails = the lowest and highest value of the still samples")
    if name == "g_sensitivity":
        return _gsens_fitted(data, p, sig, "earth_rate" in names)
    return _earth_fitted(data, b0, p, sig)


def _gsens_fitted(data: StaticData, p: dict, sig: dict, with_earth: bool) -> Fitted:
    """g-sensitivity: gyro interval means = b_g + G f_j (IEEE Std 528's g-sensitive bias), G
    linear: null law chi2(9), or chi2(8) beside the Earth rate (whose vertical part (U / g) I is
    one direction of G: U moves into G's trace)."""
    per_g = np.degrees(STANDARD_GRAVITY)  # rad/s per m/s^2 -> deg/s per g
    g, s = gsens(p), sig["gsens"].reshape(3, 3)
    gyro = channel_unit(data, data.m)
    return Fitted(
        "g_sensitivity",
        {"G": g, "G_deg_s_per_g": g * per_g},
        {"G": s, "G_deg_s_per_g": s * per_g},
        dof=8 if with_earth else 9,
        units={"G": f"{gyro} per m/s^2", "G_deg_s_per_g": "deg/s per g"},
        notes="gyro bias b + G f, f the specific force of the interval in the accelerometer's "
        "axes (m/s^2); G[i, k] = gyro channel i per f_k, in gyro output units per m/s^2 and in "
        f"deg/s per g (g = {STANDARD_GRAVITY}, for rad/s gyros); the Earth rate's vertical part "
        "is the special case G = (U / g) I",
    )


def _earth_fitted(data: StaticData, b0: Base, p: dict, sig: dict) -> Fitted:
    """Earth rate: vertical U along gravity, horizontal N with a free heading per interval.

    Null law: U enters linearly (chi2(1)); N with one free heading per interval is the tone fit
    of station.diagnose.effects.tone_null with the 2 x 2 normal matrices of the horizontal plane;
    the sum is moment-matched to scale * chi2(nu).
    """
    _, n = data.interval_means
    w = 1 / data.mean_sigma(n)[:, data.m:] ** 2  # (P, 3) information per axis
    h = np.einsum("pik,pi,pil->pkl", b0.horizontal, w, b0.horizontal)
    scale, nu = tone_null(h)
    vertical = p["earth"].size == 2  # else the vertical part is in G (g_sensitivity)
    mean, var = vertical + scale * nu, 2 * vertical + 2 * scale**2 * nu
    (u, north), s = earth_parts(p), sig["earth"]
    north, su = abs(north), s[0] if vertical else np.nan
    return Fitted(
        "earth_rate",
        {"vertical": u if vertical else np.nan, "horizontal": north,
         "rate": np.hypot(u, north) if vertical else np.nan,
         "latitude_deg": np.degrees(np.arctan2(u, north)) if vertical else np.nan},
        {"vertical": su, "horizontal": s[-1], "rate": np.hypot(u * su, north * s[-1])
         / max(np.hypot(u, north), 1e-300), "latitude_deg": np.nan},
        dof=len(data.intervals) + 1 + vertical,
        null=(var / (2 * mean), 2 * mean**2 / var),
        units={"vertical": channel_unit(data, data.m), "horizontal": channel_unit(data, data.m),
               "rate": channel_unit(data, data.m), "latitude_deg": "deg"},
        notes=f"gyro output units (Earth: {OMEGA_EARTH:.4e} rad/s); heading per interval is "
        "nuisance, profiled out (the unit is turned by hand); latitude = atan2(vertical, "
        "horizontal); a vertical part alone is also g-sensitivity G = (U / g) I, so the two "
        "compete (g_sensitivity); beside G only the horizontal part is fitted",
    )


def channel_unit(data: StaticData, channel: int) -> str:
    """The unit of a channel, as the session names it ("output units" when it does not)."""
    return data.units[channel] if channel < len(data.units) else "output units"


def untestable(data: StaticData, b0: Base) -> dict:
    """{effect: why this session cannot show it}."""
    out = dict(NOT_TESTABLE)
    if not data.gyro:
        out["earth_rate"] = out["g_sensitivity"] = "needs a gyro stream"
    if b0.cal is None:
        out["scale_nonlinearity"] = ("the poses do not determine the ellipsoid (too few distinct "
                                     "orientations), so the accelerometer has no shape to test")
    return out


GYRO_LAWS = ("earth_rate", "g_sensitivity")
"""Candidates that give the gyro's pose means a law in the orientation (`within_pose_scatter`)."""


def within_pose_scatter(data: StaticData, name: str, extended: Model, current: Model,
                        level: float) -> str:
    """"" or why a gyro law (GYRO_LAWS) is no effect: the poses' gyro means scatter about the
    model with it by more than their noise, and against that scatter its deviance decrease is
    not significant at `level`: F = (LR / (scale nu)) / (chi2_gyro / dof) with the law's null
    scale * chi2(nu) and the gyro gap's chi2 over its dof less nu, on F(nu, dof) (the scatter
    taken as at least the noise: the test only ever withholds). A gyro bias that moves from pose
    to pose (a shock at each turn, a cable's pull) projects on any law of the orientation: the
    chi2 test against the white noise alone names it."""
    from station.diagnose import static_report

    if name not in GYRO_LAWS:
        return ""
    scale, nu = extended.fitted[name].null_law
    dof = static_report.dofs(data, extended)["gyro"] - nu
    scatter = static_report.statistics(data, extended)["gyro"] * (dof + nu) / max(dof, 1)
    lr = max(current.deviance - extended.deviance, 0.0)
    log10_p = float(f_law.logsf(lr / (scale * nu) / max(scatter, 1.0), nu, max(dof, 1))
                    / np.log(10))
    if log10_p < np.log10(level):
        return ""
    return (f"the poses' gyro means scatter about it by {scatter:.2f} x their noise, and "
            f"against that scatter it is not significant (F test log10 p {log10_p:.1f}): a gyro "
            "bias that moves from pose to pose (pose_bias) explains it as well")


POSE_BIAS = {"why": "a gyro bias that moves from pose to pose (a shock at each turn, a cable's "
                    "pull) scatters the poses' gyro means, and against that scatter the law is "
                    "not significant",
             "told_apart_by": "earlier poses again (the Earth rate and g-sensitivity read the "
                              "same at the same orientation, a bias that moved does not)"}
"""How a gyro law withheld by `within_pose_scatter` is said: AMBIGUOUS with `pose_bias` (no
candidate: a free gyro bias per pose is the gyro's saturated model)."""


def said_ambiguous(result: Diagnosis) -> Diagnosis:
    """`result` with each gyro law that `within_pose_scatter` withheld at its last step (beside
    everything named: an effect named after an earlier step may explain what the law took
    there) said AMBIGUOUS with a bias moving from pose to pose (`POSE_BIAS`; issue 32 pattern
    5), with the other law if it was withheld too."""
    evidence = result.steps[-1].evidence
    held = [k for k in GYRO_LAWS if evidence.get(k, {}).get("within_noise")]
    for k in held:
        evidence[k].update(POSE_BIAS, ambiguous_with=sorted({*held, "pose_bias"} - {k}))
    return result


GAPS = {"bias_drift": ("between", "gyro", "trend"), "scale_nonlinearity": ("between",),
        "saturation": ("rails",), "earth_rate": ("gyro",), "g_sensitivity": ("gyro",)}
"""Gap statistics holding each candidate's signature (station.diagnose.select.settle)."""


def diagnose_static(data: StaticData, *, alpha: float = 0.01, max_effects: int = 3,
                    candidates=None, latitude_deg: float | None = None,
                    progress=None) -> Diagnosis:
    """The evidence loop of station.diagnose.select on a free-static session, each candidate
    within its physical range (station.diagnose.plausibility; rates are judged only when the
    gyro is in rad/s, not raw counts), then the final goodness-of-fit test of the gaps
    (station.diagnose.goodness); `progress` as `greedy`'s."""
    from station.diagnose import static_report, static_walk

    b0 = base(data)
    if candidates is None:
        candidates = tuple(c for c in CANDIDATES if c not in untestable(data, b0))
    site = plausibility.Site(latitude_deg, not any("raw counts" in n for n in data.notes))
    start = fit(data, b0)

    def run(excluded=()):
        return greedy(start, tuple(c for c in candidates if c not in excluded),
                      lambda current, names: fit(data, b0, names, current),
                      lambda m: static_report.statistics(data, m), alpha=alpha,
                      max_effects=max_effects,
                      check=lambda name, f: plausibility.check(name, f, site),
                      noise=lambda name, extended, current: within_pose_scatter(
                          data, name, extended, current, alpha / len(candidates)),
                      progress=progress)

    result, (test, _) = settle(run(), lambda step: (goodness.test(
        step.gap, static_report.dofs(data, step.model), alpha), None), alpha, GAPS, rerun=run)
    result = said_ambiguous(result)
    said = static_walk.caveat(data, result, alpha / len(candidates))
    checked = correction(data, result.final)
    if said and checked:  # drift or walk: corrected with neither (select: ambiguity)
        checked = {**checked, "applied": False, "withheld": "the drift may be the unit's walk"}
    return replace(result, fit_test=test, correction=checked, caveats=(said,) if said else (),
                   unexplained=[{**test["statistics"][k], "statistic": k,
                                 "signature": static_report.signature(data, result.final, k)}
                                for k in test["failed"]])
