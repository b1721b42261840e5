"""Writing a session file: `SessionWriter` (create, append, events, resume) and `write_results`.

Every dataset exists before the file switches to HDF5 single-writer/multiple-reader (SWMR) mode
(libver v110), its rows' time column attached as an HDF5 dimension scale and a `units` attribute
on each; samples are buffered and written in batches, flushed about once a second, so that a writer
killed at any moment leaves a readable file holding every flushed sample. `SessionWriter.resume`
reopens such a file and continues it. Results are written after the acquisition, outside SWMR mode
(new groups cannot be created in SWMR mode). Sample blocks are duck-typed: anything with `counts`,
`seq`, `device_time`, `host_time` (and optionally `channels`), e.g. a `drivers.samples.SampleBlock`.
"""

import dataclasses
import errno
import fcntl
import hashlib
import json
import numbers
import os
import threading
import time

import h5py
import numpy as np

from station.errors import InputError, SessionLockedError
from station.files.provenance import software_version, utc_now
from station.session._repair import clear_open_flags
from station.session.format import (
    CHUNK_BYTES,
    EVENT_COLUMNS,
    EVENT_KINDS,
    EVENT_UNITS,
    FORMAT,
    FORMAT_VERSION,
    KIND_DTYPE,
    LIBVER,
    MAX_JSON_BYTES,
    NAME,
    RESULT_NAME,
    STREAM_COLUMNS,
    STREAM_UNITS,
    TABLE_COLUMNS,
    TABLE_STATUS_BITS,
    TABLE_UNITS,
    TIME_SCALES,
    StreamSpec,
    complete_events,
    float_matrix,
    last_completed_position,
)
from station.session.reader import Session, read_events, read_spec
from station.session.torn import repair_tail
from station.solve.calibrate import CalibrationResult


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
        self.clock = clock  # anything with now(), e.g. a drivers.clock; None: host monotonic time
        self.flush_interval = float(flush_interval)
        self._file = h5file
        self._lock_fd = lock_fd
        self._mutex = threading.RLock()
        self.specs = {name: read_spec(g) for name, g in h5file["streams"].items()
                      if name != "table"}
        self._pending = {name: [] for name in [*self.specs, "table", "events"]}
        self._rows = {name: _lengths(h5file[_group(name)], name) for name in self._pending}
        self._last_flush = time.monotonic()
        self.last_completed_position = last_completed_position(read_events(h5file["events"]))

    @classmethod
    def create(cls, path, metadata: dict, streams: dict, *, clock=None, flush_interval: float = 1.0,
               overwrite: bool = False) -> "SessionWriter":
        """Create a session file holding `metadata` and one empty stream per `StreamSpec`.

        metadata : JSON-serialisable dict; requires "protocol" and "unit_serial" (strings); device
                   profiles (dicts), protocol settings and operator notes go in it too.
        streams  : stream name (lower-case identifier, not "table") -> `StreamSpec`.
        clock    : host clock of event times (`drivers.clock`), shared with the devices; None:
                   host monotonic time.
        """
        metadata_json = _metadata_json(metadata)
        for name, spec in streams.items():
            if not NAME.match(str(name)) or name == "table":
                raise InputError(f"stream name {name!r}: use a lower-case identifier, not 'table'")
            if not isinstance(spec, StreamSpec):
                raise TypeError(f"stream {name!r} needs a StreamSpec, got {type(spec).__name__}")
        if not streams:
            raise InputError("a session needs at least one sample stream")
        exists = FileExistsError(errno.EEXIST, "exists; choose another name, or "
                                               "SessionWriter.resume it to continue that session",
                                 os.fspath(path))
        if os.path.exists(path) and not overwrite:
            raise exists
        try:  # "w-" creates exclusively: another command's file made meanwhile is kept
            f = h5py.File(path, "w" if overwrite else "w-", libver=LIBVER)
        except FileExistsError:
            raise exists from None
        try:
            _write_layout(f, metadata, metadata_json, streams)
            f.swmr_mode = True
        except BaseException:
            f.close()
            os.unlink(path)
            raise
        writer = cls(path, f, _lock(path, fcntl.LOCK_SH), clock, flush_interval)
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
        clear_open_flags(path)
        f = _reopen(path)
        try:
            torn = _repair_torn_tails(f)
            dropped = _truncate_to_common_length(f)
            for name, rows in torn.items():
                dropped[name] = max(dropped.get(name, 0), rows)
            f.swmr_mode = True
        except BaseException:
            f.close()
            raise
        writer = cls(path, f, _lock(path, fcntl.LOCK_SH), clock, flush_interval)
        writer.event("session_resumed", writer.last_completed_position, {"dropped_rows": dropped})
        return writer

    def now(self) -> float:
        """The session clock's time: `clock.now()`, or host monotonic time without a clock."""
        return self.clock.now() if self.clock is not None else time.monotonic()

    @property
    def flushed(self) -> dict:
        """Durable rows per stream name, "table" and "events"."""
        with self._mutex:
            self._check_open()
            return {name: len(self._file[_group(name)][_first_column(name)])
                    for name in self._pending}

    def append(self, stream: str, block) -> None:
        """Buffer a block of samples of `stream` (a `drivers.samples.SampleBlock` or anything with
        its columns, e.g. a `StreamData`); flushes when `flush_interval` has passed."""
        spec = self._spec(stream)
        counts = np.asarray(block.counts)
        k = len(block.seq)
        if counts.ndim != 2 or counts.shape != (k, len(spec.channels)):
            raise InputError(f"stream {stream!r}: counts of shape {counts.shape} do not match "
                             f"{k} samples x {len(spec.channels)} channels")
        if counts.dtype.kind not in "iu" or np.asarray(block.seq).dtype.kind not in "iu":
            raise InputError(f"stream {stream!r}: counts and seq must be integers, got "
                             f"{counts.dtype} and {np.asarray(block.seq).dtype}")
        channels = tuple(getattr(block, "channels", ()))
        if channels and channels != spec.channels:
            raise InputError(f"stream {stream!r}: block channels {channels} differ "
                             f"from the stream's {spec.channels}")
        info = np.iinfo(spec.dtype)
        if k and (counts.min() < info.min or counts.max() > info.max):
            raise InputError(f"stream {stream!r}: counts exceed {spec.dtype}; create the stream "
                             "with dtype='int64'")
        columns = (counts, block.seq, block.device_time, block.host_time)
        if any(np.shape(c)[:1] != (k,) for c in columns[1:]):
            raise InputError(f"stream {stream!r}: seq, device_time and host_time need {k} entries")
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
            raise InputError(f"unknown event kind {kind!r}; use one of {', '.join(EVENT_KINDS)}")
        if position is not None:
            if isinstance(position, bool) or not isinstance(position, numbers.Integral) \
                    or position < 0:
                raise InputError(f"event position must be a non-negative int or None, got "
                                 f"{position!r}")
            position = int(position)
        text = np.frombuffer(_json(detail or {}, "event detail").encode(), dtype=np.uint8)
        t = self.now() if time is None else float(time)
        stored = -1 if position is None else position
        with self._mutex:
            self._check_open()
            self._pending["events"].append(([t], [stored], [kind], [len(text)], text))
            if kind == "position_done":
                self.last_completed_position = position
            self.flush()

    def events(self) -> list:
        """The events recorded so far (`station.session.Event`), this run's included."""
        with self._mutex:
            self.flush()
            return read_events(self._file["events"], self.path)

    def flush(self) -> None:
        """Write every buffered row and flush the file: what was appended so far is durable."""
        with self._mutex:
            self._check_open()
            for name, chunks in self._pending.items():
                if chunks:  # kept until written: an append cut by an exception is done again
                    rows = _append_rows(self._file[_group(name)], name, chunks, self._rows[name])
                    self._rows[name] = rows
                    self._pending[name] = []
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
            raise InputError(f"unknown stream {stream!r}; this session has {sorted(self.specs)}")
        return self.specs[stream]

    def _check_open(self):
        if self._file is None:
            raise InputError(f"session {self.path} is closed; use SessionWriter.resume to append")

    def _buffer(self, name: str, columns) -> None:
        with self._mutex:
            self._check_open()
            self._pending[name].append(columns)
            if time.monotonic() - self._last_flush >= self.flush_interval:
                self.flush()


def write_results(path, name: str, stream: str, readings, calibration=None,
                  readings_sigma=None, settings: dict | None = None, channels=None) -> None:
    """Add `results/<name>` to a closed session file (after the recording, or on replay).

    readings       : reduced readings M (m x n, SI units of `stream`'s channels, one row each)
    channels       : indices of the stream's channels the rows are (e.g. the 24 accelerometers of
                     a 48-channel stream); None: every channel, in order
    calibration    : optional `CalibrationResult` solved from them
    readings_sigma : optional standard deviation of each entry of M (m x n)
    settings       : optional JSON-ready dict of what reduced and solved them (replay settings)
    Existing results are never overwritten: replay writes under a new name.
    """
    if not RESULT_NAME.match(str(name)):
        raise InputError(f"results name {name!r}: use letters, digits, '_', '-', '.' (max 64)")
    if calibration is not None and not isinstance(calibration, CalibrationResult):
        raise TypeError(f"calibration: need a CalibrationResult, not {type(calibration).__name__}")
    with Session.open(path) as s:  # refuses foreign files and unknown versions
        if stream not in s.specs:
            raise InputError(f"no stream {stream!r} in {path}; it has {sorted(s.specs)}")
        spec = s.specs[stream]
        clean = s.closed_cleanly
    if not clean:
        raise SessionLockedError(f"{path} was not closed (a writer is live or was killed): close "
                                 "it, or run SessionWriter.resume(path) and close, then retry")
    rows = np.arange(len(spec.channels)) if channels is None else np.asarray(channels, np.int64)
    if rows.ndim != 1 or len(set(rows.tolist())) != len(rows) or not np.all(
            (rows >= 0) & (rows < len(spec.channels))):
        raise InputError(f"channels {rows.tolist()} are not distinct channels of {stream!r}")
    units = [spec.units[i] for i in rows]
    settings_json = None if settings is None else _json(dict(settings), "settings")
    readings = float_matrix(readings, "readings", rows=len(rows))
    if readings_sigma is not None:
        readings_sigma = float_matrix(readings_sigma, "readings_sigma", shape=readings.shape)
    with _reopen(path) as f:
        if name in f["results"]:
            raise InputError(f"results/{name} exists in {path}; write under a new name")
        sequence = len(f["results"])  # orders results written within one second of each other
        g = f["results"].create_group(name)
        g.attrs.update(stream=stream, units=units, created=utc_now(), sequence=sequence)
        if channels is not None:
            g.attrs["channels"] = rows
        if settings_json is not None:
            g.attrs["settings"] = settings_json
        g.create_dataset("readings", data=readings).attrs["units"] = units
        if readings_sigma is not None:
            g.create_dataset("readings_sigma", data=readings_sigma).attrs["units"] = units
        if calibration is not None:
            _write_calibration(g.create_group("calibration"), calibration)


def _metadata_json(metadata) -> str:
    if not isinstance(metadata, dict):
        raise TypeError(f"metadata must be a dict, got {type(metadata).__name__}")
    for key in ("protocol", "unit_serial"):
        if not isinstance(metadata.get(key), str) or not metadata[key]:
            raise InputError(f"metadata[{key!r}] must be a non-empty string")
    return _json(metadata, "metadata")


def _json(value, what: str) -> str:
    try:
        text = json.dumps(value, allow_nan=False, sort_keys=True)
    except (TypeError, ValueError) as e:
        raise InputError(f"{what} is not JSON-serialisable ({e}); convert dates to ISO strings, "
                         "arrays to lists, NaN/inf to null") from None
    if len(text) > MAX_JSON_BYTES:
        raise InputError(f"{what} is {len(text)} bytes of JSON, over the {MAX_JSON_BYTES} limit")
    return text




def _write_layout(f, metadata, metadata_json, streams) -> None:
    """Every group, dataset, attribute and dimension scale of a new file (all must exist before
    SWMR mode)."""
    units = {name: list(spec.units) for name, spec in streams.items()}
    units["table"] = TABLE_UNITS
    f.attrs.update(format=FORMAT, format_version=np.int64(FORMAT_VERSION),
                   software_version=software_version(), created=utc_now(),
                   protocol=metadata["protocol"], unit_serial=metadata["unit_serial"],
                   units=json.dumps(units, sort_keys=True))
    ds = f.create_dataset("metadata", data=metadata_json, dtype=h5py.string_dtype())
    # fixed-length, so held in the checksummed object header (the text itself is in the global
    # heap, which HDF5 does not checksum)
    ds.attrs["sha256"] = np.bytes_(hashlib.sha256(metadata_json.encode()).hexdigest())
    for name, spec in streams.items():
        g = f.create_group(f"streams/{name}")
        g.attrs.update(channels=list(spec.channels), units=list(spec.units),
                       counts_per_unit=np.asarray(spec.counts_per_unit), rate_hz=spec.rate_hz,
                       device=spec.device)
        m = len(spec.channels)
        _column(g, "counts", spec.dtype, STREAM_UNITS["counts"], m)
        for column, dtype in zip(STREAM_COLUMNS[1:], ("int64", "float64", "float64"), strict=True):
            _column(g, column, dtype, STREAM_UNITS[column])
        _channel_scale(g, spec)
        _time_scale(g, TIME_SCALES["streams"], STREAM_COLUMNS)
    g = f.create_group("streams/table")
    g.attrs.update(status_bits=list(TABLE_STATUS_BITS), units=json.dumps(TABLE_UNITS))
    for column in TABLE_COLUMNS:
        _column(g, column, "uint8" if column == "status" else "float64", TABLE_UNITS[column])
    _time_scale(g, TIME_SCALES["table"], TABLE_COLUMNS)
    g = f.create_group("events")
    g.attrs["kinds"] = list(EVENT_KINDS)
    for column, dtype in zip(EVENT_COLUMNS, ("float64", "int64", KIND_DTYPE, "int64"), strict=True):
        _column(g, column, dtype, EVENT_UNITS[column])
    _column(g, "detail", "uint8", EVENT_UNITS["detail"])
    _time_scale(g, TIME_SCALES["events"], EVENT_COLUMNS)
    g["detail"].make_scale("detail")  # a byte stream of its own length: its own dimension
    f.create_group("results")


def _time_scale(group, scale: str, columns) -> None:
    """Make column `scale` the dimension scale of the rows of the group's other `columns`."""
    group[scale].make_scale(scale)
    for column in columns:
        if column != scale:
            group[column].dims[0].attach_scale(group[scale])


def _channel_scale(group, spec: StreamSpec) -> None:
    """A `channel` dataset (the channel names) as the dimension scale of the counts' columns."""
    names = group.create_dataset("channel", data=list(spec.channels), dtype=h5py.string_dtype())
    names.attrs["units"] = "1"
    names.make_scale("channel")
    group["counts"].dims[1].attach_scale(names)


def _column(group, name, dtype, units: str, width=None) -> None:
    """An empty chunked dataset resizable along its first axis (about CHUNK_BYTES per chunk), its
    unit in a `units` attribute."""
    dtype = np.dtype(dtype)
    tail = () if width is None else (width,)
    rows = max(64, CHUNK_BYTES // (dtype.itemsize * (width or 1)))
    ds = group.create_dataset(name, shape=(0, *tail), maxshape=(None, *tail),
                              chunks=(rows, *tail), dtype=dtype, fletcher32=True)
    ds.attrs["units"] = units


def _group(name: str) -> str:
    return "events" if name == "events" else f"streams/{name}"


def _first_column(name: str) -> str:
    return "time" if name in ("events", "table") else "counts"


def _grown(name: str) -> tuple:
    """The datasets of a group that an append grows."""
    if name == "events":
        return (*EVENT_COLUMNS, "detail")
    return TABLE_COLUMNS if name == "table" else STREAM_COLUMNS


def _lengths(group, name) -> dict:
    return {column: group[column].shape[0] for column in _grown(name)}


def _append_rows(group, name, chunks, lengths) -> dict:
    """Append buffered column tuples to a group's datasets (events: detail bytes first, then the
    end offset of each event's text in them); returns the datasets' new lengths.

    `lengths` are those of the last complete append: what an append cut by an exception left (a
    Ctrl-C raises in the main thread between any two of its writes) is cut off first, so that the
    columns never go out of step."""
    for column, n in lengths.items():
        if group[column].shape[0] != n:
            group[column].resize(n, axis=0)
    columns = [np.concatenate(parts) for parts in zip(*chunks, strict=True)]
    names = _grown(name)
    if name == "events":
        text = columns.pop()
        ends = group["detail"].shape[0] + np.cumsum(columns.pop())
        _extend(group["detail"], text)
        columns.append(ends)
        names = EVENT_COLUMNS
    for column, values in zip(names, columns, strict=True):
        _extend(group[column], values)
    return _lengths(group, name)


def _extend(ds, values) -> None:
    values = np.asarray(values, dtype=ds.dtype)
    n = ds.shape[0]
    ds.resize(n + len(values), axis=0)
    ds[n:] = values


def _repair_torn_tails(f) -> dict:
    """Rewrite the last chunks that a kill cut short (`torn.repair_tail`) in every grown column,
    so that appending can read them again; returns the rows dropped per group, where any were."""
    dropped = {}
    for name, g in [*f["streams"].items(), ("events", f["events"])]:
        lost = [repair_tail(g[c]) for c in _grown(name)]
        if any(lost):
            dropped[name] = max(lost)
    return dropped


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
            n = complete_events(g["detail_end"][:n], g["detail"].shape[0])
            g["detail"].resize(int(g["detail_end"][n - 1]) if n else 0, axis=0)
        for c in columns:
            g[c].resize(n, axis=0)
        if longest > n:
            dropped[name] = int(longest - n)
    return dropped


def _write_calibration(group, result: CalibrationResult) -> None:
    """Arrays of the result become datasets, scalars and tuples of words attributes; None fields
    are listed."""
    none = []
    for field in dataclasses.fields(result):
        value = getattr(result, field.name)
        if value is None:
            none.append(field.name)
        elif isinstance(value, np.ndarray):
            group.create_dataset(field.name, data=np.asarray(value, dtype=np.float64))
        elif isinstance(value, tuple):  # words (weakly_determined): one string, "; " between
            group.attrs[field.name] = "; ".join(value)
        else:
            group.attrs[field.name] = value
    group.attrs["none_fields"] = np.array(none, dtype=h5py.string_dtype())


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
