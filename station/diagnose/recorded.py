"""A recorded rotary session (HDF5, docs/session-format.md) cut onto the diagnosis' common grid.

The diagnosis compares positions sample by sample against one shared set of windows, as in the
array format (docs/simulator.md). A recorded session has no such grid: the protocol waits on
table polls (`station.protocols.rotary`), so the time from the static window to the spin-up, the
settling time and the stop differ between positions by a few poll intervals. Per completed
position (one with `position_done`; a position recorded again keeps its last run) three
contiguous stretches of the IMU stream are taken, each aligned and cut to the shortest length
over the positions:

1. static   : from `static_start`, the shortest static window;
2. moving   : `rotate_start` aligned, from the shortest lead after `static_end` (the guard, the
              spin-up from t_s, the settling) up to the shortest `rotate_start` -> t_e (t_e: the
              stop command); the rotating window is all of the steady rotation after
              `rotate_start` (the protocol's turns and the steady guard), cut to whole turns per
              position later;
3. spindown : from t_e, the shortest stretch up to `position_done`.

Cut away, and why: the mounting and the wait for a still table before the static window (the
unit is handled there); the part of the guard, the settling and the steady rotation longer than
in the shortest position (a common grid); the rest after the table stopped beyond the shortest
(the recorder stops without waiting for the last position's tail, so it is usually short there).
The stretches keep their recorded session times (`times`), so time-dependent effects (warm-up,
heating) see the real timeline.

Timing. Spin-up and stop are table commands, not events, and the table's readings are stamped
on the host when the Modbus answer arrives: their times scatter by the request latency (on the
virtual bench at 40x, tens of ms of simulated time), while a 0.3 ms error in the ramp's timing
already shows as a latency. The ramps are therefore timed by the IMU itself: the samples
projected on the position's Eq. (18) reading, f(t) = (y - static mean) . D / |D|^2 with D the
rotating minus the static mean, run from 0 to 1 on the spin-up; a straight line through the
samples with 0.1 < f < 0.9 gives the ramp's start and slope (likewise down from 1 on the
spin-down). A latency common to all sensors is absorbed there (it is not identifiable against
the table's timing); latencies differing between sensors remain. A session whose table states
are stamped at the IMU's sample instants (metadata `table_timing` "sample": an imported array
file, `station.imports.recordings.import_npz`) is timed by the table instead: the same line through
the table's reported rate over c, and the rate and angle are the table's own at each sample, so
a common latency stays in the data, as in the array file. The rate profile is the
commanded rate c (the table's recorded set point) times that trapezoid; the table angle is the
recorded angle at rest before the spin-up (exact: a still table's angle does not depend on the
reading's stamp) plus the integral of that rate profile times the position's rate factor: the
angle the table reports from rest to rest over c times the IMU-timed turning time (1 for a table
that reports its command, to the IMU timing's precision; the true rate's factor for a table whose
angle reads the shaft, which the `rate_error` extension then uses).

Sample instants come from the sequence numbers at the nominal rate (`station.reduce.timeline.
sample_times`); each position's stretch is found by time and read from the file by row range
(`station.reduce.windows.StreamWindows`), so the work is linear in the session; the nominal rate
is checked against the device's time stamps (or the arrival times), and a window with a gap in
the sequence numbers (a lossy link) is refused.
"""

import math

import numpy as np

from station.errors import CalibrationInputError
from station.reduce.rotary import position_spins, position_windows, rotary_channels
from station.reduce.windows import StreamWindows, increasing_runs, window_ranges
from station.session import nominal_layout

RAMP_BAND = (0.1, 0.9)
"""Fractions of the steady rate between which ramp samples are fitted by a line."""

MIN_RAMP_SAMPLES = 3


def is_rotary(events) -> bool:
    """True when the events hold a rotating window (the rotary protocol's `rotate_start`)."""
    return any(e.kind == "rotate_start" for e in events)


def arrays(session, stream: str = "imu") -> dict:
    """The grid of a recorded rotary session: counts (n, k, m) of the gyros
    (`station.reduce.rotary.rotary_channels`, in the `narrowest` type) and their lsb (m,), fs,
    times (n, k), rate (n, k), c, angle (n, k), windows (name -> (2,)), a_nominal or None,
    temperature (n, k) in K (the stream's first channel in K) or None; see the module docstring
    for what is cut."""
    events, table = session.events(), _States(session.table())
    clock = session.stream(stream, columns=("seq", "device_time", "host_time"))
    stream_windows = StreamWindows(session, stream, events, clock)
    t, spec = stream_windows.t, clock.spec
    fs = spec.rate_hz
    gyros = rotary_channels(session, stream)
    kelvin = [i for i, unit in enumerate(spec.units) if unit == "K"]
    lsb = 1.0 / np.asarray(spec.counts_per_unit, float)
    spans = _spans(session.path, events)
    c = _commanded(session.path, table, spans.values())
    by_table = session.metadata.get("table_timing") == "sample"
    pos, peak = {}, 0
    for j, p in spans.items():
        # the position's own stretch, read from the file: everything below is local to it
        index, counts = stream_windows.read(p["s0"], p["done"])
        tj, seq = t[index], clock.seq[index]
        y = counts[:, gyros] * lsb[gyros]
        peak = max(peak, int(np.abs(counts[:, gyros].astype(np.int64)).max(initial=0)))
        _complete(tj, seq, fs, p["s0"], p["r1"], j)
        p.update(_table_ramps(table, c, p, j) if by_table else _ramps(tj, y, p, j))
        _complete(tj, seq, fs, p["s0"], p["te"], j)
        pos[j] = p
    _check_rate(clock, stream_windows, fs, pos)
    seq = clock.seq
    del clock  # its time columns: only the sequence numbers are read from here on
    index, windows = _grid(stream_windows, fs, list(pos.values()))
    times = t[index]
    motion = _table_motion if by_table else _imu_timed_motion
    rate, angle, factors_sigma = motion(session.path, table, c, times, pos)
    del table  # before the grid of counts is made (memory)
    counts = np.empty((*index.shape, len(gyros)), narrowest(peak))
    temperature = np.empty(index.shape) if kelvin else None
    # within each stretch, seq steps as the stream index, and every sample's counts read back
    for row, (j, idx) in enumerate(zip(pos, index, strict=True)):
        lost = int(np.sum(np.diff(seq[idx]) - np.diff(idx)))
        got, row_counts = stream_windows.read_rows(_stretches(idx))
        if lost or len(got) < len(idx):
            raise _lossy(j, t[idx[0]], t[idx[-1]], max(lost, len(idx) - len(got)))
        counts[row] = row_counts[:, gyros]
        if kelvin:
            temperature[row] = row_counts[:, kelvin[0]] * lsb[kelvin[0]]
    return {"counts": counts, "lsb": lsb[gyros],
            "fs": fs, "times": times, "rate": rate, "c": c, "angle": angle, "windows": windows,
            "rate_factors_sigma": factors_sigma,
            "a_nominal": nominal_layout(session.metadata, len(gyros)),
            "temperature": temperature}


def narrowest(peak: int) -> np.dtype:
    """The narrowest signed integer type holding +-peak: the gyros' counts on the grid take 2
    bytes a value for a 16-bit unit, whatever the type the session stores them in (the grid is
    the diagnosis' largest array)."""
    return next(np.dtype(t) for t in (np.int8, np.int16, np.int32, np.int64)
                if np.iinfo(t).max >= peak)


def _imu_timed_motion(path, table, c: float, times, pos: dict) -> tuple:
    """(rate, angle (n, k), rate factors' 1-sigma (n,)): c times the IMU-timed trapezoid, and
    the table's angle at rest before each spin-up (exact: a still table's angle does not depend
    on the reading's time stamp) plus c times the position's rate factor times its integral."""
    rate = np.stack([c * _fraction(tj, p) for tj, p in zip(times, pos.values(), strict=True)])
    start = [_rest_angle(path, table, p["s0"], p["s1"], j, "static window")
             for j, p in pos.items()]
    factors = [_rate_factor(table, p, c, a0) for p, a0 in zip(pos.values(), start, strict=True)]
    angle = np.stack([a0 + c * f * _swept(tj, p)
                      for tj, p, a0, (f, _) in zip(times, pos.values(), start, factors,
                                                   strict=True)])
    return rate, angle, np.array([sd for _, sd in factors])


def _table_motion(path, table, c: float, times, pos: dict) -> tuple:
    """(rate, angle (n, k), zeros (n,)): the table's reported rate and angle at each sample, its
    states being stamped at the sample instants (an exact angle array: its rate factors have no
    timing error)."""
    rate, angle = np.empty(times.shape), np.empty(times.shape)
    for row, (tj, (j, p)) in enumerate(zip(times, pos.items(), strict=True)):
        rows = table.rows(p["s0"], p["done"])
        if rows.size < 2:
            raise CalibrationInputError(
                f"the session {path} holds {rows.size} table state(s) in position {j + 1}, "
                "though its metadata says they are stamped at every sample.",
                "Import the array file again (station import npz).")
        rate[row] = np.interp(tj, table.time[rows], table.rate[rows])
        angle[row] = np.interp(tj, table.time[rows], table.angle[rows])
    return rate, angle, np.zeros(len(pos))


def _stretches(idx) -> list:
    """[(start, stop), ...]: the consecutive runs of the increasing row numbers `idx`."""
    cut = np.flatnonzero(np.diff(idx) != 1) + 1
    return [(int(part[0]), int(part[-1]) + 1) for part in np.split(idx, cut)]


def _spans(path, events) -> dict:
    """{position: {s0, s1 (static), r0, r1 (rotating), done}} event times of the completed
    positions. A two-axis session's spins of the position axis are refused: the table states the
    diagnosis models are the rate axis' (`station.reduce.rotary.position_spins`), and without the
    spins the cone positions are not solvable."""
    if spins := position_spins(events):
        raise CalibrationInputError(
            f"the session {path} spins the position axis of a two-axis table at position(s) "
            f"{', '.join(str(j + 1) for j in sorted(spins))}; the diagnosis models the rate "
            "axis' recorded motion only and cannot check such a session yet.",
            "Solve it with `station solve` or `station replay`; its report shows the windows.")
    windows = position_windows(events)
    if not windows:
        raise CalibrationInputError(f"the session {path} has no completed position.",
                                    "Record at least one position to the end (position_done).")
    done = {e.position: e.time for e in events if e.kind == "position_done"}
    return {j: {"s0": w["static"][0], "s1": w["static"][1], "r0": w["rotating"][0],
                "r1": w["rotating"][1], "done": done[j]} for j, w in windows.items()}


def _lossy(j, t0, t1, lost) -> CalibrationInputError:
    return CalibrationInputError(
        f"position {j + 1}: the IMU link lost {lost} samples between {t0:.2f} s and {t1:.2f} s "
        "(session clock) of the stretch the diagnosis compares.",
        "Record the position again, or solve without it (station replay --positions).")


def _complete(t, seq, fs, t0, t1, j) -> None:
    """Refuse when samples due in [t0, t1] are missing: fewer than due - 1, or a sequence gap."""
    inside = np.flatnonzero((t >= t0) & (t <= t1))
    due = (t1 - t0) * fs
    lost = int(np.sum(np.diff(seq[inside]) - 1)) if inside.size > 1 else 0
    if inside.size < due - 1 or lost:
        raise _lossy(j, t0, t1, max(lost, round(due - inside.size)))


def _ramps(t, y, p, j) -> dict:
    """Spin start ts, spin-up slope up (1/s), stop te, spin-down slope down, from the IMU; and
    the turning time at full rate (te + 1/(2 down)) - (ts + 1/(2 up)) with its 1-sigma: the two
    line fits, and the noise of the static and rotating means that scale f (an error e . D /
    |D|^2 moves both half crossings inwards by (e . D / |D|^2) / (2 slope))."""
    static, rotating = ((t >= p["s0"]) & (t <= p["s1"])), ((t >= p["r0"]) & (t <= p["r1"]))
    base = y[static].mean(0)
    d = y[rotating].mean(0) - base
    f = (y - base) @ d / (d @ d)
    ts, up, half_up, sd_up = _line(t, f, p["s1"], p["r0"], j, "spin-up")
    te, down, half_down, sd_down = _line(t, 1 - f, p["r1"], p["done"], j, "spin-down")
    var_means = y[static].var(0, ddof=1) * (1 / static.sum() + 1 / rotating.sum())
    sd_scale = 0.5 * (1 / up + 1 / down) * np.sqrt(var_means @ d**2) / (d @ d)
    return {"ts": ts, "up": up, "te": te, "down": down, "turning": half_down - half_up,
            "turning_sd": float(np.sqrt(sd_up**2 + sd_down**2 + sd_scale**2))}


def _table_ramps(table, c: float, p, j) -> dict:
    """`_ramps` from the table's reported rate over c, for states stamped at the sample
    instants (an exact profile: the lines' 1-sigma is their scatter, 0 for a trapezoid)."""
    rows = table.rows(p["s1"], p["done"])
    tt, f = table.time[rows], table.rate[rows] / c
    ts, up, half_up, sd_up = _line(tt, f, p["s1"], p["r0"], j, "spin-up of the table")
    te, down, half_down, sd_down = _line(tt, 1 - f, p["r1"], p["done"], j,
                                         "spin-down of the table")
    return {"ts": ts, "up": up, "te": te, "down": down, "turning": half_down - half_up,
            "turning_sd": float(np.hypot(sd_up, sd_down))}


def _line(t, f, t0, t1, j, what) -> tuple:
    """(zero crossing, slope, half crossing, its 1-sigma) of the straight line through the
    samples of [t0, t1] whose f lies in RAMP_BAND (f rising from 0 to 1)."""
    on = (t >= t0) & (t <= t1) & (f > RAMP_BAND[0]) & (f < RAMP_BAND[1])
    if on.sum() < MIN_RAMP_SAMPLES:
        raise CalibrationInputError(
            f"position {j + 1}: the {what} is not seen in the IMU stream ({int(on.sum())} "
            f"samples on the ramp between {t0:.2f} s and {t1:.2f} s).",
            "Check that the IMU was recording while the table moved; record the position again.")
    (slope, intercept), cov = np.polyfit(t[on], f[on], 1, cov="unscaled")
    if not slope > 0:
        raise CalibrationInputError(
            f"position {j + 1}: the {what} does not ramp in the IMU stream.",
            "Check the unit's mounting and the table; record the position again.")
    half = (0.5 - intercept) / slope
    grad = np.array([-half, -1.0]) / slope  # d half / d (slope, intercept)
    dof = max(int(on.sum()) - 2, 1)
    scatter = np.sum((f[on] - slope * t[on] - intercept) ** 2) / dof
    return -intercept / slope, slope, half, float(np.sqrt(scatter * grad @ cov @ grad))


def _check_rate(clock, stream_windows, fs, pos) -> None:
    """Refuse a nominal rate that misplaces a position's samples by half a sample.

    With device time stamps: the slope of device time - seq / fs over each position's stretch.
    Without: the arrival times' lower envelope (least delayed tenth at each end of the stream),
    which resolves the drift only to within the arrival delays (their median is allowed).
    `clock`: the stream's timing columns, `stream_windows` their instants (`StreamWindows`)."""
    if np.all(np.isfinite(clock.device_time)):
        for j, p in pos.items():
            on = stream_windows.index(p["s0"], p["te"])
            seq = clock.seq[on].astype(float)
            slope = np.polyfit(seq / fs, clock.device_time[on] - seq / fs, 1)[0]
            span = p["te"] - p["s0"]
            if abs(slope) * span * fs > 0.5:
                raise _off_rate(fs, slope, f"the device time stamps of position {j + 1}", span)
        return
    seq = clock.seq.astype(float)
    offset = clock.host_time - seq / fs
    tenth = max(len(seq) // 10, 1)
    drift = offset[-tenth:].min() - offset[:tenth].min()
    if abs(drift) > 0.5 / fs + np.median(offset - offset.min()):
        raise _off_rate(fs, drift / (np.ptp(seq) / fs), "the arrival times", np.ptp(seq) / fs)


def _off_rate(fs, slope, source, span) -> CalibrationInputError:
    return CalibrationInputError(
        f"the stream's nominal rate {fs:g} Hz is off by {slope * 1e6:.0f} ppm against {source}: "
        f"over {span:.1f} s the sample times drift by {abs(slope) * span * fs:.2f} samples.",
        "Fix rate_hz in the device profile the session was recorded with, and record again.")


def _grid(stream_windows, fs, pos) -> tuple:
    """(n, k) stream indices of the three aligned stretches, and the windows on the grid.

    The moving stretch is aligned at each position's `rotate_start`: every position then has at
    least its own whole turns plus the steady guard after that index, whatever its settling took
    (aligned at the spin start instead, the positions' common part of the rotating windows can be
    shorter than a turn when the settling times differ by a few polls). The spin-ups land at
    slightly different indices; the `spinup` window spans them all (the twin's rate profile is
    per position, so only the transients statistic sees the window)."""
    def samples(a, b, pick):
        return pick([stream_windows.count(p[a], p[b], closed=False) for p in pos])

    ns, lead = samples("s0", "s1", min), samples("s1", "r0", min)
    moving, down = samples("r0", "te", min), samples("te", "done", min)
    settle_max, settle_min = samples("ts", "r0", max), samples("ts", "r0", min)
    index = np.stack([np.concatenate([
        np.arange(s, s + ns), np.arange(r - lead, r + moving), np.arange(e, e + down)])
        for s, r, e in ([stream_windows.first(p[key]) for key in ("s0", "r0", "te")]
                        for p in pos)])
    up, dn = (math.ceil(fs * max(1 / p[key] for p in pos)) for key in ("up", "down"))
    m0 = ns + lead  # the rotating windows' start
    windows = {"static": (0, ns),
               "spinup": (max(ns, m0 - settle_max), min(m0, m0 - settle_min + up)),
               "rotating": (m0, m0 + moving),  # cut to whole turns per position later
               "spindown": (m0 + moving, m0 + moving + min(dn, down))}
    return index, {name: np.array(w) for name, w in windows.items()}



def _fraction(t, p) -> np.ndarray:
    """The trapezoid: rate / c at times t (spin-up from ts at slope up, spin-down from te)."""
    return np.clip(p["up"] * (t - p["ts"]), 0, 1) - np.clip(p["down"] * (t - p["te"]), 0, 1)


def _swept(t, p) -> np.ndarray:
    """Integral of `_fraction` from before ts to t (s)."""
    def ramp(x, slope):
        return np.where(x <= 0, 0.0, np.where(x < 1 / slope, 0.5 * slope * x**2,
                                              x - 0.5 / slope))
    return ramp(t - p["ts"], p["up"]) - ramp(t - p["te"], p["down"])


class _States:
    """The table states read for windows: `time`, `rate`, `angle`, `rate_setpoint`, `still` (not
    moving) of every state, and `rows(t0, t1)`, the states whose time lies in [t0, t1] found by
    `np.searchsorted` (`station.reduce.windows.window_ranges`), not by masks over the table."""

    def __init__(self, table):
        self.time, self.angle, self.rate_setpoint = table.time, table.angle, table.rate_setpoint
        self.rate = table.rate
        self.still = ~table.flag("moving")
        self._runs = increasing_runs(table.time)

    def rows(self, t0: float, t1: float) -> np.ndarray:
        """Indices of the states whose time lies in [t0, t1], in order."""
        ranges = window_ranges(self.time, self._runs, t0, t1)
        return np.concatenate([np.arange(a, b) for a, b in ranges] or [np.zeros(0, np.int64)])


def _commanded(path, table: _States, pos) -> float:
    """c: the table's recorded set point during the rotating windows (one for all positions)."""
    inside = np.concatenate([table.rows(p["r0"], p["r1"]) for p in pos])
    values = np.unique(table.rate_setpoint[inside])
    if values.size != 1 or values[0] == 0:
        raise CalibrationInputError(
            f"the session {path} holds the table set points {values.tolist()} in its rotating "
            "windows (one non-zero rate expected).",
            "Diagnose sessions recorded with the table connected, at one rate.")
    return float(values[0])


def _rate_factor(table: _States, p, c, start: float) -> tuple:
    """(factor, 1-sigma): the angle the table reports between rest before the spin-up (`start`)
    and rest after the stop, over c times the IMU-timed turning time at full rate (`_ramps`). 1
    for a table that reports its command (to the IMU timing's precision, the sigma); the true
    rate over the command for one whose angle reads the shaft. (1, inf) without a reading at rest
    after the stop (a position cut at the end of its spin-down, as imported arrays)."""
    rest = _at_rest(table, p["te"], p["done"])
    if not rest.size:
        return 1.0, math.inf
    factor = (np.median(table.angle[rest]) - start) / (c * p["turning"])
    return factor, factor * p["turning_sd"] / p["turning"]


def _at_rest(table: _States, t0, t1) -> np.ndarray:
    """Indices of the table readings at rest within [t0, t1]."""
    rows = table.rows(t0, t1)
    return rows[table.still[rows]]


def _rest_angle(path, table: _States, t0, t1, j, where) -> float:
    """Median angle of the table readings at rest within [t0, t1]."""
    rest = _at_rest(table, t0, t1)
    if not rest.size:
        raise CalibrationInputError(
            f"the session {path} holds no table reading at rest in position {j + 1}'s {where}.",
            "Record the session with the rotary table connected.")
    return float(np.median(table.angle[rest]))
