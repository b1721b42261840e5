"""The session file's format: names, version, columns, units and the data classes of what is read
(docs/session-format.md). No HDF5 I/O here: the writer and the reader share these definitions."""

import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from station.errors import InputError, SessionFormatError

if TYPE_CHECKING:  # the solver (scipy) loads only where a calibration is read or written
    from station.solve.calibrate import CalibrationResult

FORMAT = "imu-station-session"
FORMAT_VERSION = 1
SUPPORTED_VERSIONS = (1,)
LIBVER = ("v110", "v110")
STREAM_COLUMNS = ("counts", "seq", "device_time", "host_time")
TABLE_COLUMNS = ("time", "rate", "angle", "rate_setpoint", "status")
TABLE_UNITS = {"time": "s", "rate": "rad/s", "angle": "rad", "rate_setpoint": "rad/s",
               "status": "1"}
TABLE_STATUS_BITS = ("running", "ready", "moving", "at_rate", "fault")  # bit i = name i
EVENT_COLUMNS = ("time", "position", "kind", "detail_end")
EVENT_KINDS = ("session_start", "session_resumed", "position_start", "static_start", "static_end",
               "rotate_start", "rotate_end", "position_done", "pause", "resume", "fault", "note",
               "abort")
KIND_DTYPE = np.dtype("S24")
NAME = re.compile(r"[a-z][a-z0-9_]{0,31}\Z")
RESULT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}\Z")
MAX_JSON_BYTES = 16 << 20
CHUNK_BYTES = 64 << 10
COUNTS = "counts"
"""The unit of readings that are raw counts whose scale is not known (`Session.reading_units`)."""
STREAM_UNITS = {"counts": "count", "seq": "1", "device_time": "s", "host_time": "s"}
"""`units` attribute of each stream dataset (SI units of the counts: the group's `units`)."""
EVENT_UNITS = {"time": "s", "position": "1", "kind": "1", "detail_end": "byte", "detail": "byte"}
"""`units` attribute of each events dataset."""
TIME_SCALES = {"streams": "host_time", "table": "time", "events": "time"}
"""The column of each group kind that is the HDF5 dimension scale of the other columns' rows."""


@dataclass(frozen=True)
class StreamSpec:
    """What one raw sample stream holds: m channels of integer counts.

    channels        : channel names, in column order of `SampleBlock.counts`
    units           : SI unit of each channel (one string applies to all)
    counts_per_unit : counts per SI unit of each channel (the device profile's `scale`)
    rate_hz         : nominal sample rate
    dtype           : "int32" or "int64", storage type of the counts
    device          : device model name (profile `[imu] name`)
    """

    channels: tuple
    units: tuple
    counts_per_unit: tuple
    rate_hz: float
    dtype: str = "int32"
    device: str = ""

    def __post_init__(self):
        channels = tuple(str(c) for c in self.channels)
        m = len(channels)
        if m == 0 or len(set(channels)) != m or not all(channels):
            raise InputError(f"stream channels must be distinct non-empty names, got {channels!r}")
        units = (self.units,) * m if isinstance(self.units, str) else tuple(self.units)
        scale = np.broadcast_to(np.asarray(self.counts_per_unit, dtype=float), (m,))
        if len(units) != m:
            raise InputError(f"stream has {m} channels but {len(units)} units; give one each")
        if not (np.all(np.isfinite(scale)) and np.all(scale > 0)):
            raise InputError("counts_per_unit must be finite and positive (counts per SI unit)")
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise InputError(f"rate_hz must be a positive sample rate, got {self.rate_hz!r}")
        if self.dtype not in ("int32", "int64"):
            raise InputError(f"counts dtype must be 'int32' or 'int64', got {self.dtype!r}")
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "units", units)
        object.__setattr__(self, "counts_per_unit", tuple(float(s) for s in scale))
        object.__setattr__(self, "rate_hz", float(self.rate_hz))

    @classmethod
    def from_profile(cls, imu, dtype: str = "int32") -> "StreamSpec":
        """The spec of a device profile's `[imu]` section (`drivers.profile.ImuSection`)."""
        return cls(imu.channels, imu.units, imu.scale, imu.rate_hz, dtype, imu.name)


@dataclass(frozen=True)
class StreamData:
    """A recorded sample stream: the `SampleBlock` columns and the stream's description."""

    counts: np.ndarray | None  # (k, m) int32 or int64
    seq: np.ndarray | None  # (k,) int64
    device_time: np.ndarray | None  # (k,) float64 s
    host_time: np.ndarray | None  # (k,) float64 s; a column not read (Session.stream) is None
    spec: StreamSpec
    rows: np.ndarray | None = None  # (k,) file row of each sample; None: the k rows read, in order

    def to_si(self) -> np.ndarray:
        """Readings (k, m) in SI units: counts / counts_per_unit."""
        return self.counts / np.asarray(self.spec.counts_per_unit)


@dataclass(frozen=True)
class TableData:
    """The recorded rotary-table state; `status` bit i is `TABLE_STATUS_BITS[i]`."""

    time: np.ndarray  # (k,) s, host clock
    rate: np.ndarray  # (k,) rad/s
    angle: np.ndarray  # (k,) rad, cumulative
    rate_setpoint: np.ndarray  # (k,) rad/s
    status: np.ndarray  # (k,) uint8
    rows: np.ndarray | None = None  # (k,) file row of each state; None: the k rows read, in order

    def flag(self, name: str) -> np.ndarray:
        """Boolean array of one status bit, e.g. `flag("at_rate")`."""
        if name not in TABLE_STATUS_BITS:
            raise InputError(f"unknown table status bit {name!r}; known: {TABLE_STATUS_BITS}")
        return (self.status >> TABLE_STATUS_BITS.index(name) & 1).astype(bool)


@dataclass(frozen=True)
class Event:
    """One protocol event; `position` is None for events that belong to no position."""

    time: float
    position: int | None
    kind: str
    detail: dict


@dataclass(frozen=True)
class SessionResults:
    """One `results/<name>` group: reduced readings M (m x n, SI) and optionally the calibration."""

    name: str
    stream: str
    units: tuple  # SI unit of each row of `readings`
    readings: np.ndarray  # (m, n)
    readings_sigma: np.ndarray | None  # (m, n) standard deviation of each entry
    calibration: "CalibrationResult | None"
    created: str
    settings: dict | None = None  # what reduced and solved them (replay), None: the recording's
    channels: tuple | None = None  # the stream's channels the rows are; None: all, in order
    sequence: int = 0  # results in the file before these were written (0 in files before it)

    @property
    def order(self) -> tuple:
        """The key that sorts results oldest first: `created` is to the second, so results written
        within one second of each other are told apart by their `sequence`."""
        return self.created, self.sequence


def last_completed_position(events) -> int | None:
    """Position of the most recent `position_done` event, None if no position was completed."""
    done = [e.position for e in events if e.kind == "position_done"]
    return done[-1] if done else None


def nominal_layout(metadata: dict, m: int) -> np.ndarray | None:
    """The nominal layout (3 x m) a session's (untrusted) metadata records as `a_nominal`, or
    None when it records no usable one."""
    try:
        nominal = np.asarray(metadata.get("a_nominal"), dtype=float)
    except (TypeError, ValueError):
        return None
    return nominal if nominal.shape == (3, m) and np.all(np.isfinite(nominal)) else None


def complete_events(ends, detail_length, where="") -> int:
    """How many events have their whole detail text flushed (`ends` must increase)."""
    if len(ends) and (ends[0] < 0 or np.any(np.diff(ends) < 0)):
        raise SessionFormatError(f"{where}: events/detail_end is not increasing")
    return int(np.searchsorted(ends, detail_length, side="right"))


def float_matrix(values, what, rows=None, shape=None) -> np.ndarray:
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 2 or (rows is not None and x.shape[0] != rows) or (shape and x.shape != shape):
        want = shape or f"({rows}, n)"
        raise InputError(f"{what} has shape {x.shape}, expected {want} (sensors x positions)")
    return x
