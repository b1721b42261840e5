"""`station diagnose` on a free-static session: still intervals, their twin, the named effects a
static session can show (docs/diagnose.md, "Free-static sessions").

Data: the accelerometer stream (m >= 3 channels) and optionally a gyro stream (3 channels), SI
units, cut into still intervals (station.stillness.detect_still on all channels) and each
interval into bins of about `BIN_S` seconds. Noise sigma_i = the pooled scatter of the samples
within the bins (white-noise assumption).

Nominal model (the free-static calibration, station.free_static): accelerometer bin means
a^T v_j + b with |v_j| = g in interval j (ellipsoid closed form + ML, station.calibrate), gyro
bin means = one bias per channel. The twin predicts every bin of every still interval; the
model's deviance is the chi2 of the bin means (white noise: var = sigma_i^2 / samples) plus the
rail pile-up deviance (station.diagnose.rails). Every extension is fitted jointly with the
calibration (v_j, a upper triangular, b) by weighted nonlinear least squares on the bins; its
evidence is the deviance decrease (station.diagnose.select).
"""

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.optimize import least_squares

from station.calibrate import calibrate
from station.diagnose import rails
from station.diagnose.effects import Fitted, tone_null
from station.diagnose.effects import saturation as saturation_ext
from station.diagnose.select import Diagnosis, Step, evidence
from station.errors import CalibrationInputError
from station.sim.earth import OMEGA_EARTH
from station.stillness import detect_still

STANDARD_GRAVITY = 9.80665
BIN_S = 1.0
"""Target bin length, s: each still interval is cut into floor(T / BIN_S) bins (at least 1)."""
SCALES_S = (0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0)
"""Block lengths of the white-noise check (scatter of block means against sigma^2 / samples)."""
CANDIDATES = ("bias_drift", "scale_nonlinearity", "saturation", "earth_rate")
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
    units: tuple = ()
    notes: tuple = ()

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

    @cached_property
    def lengths(self) -> np.ndarray:
        """(B,) samples per bin."""
        return self.bins[:, 1] - self.bins[:, 0]

    def binmean(self, y: np.ndarray) -> np.ndarray:
        """(B, ...) means of per-sample values y (K, ...) over the bins."""
        starts = np.concatenate([[0], np.cumsum(self.lengths)[:-1]])
        sums = np.add.reduceat(y[self.still], starts, axis=0)
        return sums / self.lengths.reshape((-1,) + (1,) * (y.ndim - 1))

    @cached_property
    def z(self) -> np.ndarray:
        """(B, c) measured bin means."""
        return self.binmean(self.x)

    @cached_property
    def sigma(self) -> np.ndarray:
        """(c,) noise sigma pooled from the scatter within the bins."""
        dev = self.x[self.still] - np.repeat(self.z, self.lengths, axis=0)
        return np.sqrt(np.sum(dev**2, 0) / (self.still.size - len(self.bins)))

    @cached_property
    def weights(self) -> np.ndarray:
        """(B, c) sqrt(samples) / sigma: whitening of the bin means."""
        return np.sqrt(self.lengths)[:, None] / self.sigma

    @cached_property
    def interval_means(self) -> tuple:
        """(P, c) means of each still interval and (P,) their samples."""
        n = np.bincount(self.bin_interval, self.lengths)
        s = np.stack([np.bincount(self.bin_interval, self.lengths * self.z[:, i])
                      for i in range(self.c)], 1)
        return s / n[:, None], n


def from_arrays(accel, fs: float, *, gyro=None, gravity: float = STANDARD_GRAVITY,
                units=(), notes=(), **detector) -> StaticData:
    """StaticData of accelerometer samples (K, m) and optional gyro samples (K, 3) at fs Hz;
    `detector`: options of station.stillness.detect_still."""
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
    still = detect_still(x, fs, **detector)
    if len(still.intervals) < 9 + 1:
        raise CalibrationInputError(
            f"only {len(still.intervals)} still intervals found.",
            "A free-static diagnosis needs at least 10 poses (9 calibration parameters).")
    bins, owner = _bins(still.intervals, round(BIN_S * fs))
    return StaticData(x, np.arange(len(x)) / fs, float(fs), acc.shape[1], float(gravity),
                      still.intervals, bins, owner, _lsb(x[still.intervals[0, 0]:]),
                      tuple(units), tuple(notes))


def _bins(intervals: np.ndarray, n: int):
    """(B, 2) bins of about n samples covering each interval, and their interval index."""
    bins, owner = [], []
    for j, (a, z) in enumerate(intervals):
        k = max((z - a) // n, 1)
        edges = a + np.round(np.linspace(0, z - a, k + 1)).astype(int)
        bins += list(zip(edges[:-1], edges[1:]))
        owner += [j] * k
    return np.array(bins), np.array(owner)


def _lsb(x: np.ndarray) -> np.ndarray:
    """(c,) quantisation step: the smallest gap between distinct values, ignoring gaps below
    1e-3 of the median gap (decimal printing of imported numbers)."""
    out = []
    for col in x.T:
        d = np.diff(np.unique(col))
        d = d[d > 1e-3 * np.median(d)] if d.size else np.array([1.0])
        out.append(d.min())
    return np.array(out)


# ------------------------------------------------------------------------------------- model


@dataclass(frozen=True)
class Base:
    """What every model of a session starts from: the nominal calibration and fixed geometry.

    cal : the nominal calibration (station.calibrate, canonical frame).
    tangents : (P, 3, 2) orthonormal tangents of the nominal v_j (the v_j are moved in them).
    up : (P, 3) gravity direction of each interval in the accelerometer's own axes (the frame
         nearest the nominal layout: a gyro triad on the same board shares it to ~1 deg).
    horizontal : (P, 3, 2) orthonormal basis perpendicular to up.
    rails : (2, c) lowest and highest value of the still samples; lsb (c,).
    """

    cal: object
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
    sigma = data.sigma[:m, None] / np.sqrt(n)[None]
    cal = calibrate(means[:, :m].T, data.gravity, d=3, bias="estimate", sigma=sigma)
    if m == 3:
        v = calibrate(means[:, :m].T, data.gravity, d=3, bias="estimate", sigma=sigma,
                      nominal=np.eye(3)).v
    else:
        v = cal.v
    up = (v / np.linalg.norm(v, axis=0)).T
    vc = (cal.v / np.linalg.norm(cal.v, axis=0)).T
    still = data.x[data.still]
    return Base(cal, _perp(vc), up, _perp(up), np.stack([still.min(0), still.max(0)]))


@dataclass(frozen=True)
class Layout:
    """Packing of the parameter vector: name -> slice, for a set of extensions."""

    slices: dict = field(default_factory=dict)

    @classmethod
    def of(cls, data: StaticData, names) -> "Layout":
        m, p, q = data.m, len(data.intervals), data.c - data.m
        sizes = {"a": 3 * m - 3, "b": data.c, "v": 2 * p}
        if "scale_nonlinearity" in names:
            sizes["k2"] = m
        if "bias_drift" in names:
            sizes["warmup"] = sizes["slope"] = data.c
        if "earth_rate" in names and q:
            sizes["earth"] = 2 + p
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
    a = _a_matrix(p["a"], data.m)
    v = b0.cal.v / np.linalg.norm(b0.cal.v, axis=0)
    v = v + np.einsum("pik,pk->ip", b0.tangents, p["v"].reshape(-1, 2))
    v = data.gravity * v / np.linalg.norm(v, axis=0)
    s = (a.T @ v).T[data.bin_interval]
    out = np.zeros(data.z.shape)
    out[:, :data.m] = s + p["k2"] * s**2 if "k2" in p else s
    if "earth" in p:
        e = p["earth"]
        hor = np.stack([np.cos(e[2:]), np.sin(e[2:])], 1)
        rate = e[0] * b0.up + e[1] * np.einsum("pik,pk->pi", b0.horizontal, hor)
        out[:, data.m:] = rate[data.bin_interval]
    out += p["b"]
    if "warmup" in p:
        warm, slope = basis
        out += warm[:, None] * p["warmup"] + slope[:, None] * p["slope"]
    if "saturation" in names:
        out = clipped(out, b0.rails, data.sigma)
    return out


def drift_basis(data: StaticData, tau: float):
    """Two (B,) bin means of exp(-t / tau) (warm-up, Eq. of station.sim.effects.bias_drift) and of
    t / T (a linear drift over the session of length T)."""
    span = data.t[-1]
    return data.binmean(np.exp(-data.t / tau)), data.binmean(data.t / span)


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

    @property
    def names(self) -> tuple:
        return tuple(self.fitted)

    @property
    def deviance(self) -> float:
        return self.chi2 + self.rails


def rail_deviance(data: StaticData, b0: Base, prediction: np.ndarray, clip: bool) -> float:
    """Poisson deviance of the still samples at each channel's lowest and highest value against
    the twin's expectation (station.diagnose.rails)."""
    x = data.x[data.still]
    mu = np.repeat(prediction, data.lengths, axis=0)
    obs = np.stack([(x == b0.rails[0]).sum(0), (x == b0.rails[1]).sum(0)])
    exp = np.stack([
        rails.pile_up((mu - b0.rails[0] - data.lsb / 2) / data.sigma, data.lsb / data.sigma,
                      clip).sum(0),
        rails.pile_up((b0.rails[1] - data.lsb / 2 - mu) / data.sigma, data.lsb / data.sigma,
                      clip).sum(0),
    ])
    return rails.deviance(obs, exp)


def _start(data: StaticData, b0: Base, layout: Layout, start) -> np.ndarray:
    """Initial parameters: those of `start` where shared, else the nominal calibration."""
    theta = np.zeros(layout.size)
    p = layout.unpack(theta)  # views into theta
    if start is not None:
        for k, v in start.params.items():
            if k in p:
                p[k][:] = v
        if not ("earth" in p and "earth" not in start.params):
            return theta
    else:
        p["a"][:] = _a_values(b0.cal.a)
        means, n = data.interval_means
        p["b"][:] = np.concatenate([b0.cal.bias, means[:, data.m:].T @ n / n.sum()])
    if "earth" in p:  # headings from the horizontal residual of the gyro interval means
        r = data.interval_means[0][:, data.m:] - p["b"][data.m:]
        h = np.einsum("pik,pi->pk", b0.horizontal, r)
        p["earth"][0] = np.mean(np.einsum("pi,pi->p", b0.up, r))
        p["earth"][1] = np.mean(np.linalg.norm(h, axis=1))
        p["earth"][2:] = np.arctan2(h[:, 1], h[:, 0])
    return theta


def _solve(data: StaticData, b0: Base, names, start, basis):
    """Weighted least squares of the bin means on the model with extensions `names`."""
    layout = Layout.of(data, names)

    def residual(theta):
        return ((data.z - predict(data, b0, names, layout.unpack(theta), basis))
                * data.weights).ravel()

    sol = least_squares(residual, _start(data, b0, layout, start), method="trf",
                        x_scale="jac",
                        xtol=1e-12, ftol=1e-12, gtol=1e-10, max_nfev=200)
    jac = sol.jac.toarray() if hasattr(sol.jac, "toarray") else sol.jac
    cov = np.linalg.pinv(jac.T @ jac)
    return layout, sol.x, cov, float(2 * sol.cost)


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
    fitted = {name: _fitted(name, data, b0, p, sig, tau, taus) for name in names}
    return Model(fitted, p, tau, pred, chi2, rail, _calibration(data, b0, names, p, basis))


def _calibration(data: StaticData, b0: Base, names, p: dict, basis):
    """The accelerometer calibration of the interval means once the extensions' part of the
    twin is taken off (before the extensions: the nominal calibration)."""
    if not names:
        return b0.cal
    bare = {k: np.zeros_like(v) if k in ("k2", "warmup", "slope") else v for k, v in p.items()}
    added = predict(data, b0, names, p, basis) - predict(data, b0, (), bare, basis)
    means, n = data.interval_means
    extra = np.stack([np.bincount(data.bin_interval, data.lengths * added[:, i])
                      for i in range(data.m)], 1) / n[:, None]
    sigma = data.sigma[:data.m, None] / np.sqrt(n)[None]
    return calibrate((means[:, :data.m] - extra).T, data.gravity, d=3, bias="estimate",
                     sigma=sigma)


def _fitted(name: str, data: StaticData, b0: Base, p: dict, sig: dict, tau, taus) -> Fitted:
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
        return Fitted(name, {"k2": p["k2"]}, {"k2": sig["k2"]}, dof=data.m,
                      notes="output s + k2 s^2 per accelerometer channel, s = a_i . v in output "
                      "units; k2 in 1 / output unit")
    if name == "saturation":
        return Fitted(name, {"low": b0.rails[0], "high": b0.rails[1]},
                      {"low": data.lsb / 2, "high": data.lsb / 2}, dof=1,
                      notes="rails = the lowest and highest value of the still samples")
    return _earth_fitted(data, b0, p, sig)


def _earth_fitted(data: StaticData, b0: Base, p: dict, sig: dict) -> Fitted:
    """Earth rate: vertical U along gravity, horizontal N with a free heading per interval.

    Null law: U enters linearly (chi2(1)); N with one free heading per interval is the tone fit
    of station.diagnose.effects.tone_null with the 2 x 2 normal matrices of the horizontal plane;
    the sum is moment-matched to scale * chi2(nu).
    """
    e, s = p["earth"], sig["earth"]
    _, n = data.interval_means
    w = n[:, None] / data.sigma[data.m:] ** 2  # (P, 3) information per axis
    h = np.einsum("pik,pi,pil->pkl", b0.horizontal, w, b0.horizontal)
    scale, nu = tone_null(h)
    mean, var = 1 + scale * nu, 2 + 2 * scale**2 * nu
    u, north = e[0], abs(e[1])
    return Fitted(
        "earth_rate",
        {"vertical": u, "horizontal": north, "rate": np.hypot(u, north),
         "latitude_deg": np.degrees(np.arctan2(u, north)),
         "heading_deg": np.degrees(e[2:] + np.pi * (e[1] < 0)) % 360},
        {"vertical": s[0], "horizontal": s[1], "rate": np.hypot(u * s[0], north * s[1])
         / max(np.hypot(u, north), 1e-300), "latitude_deg": np.nan,
         "heading_deg": np.degrees(s[2:])},
        dof=len(data.intervals) + 2,
        null=(var / (2 * mean), 2 * mean**2 / var),
        notes=f"gyro output units (Earth: {OMEGA_EARTH:.4e} rad/s); heading per interval is "
        "nuisance (the unit is turned by hand); latitude = atan2(vertical, horizontal)",
    )


def testable(data: StaticData) -> tuple:
    """The candidates this session can show (earth_rate needs a gyro stream)."""
    return tuple(c for c in CANDIDATES if c != "earth_rate" or data.gyro)


def diagnose_static(data: StaticData, *, alpha: float = 0.01, max_effects: int = 3,
                    candidates=None) -> Diagnosis:
    """The evidence loop of station.diagnose.select on a free-static session."""
    from station.diagnose import static_report

    b0 = base(data)
    current = fit(data, b0)
    candidates = testable(data) if candidates is None else tuple(candidates)
    steps = []
    while True:
        remaining = [c for c in candidates if c not in current.fitted]
        fits, ev = {}, {}
        if len(current.fitted) < max_effects:
            for name in remaining:
                fits[name] = fit(data, b0, (*current.fitted, name), current)
                ev[name] = evidence(current, fits[name], name, len(remaining), alpha)
        best = min((n for n in ev if ev[n]["significant"]), key=lambda n: ev[n]["log10_p"],
                   default="none")
        steps.append(Step(current, static_report.statistics(data, current), ev, best))
        if best == "none":
            return Diagnosis(steps, alpha)
        current = fits[best]
