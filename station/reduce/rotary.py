"""A recorded rotary session (`station.protocols.rotary`) -> its Eq. (18) readings.

The protocol's events mark, per position, a static and a rotating window; `rotary_readings` turns
the recorded stream into M (m x n), Eq. (18): m_j = mean(rotating) - mean(static), the rotating
window cut to whole revolutions by the table's recorded angle (the arithmetic: `station.reduce.
eq18`). On a two-axis table's spin of the position axis (`rotate_start`/`rotate_end` with detail
`axis: "position"`, `station.protocols.rotary`) the cut follows the position axis' angle, recorded
at the window's two bounds with the instants it was read and interpolated linearly between them
(the protocol held that axis' rate within its tolerance all along). Eq. (18) readings carry no
bias; `static_bias` gives the calibration file its biases from the static windows
(`pooled_static_bias`: several sessions of one unit, their scatter pooled).
"""

import math

import numpy as np

from station.errors import CalibrationInputError, InputError
from station.reduce.eq18 import Reduced, reduce_rotary
from station.reduce.spikes import SPIKE, beyond, column_medians
from station.reduce.windows import StreamWindows, table_angle, table_blocks

STUCK = 100
"""Samples in a window from which a channel that never changes is stuck."""
OVERFULL = 1.01
"""Largest accepted ratio of samples found to samples due in a window (plus one each side)."""


def position_windows(events) -> dict:
    """{position: {"static": (t0, t1), "rotating": (t0, t1)}} in clock seconds for every completed
    position (one with `position_done`); a position recorded again after an abort keeps its last
    run."""
    pairs = {"static": ("static_start", "static_end"), "rotating": ("rotate_start", "rotate_end")}
    times = {}
    for e in events:
        if e.position is not None:
            if e.kind == "position_start":
                times[e.position] = {}
            times.setdefault(e.position, {})[e.kind] = e.time
    return {j: {name: (t[a], t[b]) for name, (a, b) in pairs.items()}
            for j, t in sorted(times.items())
            if "position_done" in t and all(k in t for pair in pairs.values() for k in pair)}


def position_spins(events) -> dict:
    """{position: ((t0, angle0), (t1, angle1))}: the bounds of the rotating window of every
    position whose last one spun the position axis of a two-axis table (event detail `axis:
    "position"`, its `time` and `angle`), checked: finite numbers, t1 > t0."""
    bounds = {}
    for e in events:
        if e.position is None:
            continue
        if e.kind == "position_start":
            bounds.pop(e.position, None)
        elif e.kind in ("rotate_start", "rotate_end") and e.detail.get("axis") == "position":
            bounds.setdefault(e.position, {})[e.kind] = (e.detail.get("time"),
                                                        e.detail.get("angle"))
    spins = {}
    for j, b in bounds.items():
        pair = (b.get("rotate_start"), b.get("rotate_end"))
        values = [v for bound in pair if bound is not None for v in bound]
        if len(values) != 4 or not all(isinstance(v, int | float) and not isinstance(v, bool)
                                       and math.isfinite(v) for v in values) \
                or not values[2] > values[0]:
            raise CalibrationInputError(
                f"position {j + 1}: the position axis' rotating window is not bounded by two "
                f"readings of its angle (got {pair}).",
                "The session was not written by this station's rotary protocol, or is damaged; "
                "record the position again.")
        spins[j] = pair
    return spins


def spin_angle(bounds, t) -> np.ndarray:
    """The position axis' angle at the instants `t`: the line through the window's two bounds
    ((t0, angle0), (t1, angle1)), extended beyond them (the window's events come just after the
    readings)."""
    (t0, a0), (t1, a1) = bounds
    return a0 + (a1 - a0) * (np.asarray(t, float) - t0) / (t1 - t0)


def rotary_readings(session, stream: str = "imu", coverage: float = 0.9,
                   trim: float = 0.0, channels=None) -> Reduced:
    """Eq. (18) readings of a recorded rotary session (`station.session.Session`), SI units.

    Per completed position: the samples whose sampling instant lies in the static window and in
    the rotating window, the latter cut to whole revolutions by the recorded table angle
    (interpolated at the sampling instants). A window holding less than `coverage` of the samples
    due in it (a lossy link) is refused. `trim` s are left out at both ends of every window
    (e.g. to test whether the table's start or stop leaks into the windows). `channels`: the
    stream's columns reduced (None: `rotary_channels`, every one but a temperature's).
    """
    events = session.events()
    stream_windows = StreamWindows(session, stream, events)
    table_times, table = session.table_times(), table_blocks(session)
    if not (math.isfinite(trim) and trim >= 0):
        raise InputError(f"window trim must be >= 0 seconds, got {trim!r}")
    windows = {j: {name: (t0 + trim, t1 - trim) for name, (t0, t1) in w.items()}
               for j, w in position_windows(events).items()}
    spins = position_spins(events)
    if not windows:
        raise CalibrationInputError(f"the session {session.path} has no completed position.",
                                    "Record at least as many positions as the solver asks for.")
    if len(table_times[0]) < 2:
        raise CalibrationInputError(f"the session {session.path} holds no table states.",
                                    "Record the session with the rotary table connected.")
    rate = stream_windows.spec.rate_hz
    keep = _selection(rotary_channels(session, stream) if channels is None else channels,
                      len(stream_windows.spec.channels))
    lsb = 1.0 / np.asarray(stream_windows.spec.counts_per_unit)[keep]
    parts = []
    for j, w in windows.items():
        chosen = {name: _columns(stream_windows.read(t0, t1), keep) for name, (t0, t1) in w.items()}
        for name, (t0, t1) in w.items():
            check_window_count(j, name, len(chosen[name][0]), (t1 - t0) * rate, coverage)
        for name, (_, counts) in chosen.items():
            check_samples(j, name, counts)
        (static, static_counts), (rotating, rotating_counts) = chosen["static"], chosen["rotating"]
        ns, nr = len(static), len(rotating)
        y = np.concatenate([static_counts, rotating_counts])[None]
        instants = stream_windows.t[np.concatenate([static, rotating])]
        angle = (spin_angle(spins[j], instants) if j in spins
                 else table_angle(table, table_times, instants))
        try:
            parts.append(reduce_rotary(y, lsb, {"static": np.array([0, ns]),
                                                "rotating": np.array([ns, ns + nr])}, angle=angle))
        except CalibrationInputError as exc:
            raise CalibrationInputError(f"position {j + 1}: {exc.problem}", exc.advice) from None
    return Reduced(**{name: np.concatenate([getattr(p, name) for p in parts], axis=-1)
                      for name in Reduced.__dataclass_fields__})


def rotary_channels(session, stream: str = "imu") -> np.ndarray:
    """Indices of the gyro channels of a rotary session's stream (`gyro_columns`)."""
    return gyro_columns(session.specs[stream].units)


def gyro_columns(units) -> np.ndarray:
    """Indices of the channels of `units` (a stream's channel units) a rotary session calibrates:
    every channel not in K (a unit's temperature is recorded beside its gyros, never calibrated as
    one: a thermal campaign)."""
    return np.array([i for i, u in enumerate(units) if u != "K"])


def _selection(channels, m: int):
    """The column selection of `channels` among m: a slice when it is all of them in order (the
    counts are then read as they are, not copied: the readings stay bit for bit those of a
    reduction of every column)."""
    channels = np.asarray(channels)
    return slice(None) if np.array_equal(channels, np.arange(m)) else channels


def _columns(window: tuple, keep) -> tuple:
    """A window's (sample indices, counts) with the counts' columns `keep` only."""
    indices, counts = window
    return indices, counts[:, keep]


def check_window_count(j: int, name: str, got: int, due: float, coverage: float = 0.9) -> None:
    """Refuse a window whose sample count does not match its length times the sample rate: fewer
    than `coverage` of the samples due is a lossy link; more than due (beyond one sample each
    side, and `OVERFULL`) means two stretches of the stream were timed onto the same window (a
    resumed or reconnected stream, a device whose clock jumped, samples recorded twice)."""
    if got < coverage * due:
        raise CalibrationInputError(
            f"position {j + 1}: the {name} window holds {got} samples where {due:.0f} were due.",
            "The IMU link lost data: check it and record the position again.")
    if got > OVERFULL * due + 2:
        raise CalibrationInputError(
            f"position {j + 1}: the {name} window holds {got} samples where {due:.0f} were due "
            f"({got / due:.2f}x): the samples' times overlap.",
            "The stream's timing is inconsistent (samples recorded twice, or a device clock or "
            "sequence that jumped): check the IMU link and the host clock, then record the "
            "position again; the mounting is not the cause.")


def check_samples(j: int, name: str, counts) -> None:
    """Refuse a window whose samples hold spikes or a stuck channel. Spikes: readings beyond
    `SPIKE` robust standard deviations (1.4826 MAD) of the window's own median, per channel;
    Gaussian noise puts one sample there in about 1e15, a flipped bit, a zeroed block or a
    glitching sensor puts many, and a window's own scatter would otherwise absorb them into an
    honest-looking uncertainty. Stuck: a channel whose counts do not change over a window of
    `STUCK` samples or more while another channel's do (a noiseless sensor does not exist)."""
    x = np.asarray(counts, float)
    frozen = np.ptp(x, axis=0) == 0 if len(x) >= STUCK else np.zeros(x.shape[1], bool)
    if frozen.any() and not frozen.all():
        raise CalibrationInputError(
            f"position {j + 1}: channel(s) {', '.join(str(c + 1) for c in np.flatnonzero(frozen))}"
            f" kept one value through the {name} window ({len(x)} samples) while the others "
            "varied: a stuck sensor or a frozen field in the frames.",
            "Check the sensor and the device profile's frame layout, then record the position "
            "again.")
    spikes = beyond(x - column_medians(x), 1.0)  # 1 count: quantisation
    if spikes.any():
        channels = np.flatnonzero(spikes.any(axis=0))
        raise CalibrationInputError(
            f"position {j + 1}: the {name} window holds {int(spikes.sum())} reading(s) beyond "
            f"{SPIKE:g} standard deviations of its own noise (channels "
            f"{', '.join(str(c + 1) for c in channels)}).",
            "Spikes are corrupted data or a glitching sensor, not noise: check the IMU link and "
            "the sensor, then record the position again.")


def static_bias(reduced: Reduced) -> dict:
    """The biases of a rotary calibration file: the mean of the static windows over the positions,
    1-sigma their scatter / sqrt(n) (which also holds whatever varies between positions, e.g. the
    Earth's rate)."""
    n = reduced.M.shape[1]
    if n < 2:
        raise CalibrationInputError("one position cannot give the biases' uncertainty.",
                                    "Record more positions.")
    return {"bias": reduced.static_mean.mean(axis=1),
            "bias_sigma": reduced.static_mean.std(axis=1, ddof=1) / np.sqrt(n),
            "bias_source": "static windows of the rotary protocol (mean over positions)"}


def pooled_static_bias(sessions) -> list:
    """`static_bias` of several rotary sessions of one unit (`Reduced` each, e.g. a thermal
    campaign's soaks) whose static windows scatter alike: each session's biases the mean of its
    static windows, their 1-sigma the scatter pooled over the sessions / sqrt(n) per sensor.

    With n_k positions a session's own scatter has n_k - 1 degrees of freedom (5 to 7 in a short
    soak): a fit weighting sessions by such estimated sigmas gives z-scores far heavier-tailed
    than its sigmas say (a tempco's z spread 1.19 for 7 dof against 1). The pooled variance
    sum_k (n_k - 1) s_k^2 / sum_k (n_k - 1) has sum_k (n_k - 1) degrees of freedom, and a z
    standardised by it is Student's t of those (Student 1908; e.g. Montgomery, "Design and
    Analysis of Experiments", 2017, sec. 2.4.4). It assumes the same white noise and
    between-position variation at every session, as the sensor model has it: the `temperature`
    effect moves biases and scale factors, not the noise."""
    single = [static_bias(r) for r in sessions]  # refuses a session of one position
    dof = [r.M.shape[1] - 1 for r in sessions]
    var = sum(d * r.static_mean.var(axis=1, ddof=1)
              for d, r in zip(dof, sessions, strict=True)) / sum(dof)
    source = (f"static windows of the rotary protocol (mean over positions; scatter pooled over "
              f"{len(sessions)} sessions, {sum(dof)} dof)")
    return [{**b, "bias_sigma": np.sqrt(var / (d + 1)), "bias_source": source}
            for d, b in zip(dof, single, strict=True)]
