"""Reading a session file: `Session`, also while a writer appends to it (SWMR read).

Every file is untrusted: the format and version are checked first, then the type and shape of
everything read; nothing is evaluated or unpickled, JSON is the only text decoded. The reader
imports no driver (the reduction reads sessions and never touches devices).
"""

import dataclasses
import hashlib
import os
from typing import TYPE_CHECKING

import h5py
import numpy as np

from station.errors import InputError, SessionFormatError
from station.files.hdf5 import stored_plainly
from station.limits import json_loads
from station.session._repair import open_flags
from station.session.format import (
    COUNTS,
    EVENT_COLUMNS,
    EVENT_KINDS,
    FORMAT,
    LIBVER,
    MAX_JSON_BYTES,
    STREAM_COLUMNS,
    SUPPORTED_VERSIONS,
    TABLE_COLUMNS,
    Event,
    SessionResults,
    StreamData,
    StreamSpec,
    TableData,
    complete_events,
    float_matrix,
    last_completed_position,
)
from station.session.torn import tail_rows

if TYPE_CHECKING:  # the solver (scipy) is imported where results are read: `_read_calibration`
    from station.solve.calibrate import CalibrationResult

_TABLE_KINDS = {**{c: ("f", ()) for c in TABLE_COLUMNS}, "status": ("u", ())}
"""dtype kind and trailing shape of each table column."""


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
        self.specs = {n: read_spec(_child(streams, n, h5py.Group, self.path), self.path)
                      for n in streams if n != "table"}
        self._checked = {}  # stream name (or "/table") -> its checked datasets (`_checked`)
        self._events = None  # the events read, for a file read in plain mode (`events`)

    @classmethod
    def open(cls, path) -> "Session":
        """Open a session file; `SessionFormatError` if it is not one this software reads.

        A file a writer has open (or left open when killed) is read in SWMR mode, a closed one
        in plain read-only mode."""
        live = open_flags(path) != 0
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
        return open_flags(self.path) == 0

    def reading_units(self, name: str) -> tuple:
        """The unit each channel of stream `name` reads in once divided by its counts per unit
        (`StreamData.to_si`): its SI unit (`spec.units`, which also says what it senses), or
        COUNTS for a stream imported as raw counts without their scale (`station import --unit
        NAME=counts:m/s^2`: counts per unit 1, the values stay counts; metadata
        `import.streams.NAME.unit`)."""
        entry = (self.metadata.get("import") or {}).get("streams", {}).get(name)
        unit = entry.get("unit") if isinstance(entry, dict) else None
        if isinstance(unit, str) and unit.startswith("counts:") and "@" not in unit:
            return (COUNTS,) * len(self.specs[name].units)
        return self.specs[name].units

    def stream(self, name: str, start: int = 0, stop: int | None = None,
               columns: tuple = STREAM_COLUMNS) -> StreamData:
        """The samples of a stream among its file rows [start, stop) (stop None: all flushed so
        far, the common length of its columns); rows of damaged chunks are left out, `rows` says
        which file row each sample is (None: all of [start, stop)). Only `columns` are read (the
        others are None): e.g. a stream's clock ("seq", "host_time"), from which windows are
        found and then read by row range (`station.reduce.windows`)."""
        if name not in self.specs:
            raise InputError(f"no stream {name!r} in {self.path}; it has {sorted(self.specs)}")
        spec = self.specs[name]
        if name not in self._checked:
            kinds = {"counts": ("iu", (len(spec.channels),)), "seq": ("i", ()),
                     "device_time": ("f", ()), "host_time": ("f", ())}
            self._checked[name] = _checked(self._file["streams"][name], STREAM_COLUMNS,
                                           self.path, kinds)
        read, rows = _columns(self._checked[name], self.path, drop_damaged=True, start=start,
                              stop=stop, read=columns)
        values = dict(zip(columns, read, strict=True))
        dtypes = {"seq": np.int64, "device_time": np.float64, "host_time": np.float64}
        for column, dtype in dtypes.items():
            if column in values:
                values[column] = values[column].astype(dtype, copy=False)
        if "host_time" in values:
            _finite(values["host_time"], f"/streams/{name}/host_time", self.path, start, rows)
        return StreamData(*(values.get(c) for c in STREAM_COLUMNS), spec, rows)

    def table(self, start: int = 0, stop: int | None = None) -> TableData:
        """The rotary-table states among the file rows [start, stop) (stop None: all flushed so
        far); rows of damaged chunks are left out, `rows` says which file row each state is (None:
        all of [start, stop))."""
        cols, rows = _columns(self._table(), self.path, drop_damaged=True, start=start,
                              stop=stop)
        floats = [c.astype(np.float64, copy=False) for c in cols[:-1]]
        for name, values in zip(TABLE_COLUMNS, floats, strict=False):
            _finite(values, f"/streams/table/{name}", self.path, start, rows)
        return TableData(*floats, cols[-1].astype(np.uint8, copy=False), rows)

    def table_times(self) -> tuple:
        """(time, rows): the times of the table states (their dimension scale) and the file row
        of each (None: row i is time[i]), rows of damaged chunks left out; `table(start, stop)`
        reads the states."""
        (time,), rows = _columns(self._table(), self.path, drop_damaged=True, read=("time",))
        time = time.astype(np.float64, copy=False)
        _finite(time, "/streams/table/time", self.path, 0, rows)
        return time, rows

    def _table(self) -> dict:
        """The table's checked datasets (`_checked`), looked up once."""
        if "/table" not in self._checked:  # no stream is named so ("/" is not in a name)
            g = _child(self._file["streams"], "table", h5py.Group, self.path)
            self._checked["/table"] = _checked(g, TABLE_COLUMNS, self.path, _TABLE_KINDS)
        return self._checked["/table"]

    def events(self) -> list:
        """Protocol events flushed so far, in order (a new list each call). A file read in plain
        mode (no writer: its events cannot change) is read once; a SWMR file on every call."""
        if self._events is None or self._file.swmr_mode:
            self._events = read_events(_child(self._file, "events", h5py.Group, self.path),
                                       self.path)
        return list(self._events)

    def last_completed_position(self) -> int | None:
        """Position of the last `position_done` event (None: no position completed)."""
        return last_completed_position(self.events())

    def last_instant(self) -> float:
        """The latest clock time recorded (events, table states, sample arrivals): where a resumed
        session's clock continues."""
        times = [e.time for e in self.events()] + [self.table().time.max(initial=-np.inf)]
        times += [self.stream(name).host_time.max(initial=-np.inf) for name in self.specs]
        return float(max(times))

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
        channels = _result_channels(g.attrs, len(spec.channels), where)
        m = len(spec.channels) if channels is None else len(channels)
        readings = _matrix(g, "readings", where, rows=m)
        sigma = _matrix(g, "readings_sigma", where, shape=readings.shape) if "readings_sigma" in g \
            else None
        cal = _read_calibration(g, where, readings.shape) if "calibration" in g else None
        settings = _json_object(_attr(g.attrs, "settings", str, where), f"{where} settings") \
            if "settings" in g.attrs else None
        return SessionResults(name, stream, tuple(_attr(g.attrs, "units", list, where)), readings,
                              sigma, cal, _attr(g.attrs, "created", str, where), settings,
                              channels, _attr(g.attrs, "sequence", int, where)
                              if "sequence" in g.attrs else 0)

    def close(self) -> None:
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _result_channels(attrs, m: int, where) -> tuple | None:
    """The stream channels a result's rows are (None: all of them), checked."""
    if "channels" not in attrs:
        return None
    rows = np.asarray(attrs["channels"])
    if rows.ndim != 1 or rows.dtype.kind not in "iu" or len(set(rows.tolist())) != len(rows) \
            or not np.all((rows >= 0) & (rows < m)):
        raise SessionFormatError(f"{where}: channels {rows.tolist()} are not distinct channels "
                                 f"of the stream's {m}")
    return tuple(int(i) for i in rows)


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
    """An attribute of the expected Python type (str, float, int or list of str)."""
    value = attrs.get(key)
    # an empty list written as a plain array comes back as float64 (files of early version-1
    # writers)
    if kind is list and isinstance(value, np.ndarray) and value.ndim == 1 and (
        value.dtype == object or value.size == 0
    ):
        value = list(value)
        if all(isinstance(v, str) for v in value):
            return value
    elif kind is float and isinstance(value, np.floating | float):
        return float(value)
    elif kind is int and isinstance(value, np.integer):
        return int(value)
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
    if kind is h5py.Dataset and not stored_plainly(obj):
        raise SessionFormatError(f"{where}: {obj.name} uses external storage or unknown "
                                 "filters; refusing to read it")
    return obj


def _read_metadata(f, where) -> dict:
    ds = _child(f, "metadata", h5py.Dataset, where)
    if ds.shape != () or ds.dtype.kind not in "OS":
        raise SessionFormatError(f"{where}: /metadata must be one JSON string")
    text = ds[()]
    digest = ds.attrs.get("sha256")  # files of earlier writers have none
    if digest is not None and hashlib.sha256(
            text if isinstance(text, bytes) else text.encode()).hexdigest().encode() != digest:
        raise SessionFormatError(f"{where}: /metadata does not match its checksum; the file is "
                                 "damaged (use an undamaged copy)")
    return _json_object(text, f"{where}: /metadata")


def _json_object(raw, what: str) -> dict:
    """A JSON object from untrusted text, size-limited; SessionFormatError naming `what`."""
    if len(raw) > MAX_JSON_BYTES:
        raise SessionFormatError(f"{what} is over {MAX_JSON_BYTES} bytes")
    value = json_loads(raw, what, error=SessionFormatError)
    if not isinstance(value, dict):
        raise SessionFormatError(f"{what} must be a JSON object")
    return value


def read_spec(g, where="") -> StreamSpec:
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


def _checked(g, names, where, kinds) -> dict:
    """{name: dataset} of the datasets `names` of `g`, each a plain dataset of this file with the
    dtype kind and trailing shape of `kinds` (name -> (dtype kinds, trailing shape))."""
    datasets = {n: _child(g, n, h5py.Dataset, where) for n in names}
    for n, ds in datasets.items():
        dtype_kinds, tail = kinds[n]
        if ds.dtype.kind not in dtype_kinds or ds.shape[1:] != tail:
            raise SessionFormatError(f"{where}: {ds.name} has dtype {ds.dtype} and shape "
                                     f"{ds.shape}; expected kind {dtype_kinds!r}, rows x {tail}")
    return datasets


def _columns(datasets, where, drop_damaged=False, start=0, stop=None, read=None) -> tuple:
    """(columns, rows): the datasets `read` (default: all) of `datasets` (`_checked`), refreshed
    (`_refresh`), read over the rows [start, stop) of their common length (stop None: to that
    length); `rows` the file row of each value read, None when every row of [start, stop) was
    (no chunk damaged, the common case). A chunk that does not read back (its fletcher32
    checksum fails) is a SessionFormatError, or with `drop_damaged` its rows are left out of
    every column read (but those its old checksum vouches for after a rewrite cut by a kill,
    `torn`), as samples the link lost (the sequence numbers show the gap;
    `station.session.check` names the positions they belong to)."""
    _refresh(*datasets.values())
    k = min(ds.shape[0] for ds in datasets.values())
    start, stop = min(start, k), k if stop is None else min(stop, k)
    columns, intact = zip(*(_rows(datasets[n], start, max(start, stop), where, drop_damaged)
                            for n in (datasets if read is None else read)), strict=True)
    keep = np.logical_and.reduce(intact)
    if keep.all():
        return list(columns), None
    return [c[keep] for c in columns], start + np.flatnonzero(keep)


def _refresh(*datasets) -> None:
    """Bring the datasets (of one file) up to what a live writer has flushed, when the file is
    read in SWMR mode (`Session.open`: a writer has it open, or left it open when killed); a file
    read in plain mode has no writer, so nothing to refresh (each refresh is a call into HDF5, and
    a replay reads thousands of windows)."""
    if datasets and datasets[0].file.swmr_mode:
        for ds in datasets:
            ds.refresh()


def _finite(values: np.ndarray, name: str, where, start: int, rows) -> None:
    """Refuse a recorded column (times, table rates and angles) holding NaN or inf: the writer
    never records one, so the dataset is damaged (a window cut at a NaN instant would silently
    change the result)."""
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        row = start + int(bad[0]) if rows is None else int(rows[bad[0]])
        more = f" and {bad.size - 1} more row(s)" if bad.size > 1 else ""
        raise SessionFormatError(f"{where}: {name} holds {values[bad[0]]} at row {row}{more} (a "
                                 "recorded value is finite): the dataset is damaged; use an "
                                 "undamaged copy")


def _rows(ds, start: int, stop: int, where, drop_damaged: bool) -> tuple:
    """(the rows [start, stop) of `ds`, a mask of the rows that read back intact). A last chunk
    whose rewrite a kill cut short keeps the rows its old checksum vouches for (`torn`: the
    durable ones) and loses the interrupted flush's, with or without `drop_damaged` (without it,
    every row after the tear is left out: a killed writer's events and table states end where
    its last complete flush did); other damage is a SessionFormatError without it."""
    try:
        return ds[start:stop], np.ones(stop - start, bool)
    except OSError as e:
        if ds.chunks is None:
            raise SessionFormatError(f"{where}: {ds.name} does not read back intact ({e}); the "
                                     "file is damaged") from None
        error = e
    values = np.zeros((stop - start, *ds.shape[1:]), ds.dtype)
    intact = np.ones(stop - start, bool)
    size = ds.chunks[0]
    for first in range(start - start % size, stop, size):
        a, b = max(first, start), min(first + size, stop)
        try:
            values[a - start:b - start] = ds[a:b]
        except OSError:
            kept = tail_rows(ds, first)
            if kept is None and not drop_damaged:
                raise SessionFormatError(f"{where}: {ds.name} does not read back intact "
                                         f"({error}); the file is damaged") from None
            good = min(b, first + (0 if kept is None else len(kept)))
            if good > a:
                values[a - start:good - start] = kept[a - first:good - first]
            intact[max(good, a) - start:(b if drop_damaged else stop) - start] = False
            if not drop_damaged:
                break
    return values, intact


def read_events(g, where="") -> list:
    kinds = {"time": ("f", ()), "position": ("i", ()), "kind": ("S", ()), "detail_end": ("i", ())}
    (times, positions, kind_bytes, ends), _ = _columns(_checked(g, EVENT_COLUMNS, where, kinds),
                                                       where)
    detail = _child(g, "detail", h5py.Dataset, where)
    _refresh(detail)
    if detail.dtype != np.uint8 or detail.ndim != 1:
        raise SessionFormatError(f"{where}: events/detail must be a 1-D uint8 byte stream")
    k = complete_events(ends, detail.shape[0], where)
    starts = np.concatenate([[0], ends[:-1]]).astype(np.int64)
    text, k = _event_text(detail, ends, k, where)
    events = []
    _finite(times[:k].astype(np.float64), "/events/time", where, 0, None)
    for t, p, kb, s, e in zip(times[:k], positions[:k], kind_bytes[:k], starts[:k], ends[:k],
                              strict=True):
        try:
            kind = kb.decode("ascii")
        except UnicodeDecodeError as err:
            raise SessionFormatError(f"{where}: an event kind is not ASCII ({err})") from None
        info = json_loads(text[s:e], f"{where}: an event's detail", error=SessionFormatError)
        if not isinstance(info, dict):
            raise SessionFormatError(f"{where}: event detail must be a JSON object")
        if kind not in EVENT_KINDS:
            raise SessionFormatError(f"{where}: unknown event kind {kind!r} (this software knows "
                                     f"{', '.join(EVENT_KINDS)}); the file is damaged or from "
                                     "newer software")
        events.append(Event(float(t), None if p < 0 else int(p), kind, info))
    return events


def _event_text(detail, ends, k: int, where) -> tuple:
    """(the detail bytes of the first `k` events, how many of them read back intact): a kill
    that cut the rewrite of the stream's last chunk loses the events whose bytes were in it
    (`_rows`: the rows its old checksum vouches for are kept); damage before the last chunk is
    SessionFormatError."""
    if not k:
        return b"", 0
    stop = int(ends[k - 1])
    values, intact = _rows(detail, 0, stop, where, True)
    if not intact.all():
        bad = int(np.argmin(intact))  # the first byte that did not read back
        if bad < detail.shape[0] - detail.chunks[0]:
            raise SessionFormatError(f"{where}: {detail.name} does not read back intact before "
                                     "its last chunk; the file is damaged")
        k = int(np.searchsorted(ends[:k], bad, "right"))
    return values.tobytes(), k


def _matrix(g, name, where, rows=None, shape=None) -> np.ndarray:
    ds = _child(g, name, h5py.Dataset, where)
    if ds.dtype.kind != "f":
        raise SessionFormatError(f"{where}/{name} must be floating point, got {ds.dtype}")
    try:
        return float_matrix(ds[()], f"{where}/{name}", rows, shape)
    except ValueError as e:
        raise SessionFormatError(str(e)) from None


LATER_FIELDS = ("parameter_covariance", "start", "pose_sigma", "a_sigma_white",
                "scale_factors_sigma_white", "axis_angles_sigma_white", "bias_sigma_white")
"""CalibrationResult fields added after format version 1 was first written: None when absent."""
WORDS_FIELDS = ("weakly_determined",)
"""CalibrationResult fields of words, stored as one string ("; " between them): () when absent."""


def _read_calibration(g, where, readings_shape) -> "CalibrationResult":
    """A `CalibrationResult` from its group; every field present or listed as None, arrays float,
    shapes consistent with the readings (m x n)."""
    from station.solve.calibrate import CalibrationResult

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
        elif key in WORDS_FIELDS:
            values[key] = ""
        else:
            raise SessionFormatError(f"{where}: field {key!r} is missing")
    for key in WORDS_FIELDS:
        values[key] = tuple(p for p in str(values[key]).split("; ") if p)
    a = values["a"]
    if a.ndim != 2 or a.shape[1] != m:
        raise SessionFormatError(f"{where}/a has shape {a.shape}, expected (d, {m})")
    expected = {"v": (a.shape[0], n), "residuals": (m, n), "sigma": (m, n),
                "a_sigma": a.shape, "scale_factors": (m,), "axis_angles": (m, m),
                "axis_angles_sigma": (m, m), "scale_factors_sigma": (m,), "bias": (m,),
                "bias_sigma": (m,), "a_sigma_white": a.shape, "scale_factors_sigma_white": (m,),
                "axis_angles_sigma_white": (m, m), "bias_sigma_white": (m,)}
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
