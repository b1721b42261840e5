"""Replay of a recorded session (rotary, right-angle iron or free-static), for the calibration
engineer.

`replay` reduces the raw IMU stream again and re-solves it, possibly with other settings
(`ReplaySettings`: trimmed windows, a subset of positions, another solver method, no refinement,
another magnitude). `solve_recorded` is the one reduce-and-solve path of the station (`station
replay`, `station solve` and the session report use it); what it does for a session is the kind's
entry in `station.protocols.KINDS`:

- rotary: Eq. (18) of Rupniewski (`station.reduce.rotary.rotary_readings`), then
  `station.calibrate` (closed form, then maximum likelihood weighted by each reading's standard
  error), magnitude = the recorded table rate;
- iron and static: the still poses (`station.reduce.iron.iron_readings` with the faces recognised
  from the data, or `station.reduce.static.static_readings`, both `still_readings`), then
  `station.solve.still.calibrate_still` (biases estimated; the faces' constraints of Eq. 15 for the
  iron, following a subset of poses; Hwangbo & Kanade's factorization or the ellipsoid, then
  maximum likelihood), magnitude = the recorded gravity, reported in the frame of the recorded
  nominal layout `a_nominal` as the live solution is;
- import: the still poses found in the accelerometer stream (`station.reduce.imported`), solved
  as free-static ones, or as faces of a right-angle block (`ReplaySettings.faces`).

It is deterministic: the same file and settings give bit-identical numbers, so the results stored in
a session (`results/<name>`) are reproduced exactly by a replay with the settings that made them.
`replay_into` stores a replay under a new results name (stored results are never overwritten).

`replay_raw` (sessions of kinds with a table: rotary) sends the recorded IMU stream again over the
serial wire protocol (a pseudo-terminal twin, `drivers.twins.serial.SerialTwin`) through the
ordinary driver and recorder into a new session file, with the original's table states and events
placed at the same instants relative to the re-recorded samples: the new file reduces to the same
readings as the original.
"""

import dataclasses
import math
import time
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from drivers.samples import SampleBlock
from station.calfiles.calfile import NoiseFigures
from station.errors import AcquisitionError, CalibrationInputError, InputError
from station.protocols import KINDS, lookup, reference
from station.reduce.still import ACCELEROMETER, GYRO
from station.reduce.stillness import StillOptions
from station.reduce.timeline import SEGMENT_EVENTS, arrival_offset
from station.session import (
    TABLE_STATUS_BITS,
    Session,
    SessionWriter,
    StreamData,
    nominal_layout,
    write_results,
)
from station.solve.calibrate import CalibrationResult

METHODS = ("auto", "pca", "ellipsoid", "factorization")


@dataclass(frozen=True)
class ReplaySettings:
    """How to reduce and solve a session again; the defaults are those of the recording's solution.

    stream    : sample stream to calibrate (None: the kind's, `Kind.stream`, else "imu")
    trim      : seconds left out at both ends of every window (rotary: static and rotating
                windows; iron, static: each pose's averaged window)
    positions : 0-based positions (poses) to use (None: every completed one)
    method    : closed-form method of `station.calibrate` ("auto", "pca", ...)
    refine    : maximum-likelihood refinement after the closed form
    magnitude : stimulus magnitude |v| (None: the recorded table rate, or gravity for the iron
                and static protocols, or the kind's default, standard gravity for an import)
    rest, threshold, still_channels, min_still : the still-pose detector's settings of kinds
                that detect still poses (`station.reduce.stillness.StillOptions`; None: default)
    faces     : the still poses are faces of a right-angle block (kinds with `Kind.faces`:
                an import), solved with the right-angle constraints of Eq. (15)
    channels  : names of the stream's calibrated channels to calibrate, in this order (None: all
                of them), e.g. one IMU's triad of an array recorded as one stream: the others'
                readings are left out of the solve (`channel_rows`)
    accelerometer : the stream whose still poses carry a gyro stream through its turns
                (`solve_carried`; None: the session's one stream in m/s^2)
    """

    stream: str | None = None
    trim: float = 0.0
    positions: tuple | None = None
    method: str = "auto"
    refine: bool = True
    magnitude: float | None = None
    rest: tuple | None = None
    threshold: float | None = None
    still_channels: str | None = None
    min_still: float | None = None
    faces: bool = False
    channels: tuple | None = None
    accelerometer: str | None = None

    def __post_init__(self):
        if self.method not in METHODS:
            raise InputError(f"unknown solver method {self.method!r}; choose one of {METHODS}")
        if not (math.isfinite(self.trim) and self.trim >= 0):
            raise InputError(f"trim must be >= 0 seconds, got {self.trim!r}")
        if self.magnitude is not None and not (math.isfinite(self.magnitude)
                                               and self.magnitude > 0):
            raise InputError(f"magnitude must be positive, got {self.magnitude!r}")
        if self.positions is not None:
            positions = tuple(int(p) for p in self.positions)
            if len(set(positions)) != len(positions) or min(positions, default=0) < 0:
                raise InputError(f"positions must be distinct indices >= 0, got {self.positions}")
            object.__setattr__(self, "positions", positions)
        if self.rest is not None:
            object.__setattr__(self, "rest", self.still.rest)
        if not isinstance(self.faces, bool):
            raise InputError(f"faces must be true or false, got {self.faces!r}")
        if self.channels is not None:
            channels = tuple(self.channels)
            if not channels or len(set(channels)) != len(channels) or not all(
                    isinstance(c, str) and c for c in channels):
                raise InputError(f"channels must be distinct channel names, got {self.channels!r}")
            object.__setattr__(self, "channels", channels)

    @property
    def still(self) -> StillOptions | None:
        """The detector settings given (`StillOptions`), None when none was."""
        given = (self.rest, self.threshold, self.still_channels, self.min_still)
        if all(v is None for v in given):
            return None
        return StillOptions(*given)


def replay(path, settings: ReplaySettings | None = None) -> tuple[object, CalibrationResult]:
    """(readings, calibration) of the session at `path`, reduced and solved again from its raw
    stream (`solve_recorded`)."""
    with Session.open(path) as session:
        return solve_recorded(session, settings or ReplaySettings())


def solve_recorded(session, settings: ReplaySettings, nominal=None,
                   command: str = "replay") -> tuple[object, CalibrationResult]:
    """(readings, calibration) of an open session (`station.session.Session`): the kind's
    reduction, the positions chosen, the kind's solver (`station.protocols.KINDS`).

    readings: `station.reduce.eq18.Reduced` (rotary) or `StillReadings` (iron, static); nominal:
    the frame of the result (d x m), default the recorded layout for kinds solved in it; command:
    who asks, for the error about a kind without a reduction.
    """
    kind = lookup(session.protocol, "reduce", f"{session.path} records a {session.protocol!r} "
                  "session", command)
    magnitude, _ = stimulus(session, settings)
    readings = reduce_recorded(session, settings, command)
    if kind.nominal_frame and nominal is None:
        nominal = recorded_layout(session, settings)
    return readings, kind.entry("solve")(readings, magnitude, nominal=nominal,
                                         method=settings.method, refine=settings.refine)


def recorded_noise(session, stream: str, channels) -> tuple[NoiseFigures | None, str | None]:
    """(figures, None): the `NoiseFigures` of the calibrated `channels` (indices into the
    stream's) of an open session's `stream`, from its static data (`station.reduce.noise.
    session_noise`: the protocol's static windows or still poses, else still intervals found in
    the stream); (None, why) when there are none: the problem `session_noise` names (too little
    static data, a channel that never varies)."""
    from station.reduce.noise import session_noise  # allantools loads scipy's stats: 0.4 s

    try:
        found = session_noise(session, stream, channels)
    except CalibrationInputError as exc:
        return None, exc.problem
    return NoiseFigures.from_fit(found.fit, found.curve.rate, found.curve.seconds), None


def noise_stream(session, cal=None) -> str:
    """The stream `station noise` analyses when none is named: with a calibration `cal` (--store)
    the one stream holding its sensors (by name, else enough channels in its unit); otherwise, or
    when no single stream does, the one `station solve` calibrates (`calibrated_stream`: an
    import's one stream in m/s^2, a recording's "imu"), which names the streams to choose from
    when there are several."""
    if cal is not None:
        for holds in (lambda spec: set(cal.sensors) <= set(spec.channels),
                      lambda spec: list(spec.units).count(cal.units[0]) == cal.m):
            found = [name for name, spec in session.specs.items() if holds(spec)]
            if len(found) == 1:
                return found[0]
    return calibrated_stream(session, ReplaySettings())


def calibration_channels(session, stream: str, cal) -> np.ndarray:
    """Indices into `stream`'s channels of the calibration `cal`'s sensors, in their order: by
    name, or, when the names differ (a gyro carried through the turns names its sensors gyro1..),
    the stream's channels in the calibration's unit when there are exactly m of them;
    CalibrationInputError naming both otherwise."""
    spec = session.specs[stream]
    if all(name in spec.channels for name in cal.sensors):
        rows = [spec.channels.index(name) for name in cal.sensors]
    else:
        rows = [i for i, unit in enumerate(spec.units) if unit == cal.units[0]]
    if len(rows) != cal.m or any(spec.units[i] != cal.units[k] for k, i in enumerate(rows)):
        raise CalibrationInputError(
            f"{session.path}: stream {stream!r} (channels {', '.join(spec.channels)}; units "
            f"{', '.join(sorted(set(spec.units)))}) does not hold the calibration's "
            f"{cal.m} sensors {', '.join(cal.sensors)} in {cal.units[0]}.",
            f"Give the stream of the unit's {cal.units[0]} sensors with --stream (the session's "
            f"streams: {', '.join(session.specs)}).")
    return np.asarray(rows, np.int64)


def carried(session, stream: str) -> bool:
    """True when `stream` is a gyro triad (rad/s, no m/s^2) of a session whose kind calibrates
    gyros by carrying gravity through the turns (`Kind.carry`: an import)."""
    kind = KINDS.get(session.protocol)
    units = session.specs[stream].units
    return kind is not None and kind.has("carry") and GYRO in units and ACCELEROMETER not in units


def solve_carried(session, settings: ReplaySettings, nominal=None,
                  command: str = "station solve") -> tuple:
    """(accelerometer stream, its readings, its calibration, the gyro's `CarryCalibration`) of the
    gyro stream `settings.stream` of an open session (`carried`): the accelerometer calibrated
    first on its still poses by the one path (`solve_recorded`, the same detector settings), then
    the gyro by carrying gravity through the turns between those poses (Tedaldi et al.,
    `station.solve.gyro_carry.calibrate_carry`), in the accelerometer calibration's frame."""
    from station.solve.gyro_carry import calibrate_carry

    found = [n for n, spec in session.specs.items() if ACCELEROMETER in spec.units]
    if settings.accelerometer is not None and settings.accelerometer not in found:
        raise CalibrationInputError(
            f"{session.path}: --accelerometer {settings.accelerometer!r} is not a stream in "
            f"{ACCELEROMETER}; the session's are {', '.join(found) or 'none'}.",
            "Name one of them.")
    if settings.accelerometer is not None:
        found = [settings.accelerometer]
    if len(found) != 1:
        raise CalibrationInputError(
            f"{session.path}: the gyro stream {settings.stream!r} is calibrated by carrying "
            f"gravity, measured by one accelerometer, through its turns; the streams in "
            f"{ACCELEROMETER} are {', '.join(found) or 'none'}.",
            "Name the one on the gyro's unit with --accelerometer NAME." if found else
            "Import the accelerometer (one stream with --unit NAME=m/s^2) with the gyro.")
    acc_settings = dataclasses.replace(settings, stream=found[0], accelerometer=None)
    readings, acc = solve_recorded(session, acc_settings, nominal, command)
    gyro, z, intervals = KINDS[session.protocol].entry("carry")(session, settings.stream,
                                                                found[0], readings)
    rate = session.specs[found[0]].rate_hz
    return found[0], readings, acc, calibrate_carry(gyro, rate, acc.apply(z.T).T, intervals)


def reduce_recorded(session, settings: ReplaySettings, command: str = "replay"):
    """The readings of an open session with the settings: the kind's reduction of the calibrated
    stream (with the detector's settings for kinds that detect still poses), the positions
    chosen among the completed ones (every pose of a recording without protocol events)."""
    name, path = session.protocol, session.path
    kind = lookup(name, "reduce", f"{path} records a {name!r} session", command)
    options = {"trim": settings.trim}
    if settings.still is not None:
        if not kind.still:
            raise InputError(f"{path} records a {name!r} session, which has no still poses to "
                             "detect; --rest, --threshold, --still-channels and --min-still are "
                             "for still-pose sessions (iron, static, import)")
        options["still"] = settings.still
    if settings.faces:
        if not kind.faces:
            raise InputError(f"{path} records a {name!r} session; --faces is for "
                             f"{', '.join(n for n, k in KINDS.items() if k.faces)} sessions (an "
                             "iron session recognises its faces always): leave it out")
        options["faces"] = True
    readings = kind.entry("reduce")(session, calibrated_stream(session, settings), **options)
    rows = channel_rows(session, settings)
    if rows is not None:
        readings = readings.sensors(rows)
    completed = sorted(_completed(session.events())) or list(range(readings.M.shape[1]))
    return _select(readings, completed, settings.positions, path)


def calibrated_stream(session, settings: ReplaySettings) -> str:
    """The stream the settings calibrate: theirs, else the kind's default (`Kind.stream`), else
    "imu"; checked against the session's streams."""
    kind = KINDS.get(session.protocol)
    stream = settings.stream
    if stream is None:
        stream = kind.entry("stream")(session) if kind is not None and kind.has("stream") else "imu"
    if stream not in session.specs:
        raise CalibrationInputError(f"{session.path} has no stream {stream!r}.",
                                    f"Choose one of {sorted(session.specs)} with --stream.")
    return stream


def calibrated_channels(session, stream: str) -> np.ndarray:
    """Indices into `stream`'s channels of those its session's kind calibrates (`Kind.channels`:
    e.g. a rotary session's gyros; default every channel)."""
    kind = KINDS.get(session.protocol)
    if kind is not None and kind.has("channels"):
        return np.asarray(kind.entry("channels")(session, stream))
    return np.arange(len(session.specs[stream].channels))


def solved_channels(session, settings: ReplaySettings) -> np.ndarray:
    """Indices into the calibrated stream's channels of those the settings calibrate, in order:
    the kind's (`calibrated_channels`), or the ones `settings.channels` names."""
    channels = calibrated_channels(session, calibrated_stream(session, settings))
    rows = channel_rows(session, settings)
    return channels if rows is None else channels[rows]


def channel_rows(session, settings: ReplaySettings) -> np.ndarray | None:
    """Rows of the calibrated channels (`calibrated_channels`) that `settings.channels` names, in
    its order; None when it names none (all). Refused: a name the stream does not calibrate,
    fewer than 3 (a frame needs a triad), and a gyro triad calibrated by carrying gravity
    (`carried`: calibrated whole, with the accelerometer)."""
    if settings.channels is None:
        return None
    stream = calibrated_stream(session, settings)
    spec = session.specs[stream]
    names = [spec.channels[i] for i in calibrated_channels(session, stream)]
    unknown = [c for c in settings.channels if c not in names]
    if unknown:
        raise InputError(f"{session.path}: stream {stream!r} has no calibrated channel "
                         f"{', '.join(map(repr, unknown))}; --channels takes names among "
                         f"{', '.join(names)}")
    if len(settings.channels) < 3:
        raise InputError(f"--channels names {len(settings.channels)} channel(s); a calibration "
                         "needs at least 3 (a triad) to span the frame: name a whole triad")
    if carried(session, stream):
        raise InputError(f"{session.path}: the gyro triad {stream!r} is calibrated whole, from "
                         "the turns between the accelerometer's poses: leave --channels out")
    return np.array([names.index(c) for c in settings.channels])


UNIT_FIELD = ("unknown (no --magnitude): calibrated to the local field's unit sphere, scale "
              "factors per local field and the calibrated field in units of it (|B| = 1); "
              "--magnitude with the local field in T gives them in T")
"""The stimulus in words of a magnetometer calibrated without the field's magnitude."""


def stimulus(session, settings: ReplaySettings) -> tuple[float | None, str]:
    """(stimulus magnitude, where it comes from in words): --magnitude, else the recorded one,
    else the kind's default (`Kind.stimulus_default`, e.g. standard gravity for an import); a
    magnetometer (a stream in T) without --magnitude: None, the local field's unit sphere
    (`station.calibrate` with the magnitude unknown: Remark 2, `scale_known` false)."""
    if settings.magnitude is not None:
        return settings.magnitude, "given (--magnitude)"
    if "T" in session.specs[calibrated_stream(session, settings)].units:
        return None, UNIT_FIELD
    kind = lookup(session.protocol, "reduce", f"{session.path} records a {session.protocol!r} "
                  "session")
    words, keys = kind.stimulus
    if kind.stimulus_default is not None and _recorded(session.metadata, keys) is None:
        name, ref = kind.stimulus_default
        return float(reference(ref)), f"{name}: the session records no {words} (--magnitude " \
            "gives the local value)"
    return recorded_magnitude(session.metadata, kind.stimulus, session.path), f"recorded {words}"


def _recorded(metadata: dict, keys):
    """The value at `keys` (outermost first) of the metadata, None when absent."""
    value = metadata
    for key in keys:
        value = value.get(key) if isinstance(value, dict) else None
    return value


def recorded_magnitude(metadata: dict, stimulus: tuple, path) -> float:
    """|stimulus magnitude| recorded in the (untrusted) metadata; stimulus: (words, keys outermost
    first), a `Kind.stimulus`."""
    words, keys = stimulus
    value = _recorded(metadata, keys)
    if type(value) not in (int, float) or not math.isfinite(value) or value == 0:
        raise CalibrationInputError(f"{path} records no usable {words} ({value!r}).",
                                    "Give the stimulus magnitude with --magnitude.")
    return abs(float(value))


def recorded_layout(session, settings: ReplaySettings, refuse: bool = True):
    """The nominal layout (3 x m) of the channels the settings calibrate (`channel_rows`) that an
    open session's (untrusted) metadata records as `a_nominal`; when it records none: refused, or
    None unless `refuse`."""
    stream = calibrated_stream(session, settings)
    m = len(calibrated_channels(session, stream))
    nominal = nominal_layout(session.metadata, m)
    if nominal is None:
        if not refuse:
            return None
        raise CalibrationInputError(
            f"{session.path} records no usable nominal layout a_nominal (3 x {m}).",
            "Give one with --nominal (a CSV of 3 rows, a column per sensor), or check that the "
            "session file is from a still-pose protocol.")
    rows = channel_rows(session, settings)
    return nominal if rows is None else nominal[:, rows]


def _select(readings, completed: list, positions, path):
    """The readings of `positions` (0-based, None: all) among the `completed` ones."""
    if len(completed) != readings.M.shape[1]:
        raise InputError(f"{path} reduces to {readings.M.shape[1]} readings for "
                         f"{len(completed)} completed positions; the file is damaged")
    if positions is None:
        return readings
    missing = sorted(set(positions) - set(completed))
    if missing:
        raise InputError(f"positions {[p + 1 for p in missing]} were not completed in {path}; "
                         f"choose among {[p + 1 for p in completed]}")
    return readings.take([completed.index(p) for p in positions])


def replay_into(path, name: str, settings: ReplaySettings | None = None):
    """Replay the session and store the readings and calibration as `results/<name>`, with the
    settings that made them (`SessionResults.settings`; `stored_settings` reads them back)."""
    settings = settings or ReplaySettings()
    with Session.open(path) as session:
        stream = calibrated_stream(session, settings)
        channels = solved_channels(session, settings)
    reduced, result = replay(path, settings)
    write_results(path, name, stream, reduced.M, result, reduced.sigma,
                  settings=dataclasses.asdict(settings), channels=channels.tolist())
    return reduced, result


def stored_settings(path, name: str) -> ReplaySettings:
    """The ReplaySettings stored with `results/<name>` (a replay's), to reproduce or vary them;
    ValueError when those results were not made by a replay."""
    with Session.open(path) as session:
        stored = session.results(name).settings
    if stored is None:
        raise InputError(f"results/{name} of {path} holds no replay settings (the recording's "
                         "own results: replay with the defaults reproduces them)")
    known = {f.name for f in dataclasses.fields(ReplaySettings)}
    if not set(stored) <= known:
        raise InputError(f"results/{name} holds unknown settings {sorted(set(stored) - known)}; "
                         "it was written by a newer station")
    return ReplaySettings(**stored)


def free_name(path, prefix: str = "replay") -> str:
    """The first results name `<prefix>-1`, `<prefix>-2`, ... not yet used in the session."""
    with Session.open(path) as session:
        used = set(session.result_names)
    return next(f"{prefix}-{k}" for k in range(1, len(used) + 2) if f"{prefix}-{k}" not in used)


def _completed(events) -> set:
    return {e.position for e in events if e.kind == "position_done"}


# -------------------------------------------------------------------------------- raw replay


def as_block(data: StreamData) -> SampleBlock:
    """A recorded stream as the one `SampleBlock` a driver would have read (counts as int64)."""
    return SampleBlock(data.counts.astype(np.int64), data.seq, data.device_time, data.host_time,
                       data.spec.channels)


def replay_raw(path, out, profile="imu12_serial", speed: float = 200.0,
               timeout: float = 120.0, progress=None) -> None:
    """Send the IMU stream of session `path` over a serial twin, record it into session `out`.

    profile : serial device profile (name or path) whose channels and scale match the stream;
              its rate is set to the stream's
    speed   : clock speed of the replay (simulated s per wall s)
    timeout : wall seconds the re-recording may take
    progress : optional callable(samples re-recorded, samples to re-record)
    The stream must be one gap-free segment (a session that was never resumed or reconnected).
    """
    from drivers import open_imu
    from drivers.clock import ScaledClock
    from drivers.profile import SerialImuProfile
    from drivers.twins.serial import SerialTwin
    from station.acquire.recorder import Recorder

    with Session.open(path) as session:
        kind = KINDS.get(session.protocol)
        if kind is None or not kind.table:
            tabled = ", ".join(name for name, k in KINDS.items() if k.table)
            raise InputError(f"{path} records a {session.protocol!r} session; raw replay "
                             f"re-records {tabled} sessions only (stream, table states and "
                             "events); replay it without --raw to reduce and solve it again")
        data, table, events = session.stream("imu"), session.table(), session.events()
        metadata = session.metadata
    segments = [e.kind for e in events if e.kind in SEGMENT_EVENTS]
    if segments or np.any(np.diff(data.seq) != 1):
        raise InputError(f"{path}: the IMU stream has gaps or several segments ({segments}); "
                         "raw replay needs one gap-free recording")
    spec = data.spec
    loaded = SerialImuProfile.load(profile)
    if tuple(loaded.imu.channels) != spec.channels or \
            not np.array_equal(np.broadcast_to(loaded.imu.scale, len(spec.channels)),
                               spec.counts_per_unit):
        raise InputError(f"serial profile {profile!r} does not match the stream's channels and "
                         "counts per unit; give the profile of the recorded device")
    loaded = dataclasses.replace(loaded, imu=dataclasses.replace(loaded.imu, rate_hz=spec.rate_hz))
    recorded = as_block(data)
    counts, k = recorded.counts, len(recorded)
    clock = ScaledClock(speed)
    twin = SerialTwin(loaded, lambda t: counts[np.clip(
        np.round((t - twin.start_time) * spec.rate_hz).astype(np.int64), 0, k - 1)], clock,
        max_lag=np.inf)
    replayed = {**metadata, "replay_of": str(path)}
    # the port is opened before the twin streams: opening flushes what the port holds (pyserial),
    # and frame 0 must not be among it on a busy host
    with open_imu("serial", twin.port, loaded, clock) as imu, twin, \
            SessionWriter.create(out, replayed, {"imu": spec}, clock=clock) as writer:
        with Recorder(writer, imu, clock=clock) as recorder:
            deadline = time.monotonic() + timeout
            while recorder.samples < k:
                if progress is not None:
                    progress(recorder.samples, k)
                recorder.check(stale=10.0)
                if time.monotonic() > deadline:
                    raise AcquisitionError(f"raw replay got {recorder.samples} of {k} samples in "
                                       f"{timeout} s")
                time.sleep(0.01)
        writer.flush()
        with Session.open(out) as again:
            new = again.stream("imu")
        shift = (arrival_offset(new.seq, new.host_time, spec.rate_hz)
                 - arrival_offset(data.seq, data.host_time, spec.rate_hz)
                 - (data.seq[0] - new.seq[0]) / spec.rate_hz)
        writer.append_table([SimpleNamespace(
            time=table.time[i] + shift, rate=table.rate[i], angle=table.angle[i],
            rate_setpoint=table.rate_setpoint[i],
            **{bit: bool(table.status[i] >> b & 1) for b, bit in enumerate(TABLE_STATUS_BITS)})
            for i in range(len(table.time))])
        for e in events:
            if e.kind != "session_start":
                writer.event(e.kind, e.position, e.detail, time=e.time + shift)
