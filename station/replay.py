"""Replay of a recorded rotary session, for the calibration engineer.

`replay` re-reduces the raw IMU stream (Eq. 18 of Rupniewski, `reduce_session`) and re-solves it
(`station.calibrate`: closed form, then maximum likelihood weighted by each reading's standard
error, magnitude = the recorded table rate), possibly with other settings (`ReplaySettings`:
trimmed windows, a subset of positions, another solver method). It is deterministic: the same
file and settings give bit-identical numbers, so the results stored in a session (`results/<name>`)
are reproduced exactly by a replay with the settings that made them. `replay_into` stores a
replay under a new results name (stored results are never overwritten).

`replay_raw` sends the recorded IMU stream again over the serial wire protocol (a pseudo-terminal
twin, `drivers.twin_serial.SerialTwin`) through the ordinary driver and recorder into a new session
file, with the original's table states and events placed at the same instants relative to the
re-recorded samples: the new file reduces to the same readings as the original.
"""

import math
import time
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

import station
from station.calibrate import CalibrationResult
from station.protocols.rotary import SEGMENT_EVENTS, reduce_session
from station.recorder import arrival_offset
from station.reduction import Reduced
from station.session import (
    TABLE_STATUS_BITS,
    Session,
    SessionWriter,
    write_results,
)

METHODS = ("auto", "pca", "ellipsoid", "factorization")


@dataclass(frozen=True)
class ReplaySettings:
    """How to reduce and solve a session again; the defaults are those of `station solve`.

    stream    : sample stream to calibrate
    trim      : seconds left out at both ends of every window
    positions : 0-based positions to use (None: every completed position)
    method    : closed-form method of `station.calibrate` ("auto", "pca", ...)
    refine    : maximum-likelihood refinement after the closed form
    magnitude : stimulus magnitude |v| (None: the recorded table rate)
    """

    stream: str = "imu"
    trim: float = 0.0
    positions: tuple | None = None
    method: str = "auto"
    refine: bool = True
    magnitude: float | None = None

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"unknown solver method {self.method!r}; choose one of {METHODS}")
        if not (math.isfinite(self.trim) and self.trim >= 0):
            raise ValueError(f"trim must be >= 0 seconds, got {self.trim!r}")
        if self.magnitude is not None and not (math.isfinite(self.magnitude)
                                               and self.magnitude > 0):
            raise ValueError(f"magnitude must be positive, got {self.magnitude!r}")
        if self.positions is not None:
            positions = tuple(int(p) for p in self.positions)
            if len(set(positions)) != len(positions) or min(positions, default=0) < 0:
                raise ValueError(f"positions must be distinct indices >= 0, got {self.positions}")
            object.__setattr__(self, "positions", positions)


def replay(path, settings: ReplaySettings | None = None) -> tuple[Reduced, CalibrationResult]:
    """(readings, calibration) of the rotary session at `path`, solved again from the raw stream."""
    settings = settings or ReplaySettings()
    with Session.open(path) as session:
        if session.protocol != "rotary":
            raise ValueError(f"{path} records a {session.protocol!r} session; replay reduces "
                             "rotary sessions")
        reduced = reduce_session(session, settings.stream, trim=settings.trim)
        completed = sorted(_completed(session.events()))
        rate = session.metadata.get("settings", {}).get("rate")
    if settings.positions is not None:
        missing = sorted(set(settings.positions) - set(completed))
        if missing:
            raise ValueError(f"positions {[p + 1 for p in missing]} were not completed in {path}; "
                             f"choose among {[p + 1 for p in completed]}")
        keep = [completed.index(p) for p in settings.positions]
        reduced = Reduced(**{name: getattr(reduced, name)[..., keep]
                             for name in Reduced.__dataclass_fields__})
    magnitude = settings.magnitude
    if magnitude is None:
        if not isinstance(rate, int | float) or not math.isfinite(rate) or rate == 0:
            raise ValueError(f"{path} records no usable table rate; give the magnitude")
        magnitude = abs(float(rate))
    result = station.calibrate(reduced.M, magnitude, sigma=reduced.sigma,
                               method=settings.method, refine=settings.refine)
    return reduced, result


def replay_into(path, name: str, settings: ReplaySettings | None = None):
    """Replay the session and store the readings and calibration as `results/<name>`."""
    settings = settings or ReplaySettings()
    reduced, result = replay(path, settings)
    write_results(path, name, settings.stream, reduced.M, result, reduced.sigma)
    return reduced, result


def free_name(path, prefix: str = "replay") -> str:
    """The first results name `<prefix>-1`, `<prefix>-2`, ... not yet used in the session."""
    with Session.open(path) as session:
        used = set(session.result_names)
    return next(f"{prefix}-{k}" for k in range(1, len(used) + 2) if f"{prefix}-{k}" not in used)


def _completed(events) -> set:
    return {e.position for e in events if e.kind == "position_done"}


# -------------------------------------------------------------------------------- raw replay


def replay_raw(path, out, profile="imu12_serial", speed: float = 200.0,
               timeout: float = 120.0) -> None:
    """Send the IMU stream of session `path` over a serial twin, record it into session `out`.

    profile : serial device profile (name or path) whose channels and scale match the stream;
              its rate is set to the stream's
    speed   : clock speed of the replay (simulated s per wall s)
    timeout : wall seconds the re-recording may take
    The stream must be one gap-free segment (a session that was never resumed or reconnected).
    """
    import dataclasses

    from drivers.profile import SerialImuProfile
    from drivers.serial_imu import SerialImu
    from drivers.twin_serial import SerialTwin
    from station.clock import ScaledClock
    from station.recorder import Recorder

    with Session.open(path) as session:
        data, table, events = session.stream("imu"), session.table(), session.events()
        metadata = session.metadata
    segments = [e.kind for e in events if e.kind in SEGMENT_EVENTS]
    if segments or np.any(np.diff(data.seq) != 1):
        raise ValueError(f"{path}: the IMU stream has gaps or several segments ({segments}); "
                         "raw replay needs one gap-free recording")
    spec = data.spec
    loaded = SerialImuProfile.load(profile)
    if tuple(loaded.imu.channels) != spec.channels or \
            not np.array_equal(np.broadcast_to(loaded.imu.scale, len(spec.channels)),
                               spec.counts_per_unit):
        raise ValueError(f"serial profile {profile!r} does not match the stream's channels and "
                         "counts per unit; give the profile of the recorded device")
    loaded = dataclasses.replace(loaded, imu=dataclasses.replace(loaded.imu, rate_hz=spec.rate_hz))
    counts, k = data.counts.astype(np.int64), len(data.seq)
    clock = ScaledClock(speed)
    twin = SerialTwin(loaded, lambda t: counts[np.clip(
        np.round((t - twin.start_time) * spec.rate_hz).astype(np.int64), 0, k - 1)], clock,
        max_lag=np.inf)
    replayed = {**metadata, "replay_of": str(path)}
    # the port is opened before the twin streams: opening flushes what the port holds (pyserial),
    # and frame 0 must not be among it on a busy host
    with SerialImu(twin.port, loaded, clock) as imu, twin, \
            SessionWriter.create(out, replayed, {"imu": spec}, clock=clock) as writer:
        with Recorder(writer, imu, clock=clock) as recorder:
            deadline = time.monotonic() + timeout
            while recorder.samples < k:
                recorder.check(stale=10.0)
                if time.monotonic() > deadline:
                    raise TimeoutError(f"raw replay got {recorder.samples} of {k} samples in "
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
