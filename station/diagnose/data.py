"""A rotary session as the diagnose workflow sees it: SI samples, timeline, windows and bins.

Loaded from the array format of `station import` / `station simulate` (docs/simulator.md), or
from a recorded HDF5 session (`from_session`: the positions cut onto a common grid by
`station.diagnose.recorded`, whose docstring says what is cut and why). The table angle is
cumulative over the session (the table is not reset between positions), so that effects tied to
the table's heading (Earth rate, axis wobble) see the same angle as the twin.
"""

import os
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from station.diagnose import coloured, outliers, quantisation, recorded
from station.errors import CalibrationInputError
from station.model.temperature import check_kelvin
from station.reduce.eq18 import reduce_rotary, whole_revolutions
from station.reduce.spikes import SPIKE, column_medians, robust_sigma
from station.session import Session

POSITIONS = 16
"""Positions of a chunk (`RotaryData.chunks`): 16 positions of 7000 samples of 12 sensors are
11 MB in SI units, against the session's 672 MB at 1000 positions."""
REQUIRED = ("y", "lsb", "fs", "t0", "rate_cmd", "c_cmd", "seg_static", "seg_spinup",
            "seg_rotating", "seg_spindown")


@dataclass(frozen=True)
class RotaryData:
    """One rotary session; arrays (n, k, m) unless noted, SI units.

    counts : raw integer samples (for the rail pile-up); the samples in SI units, counts * lsb,
        are made a chunk of positions at a time (`chunks`, `residual`), never for the session.
    t : (k,) sample times within a position; t0 (n,) position starts (session time).
    times : (n, k) session times of the samples when the grid is not one contiguous stretch
        per position (a recorded session), else None (t0 + t).
    rate : (k,) or (n, k) commanded rate; c the steady commanded rate; angle (n, k) cumulative
        table angle.
    windows : name -> (2,) [start, stop) of static, spinup, rotating, spindown; the rotating
        window is cut per position to whole revolutions (rot_stop, (n,)).
    bin : samples per bin of the binned residuals.
    rate_factors_sigma : (n,) 1-sigma of `rate_factors` (0: read off an exact angle array;
        recorded sessions: the IMU timing of the turning time).
    temperature : (n, k) the unit's recorded temperature at the samples, K (its own temperature
        channel), or None when the session records none.
    spikes : (m,) outliers found and replaced per sensor among all its samples (`despiked`).
    random_walk, bias_instability : (m,) each sensor's bias random walk K (units / sqrt(s)) and
        flicker's bias instability B (units) from a rest recording of the unit (a calibration
        file's noise figures), or None: not in the noise model. With either, the gaps are
        judged by generalised least squares against them (station.diagnose.coloured).
    """

    counts: np.ndarray
    lsb: np.ndarray
    fs: float
    t0: np.ndarray
    rate: np.ndarray
    c: float
    angle: np.ndarray
    windows: dict
    rot_stop: np.ndarray
    a_nominal: np.ndarray | None
    bin: int
    times: np.ndarray | None = None
    rate_factors_sigma: np.ndarray | None = None
    temperature: np.ndarray | None = None
    spikes: np.ndarray | None = None
    random_walk: np.ndarray | None = None
    bias_instability: np.ndarray | None = None

    @property
    def shape(self) -> tuple:
        return self.counts.shape

    @cached_property
    def y_mean(self) -> np.ndarray:
        """(m,) the mean of the samples over the session, SI units."""
        return self.counts.mean((0, 1)) * self.lsb

    def chunks(self):
        """Slices of at most `POSITIONS` consecutive positions covering the session: what is of
        the session's size (n, k, m) in SI units is made and used a chunk at a time."""
        n = self.shape[0]
        return (slice(start, min(start + POSITIONS, n)) for start in range(0, n, POSITIONS))

    def positions(self, rows: slice) -> range:
        """The position indices of the chunk `rows` (a slice of `chunks`), in order."""
        return range(*rows.indices(self.shape[0]))

    def residual(self, z: np.ndarray, rows: slice = slice(None)) -> np.ndarray:
        """y - z at the positions `rows` (z of their shape), made in z's array (the caller's
        own)."""
        np.subtract(self.counts[rows] * self.lsb, z, out=z)
        return z

    @cached_property
    def rail(self) -> int:
        """The largest |count| of the session (station.diagnose.rails): found once, read by every
        chunk's rail expectation."""
        return max(int(self.counts.max()), -int(self.counts.min()))

    def outlier_test(self, alpha: float) -> dict:
        """The outliers replaced against Gaussian noise (station.diagnose.outliers.counted)."""
        n, k, m = self.shape
        return outliers.counted(np.zeros(m, int) if self.spikes is None else self.spikes, n * k,
                                alpha)

    @property
    def coloured(self) -> bool:
        """Whether a bias random walk or flicker is in the noise model."""
        return self.random_walk is not None or self.bias_instability is not None

    def rail_offsets(self, mu: np.ndarray, rows: slice) -> np.ndarray | None:
        """(p, m) what the samples of the positions `rows` stand off the twin's expected output
        mu (p, k, m) in their static windows, with coloured noise in the model (the bias has
        wandered there: the rail pile-up's expected counts take it, station.diagnose.rails),
        else None (white noise: the twin's one bias)."""
        if not self.coloured:
            return None
        s0, s1 = self.windows["static"]
        return (self.counts[rows, s0:s1] * self.lsb).mean(1) - mu[:, s0:s1].mean(1)

    @cached_property
    def coloured_static(self) -> list:
        """The static means' whitening under the coloured noise
        (station.diagnose.coloured.static_factors), made once."""
        return coloured.static_factors(self)

    @property
    def correlated(self) -> bool:
        """Whether a position's bins share errors: coloured noise in the model, or a sensor
        quantised coarser than its noise (each window's level keeps its quantisation error: the
        bins of a window with a steady signal read it together). The within-position part of the
        deviance is then judged by generalised least squares (`bin_whitening`)."""
        return self.coloured or bool(self.coarse.any())

    @cached_property
    def bin_whitening(self) -> list:
        """The bins' whitening under the coloured noise and the quantisation error the bins keep
        (station.diagnose.coloured.bin_factors), made once."""
        return coloured.bin_factors(self)

    @cached_property
    def coloured_bins_variograms(self) -> list:
        """[(scale (m,), (K, K) E gamma between a position's bins)] of each coloured term
        (station.diagnose.coloured), made once."""
        spans = coloured.bin_spans(self)
        return [(scale, coloured.mean_variogram(spans, spans, term))
                for term, scale in coloured.present(self)]

    def static_whitened(self, means: np.ndarray) -> np.ndarray:
        """(n, m) static means (n, m) net of one level per sensor over their standard error:
        their sum of squares is the chi2 of the static means (white noise: centred and weighted;
        with coloured noise: by generalised least squares, station.diagnose.coloured)."""
        if not self.coloured:
            s0, s1 = self.windows["static"]
            return (means - means.mean(0)) / np.sqrt(self.sigma**2 / (s1 - s0) + self.kept)
        return np.stack([f @ means[:, i] for i, f in enumerate(self.coloured_static)], 1)

    @cached_property
    def t(self) -> np.ndarray:
        return np.arange(self.shape[1]) / self.fs

    @cached_property
    def reduced(self):
        """Eq. (18) reduction of the measured samples (from the counts, a window at a time)."""
        return reduce_rotary(self.counts, self.lsb, self._segments(slice(None)))

    @cached_property
    def sigma(self) -> np.ndarray:
        """(m,) per-sample noise: the pooled standard deviation within the static windows; on a
        sensor quantised coarser than its noise (`coarse`) the larger of it and the rotating
        windows' (`rotating_scatter`): the static windows read one level, whose place in its
        step sets their scatter, and the rotating windows' features would be judged by it."""
        s0, s1 = self.windows["static"]
        var = np.concatenate([self.counts[rows, s0:s1].var(1, ddof=1) for rows in self.chunks()])
        static = np.sqrt(var.mean(0)) * self.lsb
        return np.where(self.coarse, np.maximum(static, self.rotating_scatter), static)

    @cached_property
    def rate_factors(self) -> np.ndarray:
        """(n,) mean table rate over each whole-revolution rotating window, as read by the
        table's angle, over the commanded rate c: 1 when the angle is the command's (to rounding
        for an angle array, to `rate_factors_sigma` for a recorded session)."""
        r0 = self.windows["rotating"][0]
        last = self.rot_stop - 1
        rows = np.arange(self.shape[0])
        turned = self.angle[rows, last] - self.angle[rows, r0]
        return turned * self.fs / (last - r0) / self.c

    @cached_property
    def step(self) -> np.ndarray:
        """(m,) the quantisation step of each sensor, SI units (station.diagnose.quantisation:
        the smallest gap between distinct values of the first chunk's static windows)."""
        s0, s1 = self.windows["static"]
        first = next(self.chunks())
        return quantisation.step(self.counts[first, s0:s1].reshape(-1, self.shape[2])) * self.lsb

    @cached_property
    def analog_sigma(self) -> np.ndarray:
        """(m,) the noise before quantisation: from the samples' scatter within the rotating
        windows (`rotating_scatter`; station.diagnose.quantisation.analog_sigma) and, for a
        sensor that it finds coarser than its noise, from the values its static and rotating
        windows read (quantisation.level_sigma: 4 times more precise at 6 sigma a step, where
        the scatter's average over 20 levels left kept's estimate 40 % rms off)."""
        out = quantisation.analog_sigma(self.rotating_scatter, self.step)
        s0, s1 = self.windows["static"]
        r0 = self.windows["rotating"][0]
        for i in np.flatnonzero(quantisation.coarse(self.step, out)):
            per = round(self.step[i] / self.lsb[i])  # counts per step
            windows = [w // per for rows in self.chunks()
                       for x, stop in zip(self.counts[rows, :, i], self.rot_stop[rows],
                                          strict=True)
                       for w in (x[s0:s1], x[r0:stop])]
            out[i] = quantisation.level_sigma(windows) * self.step[i]
        return out

    @cached_property
    def rotating_scatter(self) -> np.ndarray:
        """(m,) the samples' scatter about their whole-revolution rotating window's mean, pooled
        over the positions. Each position's rotating level lies elsewhere within a step (the
        sensed rate differs with the orientation), so the scatter holds the step's average
        quantisation error, the premise of `quantisation.analog_sigma`; the static windows read
        one level at every position (the bias), whose place in its step sets their scatter
        (from 0 to half a step when the noise is finer than the step)."""
        r0, squares, dof = self.windows["rotating"][0], 0.0, 0
        for rows in self.chunks():
            for x, stop in zip(self.counts[rows], self.rot_stop[rows], strict=True):
                w = x[r0:stop].astype(float)
                squares = squares + np.sum((w - w.mean(0)) ** 2, 0)
                dof += len(w) - 1
        return np.sqrt(squares / dof) * self.lsb

    @cached_property
    def kept(self) -> np.ndarray:
        """(m,) variance of the quantisation error a window mean keeps (station.diagnose.
        quantisation: 0 to 1e-5 step^2 while the noise dithers the step, up to step^2 / 12 for a
        channel quieter than its step), at the noise before quantisation."""
        return quantisation.kept(self.analog_sigma, self.step)

    @cached_property
    def coarse(self) -> np.ndarray:
        """(m,) sensors quantised coarser than their noise (station.diagnose.quantisation.coarse):
        their rail pile-up is not judged (`station.diagnose.rails`)."""
        return quantisation.coarse(self.step, self.analog_sigma)

    @property
    def bin_variance(self) -> np.ndarray:
        """(m,) variance of a bin's mean: the white noise's over its `bin` samples and the
        quantisation error it keeps (`kept`), taken as independent between bins. Exact where the
        signal sweeps the steps within a window; where it stays within a step, a small change
        of the signal moves the output by the step's unknown local gain (0 to step / (sigma
        sqrt(2 pi)) per unit), a shape the white model would read as a tone or a trend: the
        kept error per bin holds it, conservatively (bins that share a level share its error,
        which their contrasts cancel)."""
        return self.sigma**2 / self.bin + self.kept

    def quantisation_report(self) -> dict:
        """The steps against the noise, and whether some sensor is quantised coarser than its
        noise (station.diagnose.quantisation.report)."""
        m = self.shape[2]
        return quantisation.report(self.step, self.analog_sigma,
                                   [f"sensor {i}" for i in range(m)], [""] * m)

    @property
    def sigma_m(self) -> np.ndarray:
        """(m, n) standard error of M: white noise of `sigma` per sample, the quantisation
        error each of its two window means keeps (`kept`) and the coloured noise's change
        between them (`coloured`)."""
        r = self.reduced
        var = (self.sigma[:, None] ** 2 * (1 / r.n_static + 1 / r.n_rotating)
               + 2 * self.kept[:, None])
        if self.coloured:
            var = var + self.coloured_reading
        return np.sqrt(var)

    @cached_property
    def coloured_reading(self) -> np.ndarray:
        """(m, n) the variance the coloured noise gives each M_j
        (station.diagnose.coloured.reading_variance), made once."""
        return coloured.reading_variance(self)

    @property
    def t_session(self) -> np.ndarray:
        """(n, k) session times of the samples."""
        return self.session_times(slice(None))

    def session_times(self, rows: slice) -> np.ndarray:
        """(p, k) session times of the samples at the positions `rows`."""
        return self.t0[rows, None] + self.t if self.times is None else self.times[rows]

    def reduce(self, x: np.ndarray, rows: slice = slice(None)):
        """Eq. (18) reduction of a series x (p, k, m) in SI units at the positions `rows` over
        this session's windows."""
        return reduce_rotary(x, 1.0, self._segments(rows))

    def _segments(self, rows: slice) -> dict:
        """The Eq. (18) windows of the positions `rows` (the rotating one cut to whole turns)."""
        stop = self.rot_stop[rows]
        rot = np.stack([np.full_like(stop, self.windows["rotating"][0]), stop], 1)
        return {"static": self.windows["static"], "rotating": rot}

    def bins(self, x: np.ndarray) -> np.ndarray:
        """Means of x (n, k, m) over consecutive bins of `bin` samples: (n, K, m)."""
        n, k, m = x.shape
        kb = k // self.bin
        return x[:, : kb * self.bin].reshape(n, kb, self.bin, m).mean(2)

    def window_mask(self, name: str) -> np.ndarray:
        """(n, K) bins lying wholly inside window `name` (rotating: the whole-revolution cut)."""
        n, k, _ = self.shape
        kb = k // self.bin
        first = np.arange(kb) * self.bin
        start, stop = self.windows[name]
        stops = self.rot_stop if name == "rotating" else np.full(n, stop)
        return (first >= start)[None, :] & (first[None, :] + self.bin <= stops[:, None])


def load(path, bin_seconds: float = 0.1) -> RotaryData:
    """A RotaryData from a rotary `.npz` data file, checked as `station import npz` checks it
    (headers before loading, never unpickles; types, shapes and values)."""
    from station.imports.recordings import read_npz

    return from_arrays(read_npz(path), bin_seconds)


def is_rotary(session) -> bool:
    """True when a recorded session (`station.session.Session`) holds rotary protocol
    events."""
    return recorded.is_rotary(session.events())


def from_session(session_or_path, stream: str = "imu", bin_seconds: float = 0.1) -> RotaryData:
    """A RotaryData from a recorded rotary HDF5 session (a `Session` or a path).

    Per completed position: the static window from its start, the moving part aligned at the
    spin start (guard, spin-up, settling, rotating window, steady guard) and the spin-down
    aligned at the stop, each cut to the shortest length over the positions; the samples keep
    their session times. Cut away: the mounting and the wait for stillness, what is longer than
    in the shortest position, the rest after the stop beyond the shortest. Spin-up and stop are
    timed by the IMU samples (the table readings' host stamps scatter by the Modbus latency), the
    rate profile is the table's set point times that trapezoid, the angle the table's recorded
    angle at rest before the spin-up plus its integral. Windows with lost samples are refused.
    Details: `station.diagnose.recorded`.
    """
    if isinstance(session_or_path, str | os.PathLike):
        with Session.open(session_or_path) as session:
            return from_session(session, stream, bin_seconds)
    if not is_rotary(session_or_path):
        raise CalibrationInputError(
            f"the session {session_or_path.path} holds no rotary protocol events.",
            "Give a session recorded with the rotary protocol.")
    grid = recorded.arrays(session_or_path, stream)
    return _rotary_data(grid["counts"], grid["lsb"], grid["fs"], grid["rate"], grid["c"],
                        grid["angle"], grid["windows"], grid["a_nominal"], bin_seconds,
                        grid["times"][:, 0], grid["times"], grid["rate_factors_sigma"],
                        _temperature(grid["temperature"], grid["times"].shape), owned=True)


def from_arrays(arrays: dict, bin_seconds: float = 0.1) -> RotaryData:
    """A RotaryData from the arrays of a rotary data file, checked."""
    missing = [key for key in REQUIRED if key not in arrays]
    if missing:
        raise CalibrationInputError(
            f"the data file lacks {', '.join(missing)}, which the rotary diagnosis needs.",
            "Give a rotary session (station simulate --protocol rotary, or station import).",
        )
    counts = np.asarray(arrays["y"])
    if counts.ndim != 3 or not np.issubdtype(counts.dtype, np.integer):
        raise CalibrationInputError(
            f"y has shape {counts.shape} and dtype {counts.dtype}.",
            "y must hold integer counts, (positions, samples, sensors).",
        )
    n, k, m = counts.shape
    fs = float(arrays["fs"])
    rate = np.asarray(arrays["rate_cmd"], float)
    if rate.shape != (k,):
        raise CalibrationInputError(
            f"rate_cmd has shape {rate.shape}, expected ({k},).", "Give one rate per sample."
        )
    angle = arrays.get("angle")
    if angle is None:
        angle = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]))]) / fs
    angle = np.broadcast_to(np.asarray(angle, float), (n, k))
    start = np.concatenate([[0.0], np.cumsum(angle[:-1, -1] - angle[:-1, 0])])
    windows = {name: np.asarray(arrays[f"seg_{name}"], int)
               for name in ("static", "spinup", "rotating", "spindown")}
    nominal = arrays.get("a_nominal")
    return _rotary_data(counts, np.broadcast_to(np.asarray(arrays["lsb"], float), (m,)), fs,
                        rate, float(arrays["c_cmd"]), start[:, None] + angle - angle[:, :1],
                        windows, None if nominal is None else np.asarray(nominal, float),
                        bin_seconds, np.asarray(arrays["t0"], float),
                        temperature=_temperature(arrays.get("temperature"), (n, k)))


def _temperature(values, shape: tuple) -> np.ndarray | None:
    """The recorded temperature (n, k) in K, checked (shape, finite, kelvin), or None."""
    if values is None:
        return None
    t = np.asarray(values, float)
    if t.shape != shape:
        raise CalibrationInputError(
            f"temperature has shape {t.shape}, expected {shape}.",
            "Give the unit's temperature in K at every sample, (positions, samples).")
    check_kelvin(t.ravel(), "the recorded temperature")
    return t


def _rotary_data(counts, lsb, fs, rate, c, angle, windows, a_nominal, bin_seconds, t0,
                 times=None, rate_factors_sigma=None, temperature=None,
                 owned: bool = False) -> RotaryData:
    """The RotaryData of checked arrays; the rotating window cut to whole turns per position,
    the outliers replaced (`despiked`; in a copy of the counts unless they are `owned`)."""
    r0, r1 = windows["rotating"]
    rot_stop = np.array([whole_revolutions(a, r0, r1)[0] for a in angle])
    sd = np.zeros(len(angle)) if rate_factors_sigma is None else np.asarray(rate_factors_sigma)
    counts, spikes = despiked(counts, rate, windows, rot_stop, owned)
    return RotaryData(counts=counts, lsb=np.array(lsb, float), fs=fs, t0=t0, rate=rate, c=c,
                      angle=angle, windows=windows, rot_stop=rot_stop, a_nominal=a_nominal,
                      bin=max(1, round(bin_seconds * fs)), times=times, rate_factors_sigma=sd,
                      temperature=temperature, spikes=spikes)


def despiked(counts: np.ndarray, rate: np.ndarray, windows: dict, rot_stop: np.ndarray,
             owned: bool) -> tuple:
    """(counts, outliers per sensor (m,)): each position's samples
    beyond `station.reduce.spikes.SPIKE` robust standard deviations (at least one count) of its
    steady model in the table rate, level + gain x rate(t) (level: the static window's median,
    gain: the whole-turn rotating window's median less it, over the rate there; medians, which
    spikes do not move), replaced by that model rounded to a count, so that a spike weighs
    nothing in the noise sigma, the readings M or the gaps (issue 32: spikes of 30 sigma on
    0.1 % of the samples inflated sigma 1.35 times, and nothing said so). The model follows the
    ramps' corners, which a sample's neighbours do not (a corner departs from their medians by a
    sample's change of rate, tens of sigma on a fast table); a sample is an outlier only where
    it departs alone (`isolated`): where the model itself misses (a clipped output's ramp, whose
    gain the rail's median understates) the departure is shared by a run of samples. The counts
    are copied before the first change unless `owned`."""
    n, k, m = counts.shape
    rate = np.broadcast_to(rate, (n, k))
    (s0, s1), r0 = windows["static"], windows["rotating"][0]
    found = np.zeros(m, int)
    for j, stop in enumerate(rot_stop):
        x = counts[j].astype(float)
        level = column_medians(x[s0:s1])
        gain = (column_medians(x[r0:stop]) - level) / np.median(rate[j, r0:stop])
        model = level + rate[j, :, None] * gain
        flags = isolated(x - model)
        if flags.any():
            if not owned:
                counts, owned = counts.copy(), True
            counts[j][flags] = np.rint(model[flags])
            found += flags.sum(0)
    return counts, found


def isolated(dev: np.ndarray) -> np.ndarray:
    """(k, m) the deviations dev (k, m) beyond SPIKE robust standard deviations (at least one
    count: `station.reduce.spikes`) whose neighbours before and after both lie within half that:
    a single sample departing, as a spike does."""
    limit = SPIKE * np.maximum(robust_sigma(dev), 1.0)
    calm = np.pad(np.abs(dev) < limit / 2, ((1, 1), (0, 0)), constant_values=True)
    return (np.abs(dev) > limit) & calm[:-2] & calm[2:]
