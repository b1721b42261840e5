"""The crash-safe HDF5 session file: one unit, one protocol run (format: docs/session-format.md).

`SessionWriter` records sample streams, the rotary-table state and protocol events while a session
runs. Every dataset exists before the file switches to HDF5 single-writer/multiple-reader (SWMR)
mode (libver v110); samples are buffered and written in batches, flushed about once a second, so
that a writer killed at any moment leaves a readable file holding every flushed sample.
`SessionWriter.resume` reopens such a file and continues it. Results are written after the
acquisition, outside SWMR mode (new groups cannot be created in SWMR mode).

`Session` reads a file, also while a writer is live (SWMR read). Every file is untrusted: the format
and version are checked first, then the type and shape of everything read; nothing is evaluated or
unpickled, JSON is the only text decoded.
"""

import dataclasses
import fcntl
import json
import math
import numbers
import os
import re
import struct
import threading
import time
from dataclasses import dataclass

import h5py
import numpy as np

from drivers.samples import SampleBlock
from station.solve.calibrate import CalibrationResult
from drivers.clock import WallClock
from station.files.provenance import software_version, utc_now
from station.errors import SessionFormatError, SessionLockedError

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
ALLOWED_FILTERS = {h5py.h5z.FILTER_DEFLATE, h5py.h5z.FILTER_SHUFFLE, h5py.h5z.FILTER_FLETCHER32}


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
            raise ValueError(f"stream channels must be distinct non-empty names, got {channels!r}")
        units = (self.units,) * m if isinstance(self.units, str) else tuple(self.units)
        scale = np.broadcast_to(np.asarray(self.counts_per_unit, dtype=float), (m,))
        if len(units) != m:
            raise ValueError(f"stream has {m} channels but {len(units)} units; give one each")
        if not (np.all(np.isfinite(scale)) and np.all(scale > 0)):
            raise ValueError("counts_per_unit must be finite and positive (counts per SI unit)")
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ValueError(f"rate_hz must be a positive sample rate, got {self.rate_hz!r}")
        if self.dtype not in ("int32", "int64"):
            raise ValueError(f"counts dtype must be 'int32' or 'int64', got {self.dtype!r}")
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

    counts: np.ndarray  # (k, m) int32 or int64
    seq: np.ndarray  # (k,) int64
    device_time: np.ndarray  # (k,) float64 s
    host_time: np.ndarray  # (k,) float64 s
    spec: StreamSpec

    def to_si(self) -> np.ndarray:
        """Readings (k, m) in SI units: counts / counts_per_unit."""
        return self.counts / np.asarray(self.spec.counts_per_unit)

    def to_block(self) -> SampleBlock:
        """The samples as one `SampleBlock` (counts as int64), e.g. to replay them."""
        return SampleBlock(self.counts.astype(np.int64), self.seq, self.device_time,
                           self.host_time, self.spec.channels)


@dataclass(frozen=True)
class TableData:
    """The recorded rotary-table state; `status` bit i is `TABLE_STATUS_BITS[i]`."""

    time: np.ndarray  # (k,) s, host clock
    rate: np.ndarray  # (k,) rad/s
    angle: np.ndarray  # (k,) rad, cumulative
    rate_setpoint: np.ndarray  # (k,) rad/s
    status: np.ndarray  # (k,) uint8

    def flag(self, name: str) -> np.ndarray:
        """Boolean array of one status bit, e.g. `flag("at_rate")`."""
        if name not in TABLE_STATUS_BITS:
            raise ValueError(f"unknown table status bit {name!r}; known: {TABLE_STATUS_BITS}")
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
    calibration: CalibrationResult | None
    created: str
    settings: dict | None = None  # what reduced and solved them (replay), None: the recording's


def last_completed_position(events) -> int | None:
    """Position of the most recent `position_done` event, None if no position was completed."""
    done = [e.position for e in events if e.kind == "position_done"]
    return done[-1] if done else None


# ----------------------------------------------------------------------------------------- writer


class SessionWriter:
    """Records one session into one HDF5 file; use `create` or `resume`, then as a context manager.

    Samples and table states are buffered and written together once `flush_interval` seconds (wall
    time) have passed since the last flush; events are flushed at once. `flushed` says how many rows
    of each stream are durable: they survive a kill of this process at any later moment. The methods
    may be called from several threads (e.g. a CAN notifier and a table poller).
    """

    def __init__(self, path, h5file, lock_fd, clock, flush_interval):
        """Internal: use `SessionWriter.create` or `SessionWriter.resume`."""
        self.path = os.fspath(path)
        self.clock = clock
        self.flush_interval = float(flush_interval)
        self._file = h5file
        self._lock_fd = lock_fd
        self._mutex = threading.RLock()
        self.specs = {name: _read_spec(g) for name, g in h5file["streams"].items()
                      if name != "table"}
        self._pending = {name: [] for name in [*self.specs, "table", "events"]}
        self._last_flush = time.monotonic()
        self.last_completed_position = last_completed_position(_read_events(h5file["events"]))

    @classmethod
    def create(cls, path, metadata: dict, streams: dict, *, clock=None, flush_interval: float = 1.0,
               overwrite: bool = False) -> "SessionWriter":
        """Create a session file holding `metadata` and one empty stream per `StreamSpec`.

        metadata : JSON-serialisable dict; requires "protocol" and "unit_serial" (strings); device
                   profiles (dicts), protocol settings and operator notes go in it too.
        streams  : stream name (lower-case identifier, not "table") -> `StreamSpec`.
        clock    : host clock of event times (`drivers.clock`), shared with the devices.
        """
        metadata_json = _metadata_json(metadata)
        for name, spec in streams.items():
            if not NAME.match(str(name)) or name == "table":
                raise ValueError(f"stream name {name!r}: use a lower-case identifier, not 'table'")
            if not isinstance(spec, StreamSpec):
                raise TypeError(f"stream {name!r} needs a StreamSpec, got {type(spec).__name__}")
        if not streams:
            raise ValueError("a session needs at least one sample stream")
        if os.path.exists(path) and not overwrite:
            raise FileExistsError(f"{path} exists; choose another name, or SessionWriter.resume "
                                  "it to continue that session")
        f = h5py.File(path, "w", libver=LIBVER)
        try:
            _write_layout(f, metadata, metadata_json, streams)
            f.swmr_mode = True
        except BaseException:
            f.close()
            os.unlink(path)
            raise
        writer = cls(path, f, _lock(path, fcntl.LOCK_SH), clock or WallClock(), flush_interval)
        writer.event("session_start")
        return writer

    @classmethod
    def resume(cls, path, *, clock=None, flush_interval: float = 1.0) -> "SessionWriter":
        """Reopen a session file, possibly left by a killed writer, to append to it.

        Rows beyond the common length of a stream's columns (a flush cut by the kill) are dropped.
        `last_completed_position` tells the protocol where to continue; a `session_resumed` event
        records it.
        """
        with Session.open(path):  # refuses foreign files and unknown versions
            pass
        os.close(_lock(path, fcntl.LOCK_EX))  # no live writer
        _clear_open_flags(path)
        f = _reopen(path)
        try:
            dropped = _truncate_to_common_length(f)
            f.swmr_mode = True
        except BaseException:
            f.close()
            raise
        writer = cls(path, f, _lock(path, fcntl.LOCK_SH), clock or WallClock(), flush_interval)
        writer.event("session_resumed", writer.last_completed_position, {"dropped_rows": dropped})
        return writer

    @property
    def flushed(self) -> dict:
        """Durable rows per stream name, "table" and "events"."""
        with self._mutex:
            self._check_open()
            return {name: len(self._file[_group(name)][_first_column(name)])
                    for name in self._pending}

    def append(self, stream: str, block: SampleBlock) -> None:
        """Buffer a `SampleBlock` of `stream`; flushes when `flush_interval` has passed."""
        spec = self._spec(stream)
        counts = np.asarray(block.counts)
        k = len(block.seq)
        if counts.ndim != 2 or counts.shape != (k, len(spec.channels)):
            raise ValueError(f"stream {stream!r}: counts of shape {counts.shape} do not match "
                             f"{k} samples x {len(spec.channels)} channels")
        if counts.dtype.kind not in "iu" or np.asarray(block.seq).dtype.kind not in "iu":
            raise ValueError(f"stream {stream!r}: counts and seq must be integers, got "
                             f"{counts.dtype} and {np.asarray(block.seq).dtype}")
        if block.channels and tuple(block.channels) != spec.channels:
            raise ValueError(f"stream {stream!r}: block channels {tuple(block.channels)} differ "
                             f"from the stream's {spec.channels}")
        info = np.iinfo(spec.dtype)
        if k and (counts.min() < info.min or counts.max() > info.max):
            raise ValueError(f"stream {stream!r}: counts exceed {spec.dtype}; create the stream "
                             "with dtype='int64'")
        columns = (counts, block.seq, block.device_time, block.host_time)
        if any(np.shape(c)[:1] != (k,) for c in columns[1:]):
            raise ValueError(f"stream {stream!r}: seq, device_time and host_time need {k} entries")
        if k:
            self._buffer(stream, columns)

    def append_table(self, readings) -> None:
        """Buffer table states: one reading or an iterable of readings with the attributes `time`,
        `rate`, `angle`, `rate_setpoint` and the status flags of `TABLE_STATUS_BITS` (as
        `drivers.rotary_table.TableReading`)."""
        readings = [readings] if hasattr(readings, "rate") else list(readings)
        if not readings:
            return
        status = [sum(int(bool(getattr(r, b))) << i for i, b in enumerate(TABLE_STATUS_BITS))
                  for r in readings]
        columns = [[float(getattr(r, c)) for r in readings] for c in TABLE_COLUMNS[:-1]]
        self._buffer("table", (*columns, status))

    def event(self, kind: str, position: int | None = None, detail: dict | None = None,
              time: float | None = None) -> None:
        """Record a protocol event (kinds: `EVENT_KINDS`) and flush everything at once.

        position : index of the protocol position it belongs to, None for none
        detail   : JSON-serialisable dict; operator notes are `event("note", detail={"text": ...})`
        time     : host clock seconds, default `clock.now()`
        """
        if kind not in EVENT_KINDS:
            raise ValueError(f"unknown event kind {kind!r}; use one of {', '.join(EVENT_KINDS)}")
        if position is not None:
            if isinstance(position, bool) or not isinstance(position, numbers.Integral) \
                    or position < 0:
                raise ValueError(f"event position must be a non-negative int or None, got "
                                 f"{position!r}")
            position = int(position)
        text = np.frombuffer(_json(detail or {}, "event detail").encode(), dtype=np.uint8)
        t = self.clock.now() if time is None else float(time)
        stored = -1 if position is None else position
        with self._mutex:
            self._check_open()
            self._pending["events"].append(([t], [stored], [kind], [len(text)], text))
            if kind == "position_done":
                self.last_completed_position = position
            self.flush()

    def flush(self) -> None:
        """Write every buffered row and flush the file: what was appended so far is durable."""
        with self._mutex:
            self._check_open()
            for name, chunks in self._pending.items():
                if chunks:
                    self._pending[name] = []
                    _append_rows(self._file[_group(name)], name, chunks)
            self._file.flush()
            self._last_flush = time.monotonic()

    def write_results(self, name: str, stream: str, readings, calibration=None,
                      readings_sigma=None) -> None:
        """End the recording and write `results/<name>` (see module function `write_results`)."""
        self.close()
        write_results(self.path, name, stream, readings, calibration, readings_sigma)

    def close(self) -> None:
        """Flush and close the file (a second call does nothing)."""
        with self._mutex:
            if self._file is None:
                return
            try:
                self.flush()
            finally:
                self._file.close()
                self._file = None
                os.close(self._lock_fd)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _spec(self, stream: str) -> StreamSpec:
        if stream not in self.specs:
            raise ValueError(f"unknown stream {stream!r}; this session has {sorted(self.specs)}")
        return self.specs[stream]

    def _check_open(self):
        if self._file is None:
            raise ValueError(f"session {self.path} is closed; use SessionWriter.resume to append")

    def _buffer(self, name: str, columns) -> None:
        with self._mutex:
            self._check_open()
            self._pending[name].append(columns)
            if time.monotonic() - self._last_flush >= self.flush_interval:
                self.flush()


def write_results(path, name: str, stream: str, readings, calibration=None,
                  readings_sigma=None, settings: dict | None = None) -> None:
    """Add `results/<name>` to a closed session file (after the recording, or on replay).

    readings       : reduced readings M (m x n, SI units of `stream`'s channels, one row each)
    calibration    : optional `CalibrationResult` solved from them
    readings_sigma : optional standard deviation of each entry of M (m x n)
    settings       : optional JSON-ready dict of what reduced and solved them (replay settings)
    Existing results are never overwritten: replay writes under a new name.
    """
    if not RESULT_NAME.match(str(name)):
        raise ValueError(f"results name {name!r}: use letters, digits, '_', '-', '.' (max 64)")
    if calibration is not None and not isinstance(calibration, CalibrationResult):
        raise TypeError(f"calibration: need a CalibrationResult, not {type(calibration).__name__}")
    with Session.open(path) as s:  # refuses foreign files and unknown versions
        if stream not in s.specs:
            raise ValueError(f"no stream {stream!r} in {path}; it has {sorted(s.specs)}")
        spec = s.specs[stream]
        clean = s.closed_cleanly
    if not clean:
        raise SessionLockedError(f"{path} was not closed (a writer is live or was killed): close "
                                 "it, or run SessionWriter.resume(path) and close, then retry")
    m = len(spec.channels)
    settings_json = None if settings is None else _json(dict(settings), "settings")
    readings = _float_matrix(readings, "readings", rows=m)
    if readings_sigma is not None:
        readings_sigma = _float_matrix(readings_sigma, "readings_sigma", shape=readings.shape)
    with _reopen(path) as f:
        if name in f["results"]:
            raise ValueError(f"results/{name} exists in {path}; write under a new name")
        g = f["results"].create_group(name)
        g.attrs.update(stream=stream, units=list(spec.units), created=utc_now())
        if settings_json is not None:
            g.attrs["settings"] = settings_json
        g.create_dataset("readings", data=readings)
        if readings_sigma is not None:
            g.create_dataset("readings_sigma", data=readings_sigma)
        if calibration is not None:
            _write_calibration(g.create_group("calibration"), calibration)


def _metadata_json(metadata) -> str:
    if not isinstance(metadata, dict):
        raise TypeError(f"metadata must be a dict, got {type(metadata).__name__}")
    for key in ("protocol", "unit_serial"):
        if not isinstance(metadata.get(key), str) or not metadata[key]:
            raise ValueError(f"metadata[{key!r}] must be a non-empty string")
    return _json(metadata, "metadata")


def _json(value, what: str) -> str:
    try:
        text = json.dumps(value, allow_nan=False, sort_keys=True)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what} is not JSON-serialisable ({e}); convert dates to ISO strings, "
                         "arrays to lists, NaN/inf to null") from None
    if len(text) > MAX_JSON_BYTES:
        raise ValueError(f"{what} is {len(text)} bytes of JSON, over the {MAX_JSON_BYTES} limit")
    return text


def _write_layout(f, metadata, metadata_json, streams) -> None:
    """Every group, dataset and attribute of a new file (all must exist before SWMR mode)."""
    units = {name: list(spec.units) for name, spec in streams.items()}
    units["table"] = TABLE_UNITS
    f.attrs.update(format=FORMAT, format_version=np.int64(FORMAT_VERSION),
                   software_version=software_version(), created=utc_now(),
                   protocol=metadata["protocol"], unit_serial=metadata["unit_serial"],
                   units=json.dumps(units, sort_keys=True))
    f.create_dataset("metadata", data=metadata_json, dtype=h5py.string_dtype())
    for name, spec in streams.items():
        g = f.create_group(f"streams/{name}")
        g.attrs.update(channels=list(spec.channels), units=list(spec.units),
                       counts_per_unit=np.asarray(spec.counts_per_unit), rate_hz=spec.rate_hz,
                       device=spec.device)
        m = len(spec.channels)
        _column(g, "counts", spec.dtype, m)
        for column, dtype in zip(STREAM_COLUMNS[1:], ("int64", "float64", "float64")):
            _column(g, column, dtype)
    g = f.create_group("streams/table")
    g.attrs.update(status_bits=list(TABLE_STATUS_BITS), units=json.dumps(TABLE_UNITS))
    for column in TABLE_COLUMNS:
        _column(g, column, "uint8" if column == "status" else "float64")
    g = f.create_group("events")
    g.attrs["kinds"] = list(EVENT_KINDS)
    for column, dtype in zip(EVENT_COLUMNS, ("float64", "int64", KIND_DTYPE, "int64")):
        _column(g, column, dtype)
    _column(g, "detail", "uint8")
    f.create_group("results")


def _column(group, name, dtype, width=None) -> None:
    """An empty chunked dataset resizable along its first axis (about CHUNK_BYTES per chunk)."""
    dtype = np.dtype(dtype)
    tail = () if width is None else (width,)
    rows = max(64, CHUNK_BYTES // (dtype.itemsize * (width or 1)))
    group.create_dataset(name, shape=(0, *tail), maxshape=(None, *tail), chunks=(rows, *tail),
                         dtype=dtype)


def _group(name: str) -> str:
    return "events" if name == "events" else f"streams/{name}"


def _first_column(name: str) -> str:
    return "time" if name in ("events", "table") else "counts"


def _append_rows(group, name, chunks) -> None:
    """Append buffered column tuples to a group's datasets (events: detail bytes first, then the
    end offset of each event's text in them)."""
    columns = [np.concatenate(parts) for parts in zip(*chunks, strict=True)]
    if name == "events":
        text = columns.pop()
        lengths = columns.pop()
        ends = group["detail"].shape[0] + np.cumsum(lengths)
        _extend(group["detail"], text)
        columns.append(ends)
        names = EVENT_COLUMNS
    else:
        names = TABLE_COLUMNS if name == "table" else STREAM_COLUMNS
    for column, values in zip(names, columns, strict=True):
        _extend(group[column], values)


def _extend(ds, values) -> None:
    values = np.asarray(values, dtype=ds.dtype)
    n = ds.shape[0]
    ds.resize(n + len(values), axis=0)
    ds[n:] = values


def _truncate_to_common_length(f) -> dict:
    """Cut each group's columns to the rows complete in all of them (a flush cut by a kill may
    leave some columns longer); returns the rows dropped per group, where any were."""
    groups = {name: (g, TABLE_COLUMNS if name == "table" else STREAM_COLUMNS)
              for name, g in f["streams"].items()}
    groups["events"] = (f["events"], EVENT_COLUMNS)
    dropped = {}
    for name, (g, columns) in groups.items():
        longest = max(g[c].shape[0] for c in columns)
        n = min(g[c].shape[0] for c in columns)
        if name == "events":
            n = _complete_events(g["detail_end"][:n], g["detail"].shape[0])
            g["detail"].resize(int(g["detail_end"][n - 1]) if n else 0, axis=0)
        for c in columns:
            g[c].resize(n, axis=0)
        if longest > n:
            dropped[name] = int(longest - n)
    return dropped


def _complete_events(ends, detail_length, where="") -> int:
    """How many events have their whole detail text flushed (`ends` must increase)."""
    if len(ends) and (ends[0] < 0 or np.any(np.diff(ends) < 0)):
        raise SessionFormatError(f"{where}: events/detail_end is not increasing")
    return int(np.searchsorted(ends, detail_length, side="right"))


def _write_calibration(group, result: CalibrationResult) -> None:
    """Arrays of the result become datasets, scalars attributes; None fields are listed."""
    none = []
    for field in dataclasses.fields(result):
        value = getattr(result, field.name)
        if value is None:
            none.append(field.name)
        elif isinstance(value, np.ndarray):
            group.create_dataset(field.name, data=np.asarray(value, dtype=np.float64))
        else:
            group.attrs[field.name] = value
    group.attrs["none_fields"] = np.array(none, dtype=h5py.string_dtype())


def _float_matrix(values, what, rows=None, shape=None) -> np.ndarray:
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 2 or (rows is not None and x.shape[0] != rows) or (shape and x.shape != shape):
        want = shape or f"({rows}, n)"
        raise ValueError(f"{what} has shape {x.shape}, expected {want} (sensors x positions)")
    return x


# ----------------------------------------------------------------- locks and the HDF5 superblock


def _reopen(path) -> h5py.File:
    """A closed session file opened for writing, outside SWMR mode."""
    try:
        return h5py.File(path, "r+", libver=LIBVER)
    except OSError as e:
        raise SessionLockedError(f"{path} cannot be opened for writing ({e}); close the programs "
                                 "that have it open") from None


def _lock(path, how) -> int:
    """A descriptor of `path` holding an flock: shared while a writer is live, exclusive to check
    that none is. The kernel releases it when the writer dies, even by kill -9."""
    fd = os.open(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, how | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise SessionLockedError(f"{path} is open in another process (a live writer, or a reader "
                                 "of the closed file); close it there first") from None
    return fd


def _superblock(path) -> tuple[bytearray, int]:
    """The first 48 bytes of the file and its HDF5 superblock version, signature checked, and for
    versions 2-3 the checksum (HDF5 file format specification, section II.A: signature, version,
    offset size, length size, file consistency flags at byte 11, four addresses, then a Jenkins
    lookup3 checksum of the preceding bytes). Checked here because HDF5's SWMR reader retries
    checksum failures for minutes instead of failing."""
    with open(path, "rb") as fh:
        head = bytearray(fh.read(48))
    if head[:8] != b"\x89HDF\r\n\x1a\n":
        raise SessionFormatError(f"{path} is not an HDF5 file (no HDF5 signature at offset 0); "
                                 "not a session file")
    version = head[8]
    if version >= 2 and (len(head) < 48 or head[9] != 8):
        raise SessionFormatError(f"{path}: unexpected HDF5 superblock (version {version}, offset "
                                 f"size {head[9]}); not a session file written by this software")
    if version >= 2 and struct.unpack_from("<I", head, 44)[0] != _lookup3(bytes(head[:44])):
        raise SessionFormatError(f"{path}: the HDF5 superblock checksum is wrong; the file is "
                                 "damaged")
    return head, version


def _open_flags(path) -> int:
    """The superblock's file consistency flags: non-zero while a writer has the file open, or
    after it was killed. Superblocks before version 2 have none."""
    head, version = _superblock(path)
    return head[11] if version >= 2 else 0


def _clear_open_flags(path) -> None:
    """Clear the 'open for (SWMR) write' flags a killed writer leaves in the superblock, as the
    HDF5 tool `h5clear -s` does, and rewrite the superblock checksum."""
    head, version = _superblock(path)
    if version != 3:
        raise SessionFormatError(f"{path}: HDF5 superblock version {version}, sessions are "
                                 "written with version 3 (libver v110)")
    if head[11] == 0:
        return
    head[11] = 0
    struct.pack_into("<I", head, 44, _lookup3(bytes(head[:44])))
    with open(path, "r+b") as fh:
        fh.write(head)
        fh.flush()
        os.fsync(fh.fileno())


def _lookup3(data: bytes, initval: int = 0) -> int:
    """Bob Jenkins' lookup3 `hashlittle`, the checksum of HDF5 metadata: mix() over each 12-byte
    block but the last, final() after adding the last (zero-padded) block."""
    mask = 0xFFFFFFFF

    def rot(x, k):
        return (x << k | x >> (32 - k)) & mask

    h = [(0xDEADBEEF + len(data) + initval) & mask] * 3  # a, b, c
    if not data:
        return h[2]
    padded = data + bytes(-len(data) % 12)
    blocks = [struct.unpack_from("<3I", padded, i) for i in range(0, len(padded), 12)]
    for block in blocks:
        h = [(x + w) & mask for x, w in zip(h, block)]
        if block is blocks[-1]:
            break
        for i, r in enumerate((4, 6, 8, 16, 19, 4)):  # x -= z; x ^= rot(z, r); z += y
            x, y, z = i % 3, (i + 1) % 3, (i + 2) % 3
            h[x] = (h[x] - h[z]) & mask ^ rot(h[z], r)
            h[z] = (h[z] + h[y]) & mask
    for i, r in enumerate((14, 11, 25, 16, 4, 14, 24)):  # x ^= y; x -= rot(y, r)
        x = (2 + i) % 3
        y = (x + 2) % 3
        h[x] = (h[x] ^ h[y]) - rot(h[y], r) & mask
    return h[2]


# ----------------------------------------------------------------------------------------- reader


class Session:
    """A session file opened for reading, also while a writer appends to it (SWMR read).

    Every accessor refreshes its datasets first, so repeated calls see the rows flushed since.
    Results groups added after opening are seen only after reopening.
    """

    def __init__(self, path, h5file):
        """Internal: use `Session.open`."""
        self.path = os.fspath(path)
        self._file = h5file
        attrs = h5file.attrs
        self.format_version = _check_format(self.path, attrs)
        self.software_version = _attr(attrs, "software_version", str, self.path)
        self.created = _attr(attrs, "created", str, self.path)
        self.protocol = _attr(attrs, "protocol", str, self.path)
        self.unit_serial = _attr(attrs, "unit_serial", str, self.path)
        self.metadata = _read_metadata(h5file, self.path)
        streams = _child(h5file, "streams", h5py.Group, self.path)
        self.specs = {n: _read_spec(_child(streams, n, h5py.Group, self.path), self.path)
                      for n in streams if n != "table"}

    @classmethod
    def open(cls, path) -> "Session":
        """Open a session file; `SessionFormatError` if it is not one this software reads.

        A file a writer has open (or left open when killed) is read in SWMR mode, a closed one
        in plain read-only mode."""
        live = _open_flags(path) != 0
        try:
            f = h5py.File(path, "r", swmr=live, libver=LIBVER)
        except OSError as e:
            raise SessionFormatError(f"{path} is not a readable HDF5 file ({e})") from None
        try:
            return cls(path, f)
        except BaseException:
            f.close()
            raise

    @property
    def closed_cleanly(self) -> bool:
        """False while a writer is live or after it was killed (superblock flags still set)."""
        return _open_flags(self.path) == 0

    def stream(self, name: str) -> StreamData:
        """All samples of a stream flushed so far (the common length of its columns)."""
        if name not in self.specs:
            raise ValueError(f"no stream {name!r} in {self.path}; it has {sorted(self.specs)}")
        spec = self.specs[name]
        g = self._file["streams"][name]
        counts, seq, device_time, host_time = _columns(g, STREAM_COLUMNS, self.path, {
            "counts": ("iu", (len(spec.channels),)), "seq": ("i", ()),
            "device_time": ("f", ()), "host_time": ("f", ())})
        return StreamData(counts, seq.astype(np.int64), device_time.astype(np.float64),
                          host_time.astype(np.float64), spec)

    def table(self) -> TableData:
        """The rotary-table states flushed so far."""
        g = _child(self._file["streams"], "table", h5py.Group, self.path)
        kinds = {c: ("f", ()) for c in TABLE_COLUMNS}
        kinds["status"] = ("u", ())
        cols = _columns(g, TABLE_COLUMNS, self.path, kinds)
        return TableData(*(c.astype(np.float64) for c in cols[:-1]), cols[-1].astype(np.uint8))

    def events(self) -> list:
        """Protocol events flushed so far, in order."""
        return _read_events(_child(self._file, "events", h5py.Group, self.path), self.path)

    def last_completed_position(self) -> int | None:
        """Position of the last `position_done` event (None: no position completed)."""
        return last_completed_position(self.events())

    @property
    def result_names(self) -> tuple:
        return tuple(_child(self._file, "results", h5py.Group, self.path))

    def results(self, name: str) -> SessionResults:
        """The `results/<name>` group: readings, their sigma and the calibration if stored."""
        g = _child(_child(self._file, "results", h5py.Group, self.path), name, h5py.Group,
                   self.path)
        where = f"{self.path}:results/{name}"
        stream = _attr(g.attrs, "stream", str, where)
        spec = self.specs.get(stream)
        if spec is None:
            raise SessionFormatError(f"{where} names stream {stream!r}, which the file lacks")
        m = len(spec.channels)
        readings = _matrix(g, "readings", where, rows=m)
        sigma = _matrix(g, "readings_sigma", where, shape=readings.shape) if "readings_sigma" in g \
            else None
        cal = _read_calibration(g, where, readings.shape) if "calibration" in g else None
        settings = _json_object(_attr(g.attrs, "settings", str, where), f"{where} settings") \
            if "settings" in g.attrs else None
        return SessionResults(name, stream, tuple(_attr(g.attrs, "units", list, where)), readings,
                              sigma, cal, _attr(g.attrs, "created", str, where), settings)

    def close(self) -> None:
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _check_format(path, attrs) -> int:
    """The file's format version; `SessionFormatError` unless ours and a supported version."""
    fmt = attrs.get("format")
    if fmt != FORMAT:
        raise SessionFormatError(f"{path} is not an IMU station session file (format attribute "
                                 f"{fmt!r}, expected {FORMAT!r})")
    version = attrs.get("format_version")
    version = version.item() if isinstance(version, np.generic) else version
    if type(version) is not int or version not in SUPPORTED_VERSIONS:
        raise SessionFormatError(
            f"{path} has session format_version {version!r}; this software reads versions "
            f"{', '.join(map(str, SUPPORTED_VERSIONS))} (newer files need newer station software)")
    return int(version)


def _attr(attrs, key, kind, where):
    """An attribute of the expected Python type (str, float or list of str)."""
    value = attrs.get(key)
    # an empty list written as a plain array comes back as float64 (files of early version-1 writers)
    if kind is list and isinstance(value, np.ndarray) and value.ndim == 1 and (
        value.dtype == object or value.size == 0
    ):
        value = list(value)
        if all(isinstance(v, str) for v in value):
            return value
    elif kind is float and isinstance(value, np.floating | float):
        return float(value)
    elif isinstance(value, kind):
        return value
    raise SessionFormatError(f"{where}: attribute {key!r} is missing or not a {kind.__name__}")


def _child(group, name, kind, where):
    """A member of `group` that is a plain (hard-linked) group or dataset of this file."""
    link = group.get(name, getlink=True)
    if not isinstance(link, h5py.HardLink):
        raise SessionFormatError(f"{where}: {group.name}/{name} is missing or an external link")
    obj = group[name]
    if not isinstance(obj, kind):
        raise SessionFormatError(f"{where}: {obj.name} is not a {kind.__name__}")
    if kind is h5py.Dataset:
        plist = obj.id.get_create_plist()
        filters = {plist.get_filter(i)[0] for i in range(plist.get_nfilters())}
        if obj.external or obj.is_virtual or not filters <= ALLOWED_FILTERS:
            raise SessionFormatError(f"{where}: {obj.name} uses external storage or unknown "
                                     "filters; refusing to read it")
    return obj


def _read_metadata(f, where) -> dict:
    ds = _child(f, "metadata", h5py.Dataset, where)
    if ds.shape != () or ds.dtype.kind not in "OS":
        raise SessionFormatError(f"{where}: /metadata must be one JSON string")
    return _json_object(ds[()], f"{where}: /metadata")


def _json_object(raw, what: str) -> dict:
    """A JSON object from untrusted text, size-limited; SessionFormatError naming `what`."""
    if len(raw) > MAX_JSON_BYTES:
        raise SessionFormatError(f"{what} is over {MAX_JSON_BYTES} bytes")
    try:
        value = json.loads(raw)
    except (ValueError, UnicodeDecodeError) as e:
        raise SessionFormatError(f"{what} is not valid JSON ({e})") from None
    if not isinstance(value, dict):
        raise SessionFormatError(f"{what} must be a JSON object")
    return value


def _read_spec(g, where="") -> StreamSpec:
    """The StreamSpec of a stream group, validated."""
    try:
        return StreamSpec(tuple(_attr(g.attrs, "channels", list, where)),
                          tuple(_attr(g.attrs, "units", list, where)),
                          tuple(np.asarray(g.attrs.get("counts_per_unit"), dtype=float).ravel()),
                          _attr(g.attrs, "rate_hz", float, where),
                          np.dtype(_child(g, "counts", h5py.Dataset, where).dtype).name,
                          _attr(g.attrs, "device", str, where))
    except (TypeError, ValueError) as e:
        if isinstance(e, SessionFormatError):
            raise
        raise SessionFormatError(f"{where}: stream {g.name} is malformed ({e})") from None


def _columns(g, names, where, kinds) -> list:
    """Datasets `names` of `g` read to their common length, each checked for dtype kind and
    trailing shape."""
    datasets = [_child(g, n, h5py.Dataset, where) for n in names]
    for ds, n in zip(datasets, names):
        ds.refresh()
        dtype_kinds, tail = kinds[n]
        if ds.dtype.kind not in dtype_kinds or ds.shape[1:] != tail:
            raise SessionFormatError(f"{where}: {ds.name} has dtype {ds.dtype} and shape "
                                     f"{ds.shape}; expected kind {dtype_kinds!r}, rows x {tail}")
    k = min(ds.shape[0] for ds in datasets)
    return [ds[:k] for ds in datasets]


def _read_events(g, where="") -> list:
    kinds = {"time": ("f", ()), "position": ("i", ()), "kind": ("S", ()), "detail_end": ("i", ())}
    times, positions, kind_bytes, ends = _columns(g, EVENT_COLUMNS, where, kinds)
    detail = _child(g, "detail", h5py.Dataset, where)
    detail.refresh()
    if detail.dtype != np.uint8 or detail.ndim != 1:
        raise SessionFormatError(f"{where}: events/detail must be a 1-D uint8 byte stream")
    k = _complete_events(ends, detail.shape[0], where)
    starts = np.concatenate([[0], ends[:-1]]).astype(np.int64)
    text = detail[:int(ends[k - 1])].tobytes() if k else b""
    events = []
    for t, p, kb, s, e in zip(times[:k], positions[:k], kind_bytes[:k], starts[:k], ends[:k]):
        try:
            kind = kb.decode("ascii")
            info = json.loads(text[s:e])
        except (UnicodeDecodeError, ValueError) as err:
            raise SessionFormatError(f"{where}: an event is not valid ASCII/JSON ({err})") from None
        if not isinstance(info, dict):
            raise SessionFormatError(f"{where}: event detail must be a JSON object")
        events.append(Event(float(t), None if p < 0 else int(p), kind, info))
    return events


def _matrix(g, name, where, rows=None, shape=None) -> np.ndarray:
    ds = _child(g, name, h5py.Dataset, where)
    if ds.dtype.kind != "f":
        raise SessionFormatError(f"{where}/{name} must be floating point, got {ds.dtype}")
    try:
        return _float_matrix(ds[()], f"{where}/{name}", rows, shape)
    except ValueError as e:
        raise SessionFormatError(str(e)) from None


LATER_FIELDS = ("parameter_covariance",)
"""CalibrationResult fields added after format version 1 was first written: None when absent."""


def _read_calibration(g, where, readings_shape) -> CalibrationResult:
    """A `CalibrationResult` from its group; every field present or listed as None, arrays float,
    shapes consistent with the readings (m x n)."""
    g = _child(g, "calibration", h5py.Group, where)
    where = f"{where}/calibration"
    none = set(_attr(g.attrs, "none_fields", list, where))
    m, n = readings_shape
    values = {}
    for field in dataclasses.fields(CalibrationResult):
        key = field.name
        if key in none:
            values[key] = None
        elif key in g:
            ds = _child(g, key, h5py.Dataset, where)
            if ds.dtype.kind != "f" or ds.ndim > 2:
                raise SessionFormatError(f"{where}/{key} must be a float array, got {ds.dtype}")
            values[key] = ds[()]
        elif key in g.attrs:
            value = g.attrs[key]
            if not isinstance(value, str | np.generic):
                raise SessionFormatError(f"{where}: attribute {key!r} must be a scalar")
            values[key] = value if isinstance(value, str) else value.item()
        elif key in LATER_FIELDS:
            values[key] = None  # written before the field existed
        else:
            raise SessionFormatError(f"{where}: field {key!r} is missing")
    a = values["a"]
    if a.ndim != 2 or a.shape[1] != m:
        raise SessionFormatError(f"{where}/a has shape {a.shape}, expected (d, {m})")
    expected = {"v": (a.shape[0], n), "residuals": (m, n), "sigma": (m, n),
                "a_sigma": a.shape, "scale_factors": (m,), "axis_angles": (m, m),
                "axis_angles_sigma": (m, m), "scale_factors_sigma": (m,), "bias": (m,),
                "bias_sigma": (m,)}
    for key, shape in expected.items():
        if values[key] is not None and values[key].shape != shape:
            raise SessionFormatError(f"{where}/{key} has shape {values[key].shape}, expected "
                                     f"{shape}")
    cov = values["covariance"]
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1]:
        raise SessionFormatError(f"{where}/covariance must be square, got {cov.shape}")
    pc = values["parameter_covariance"]
    k = a.size + (m if values["bias_estimated"] else 0)
    if pc is not None and pc.shape != (k, k):
        raise SessionFormatError(f"{where}/parameter_covariance has shape {pc.shape}, expected "
                                 f"({k}, {k})")
    return CalibrationResult(**values)
