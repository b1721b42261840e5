"""Foreign recordings into session files (docs/session-format.md), as `station import` does.

Four formats (the flight-controller logs: station/imports/ulog.py, import_dataflash.py),
every file treated as untrusted input (sizes, types and values checked before use, nothing
unpickled or evaluated; errors are `CalibrationInputError`s naming the problem and the fix):

- `import_text`: tables `t x y z` without a header (imu_tk's `.mat` files are such text; MATLAB
  v5/v7 and v7.3 files with one numeric array are read too, in either orientation), one file per
  stream (station.imports.tables.read_matrix);
- `import_csv`: a delimited text file with a header of column names (imucal's sessions), the
  delimiter sniffed and a preamble skipped (station.imports.tables.read_csv), one stream per group
  of named columns, time from a column or from sample numbers at a given rate; a Kalibr/EuRoC
  IMU CSV is recognised by its header without any (station.imports.kalibr);
- `import_npz`: the array file of raw rotary recordings (docs/simulator.md: `y`, `lsb`, `fs`, `t0`,
  `rate_cmd`, `c_cmd`, `seg_*`, `a_nominal`, optional `angle`), loaded with `allow_pickle=False`
  after its array headers were checked. The session holds the counts, the table's angle and rate as
  table states and the protocol's events, so `station.reduce.rotary.rotary_readings` reduces it.
  Other arrays holding fixed-width strings or one number (a data set name, a version tag) are kept
  as session metadata;
- `import_binary`: a raw dump of a serial IMU's binary frames, decoded by the drivers' own parser
  (drivers.wire.binary, the live link's decoder) with the device profile; bad frames are counted
  and skipped, the device time stamps (unwrapped) are the sample times.

Time columns are in seconds unless a `time_unit` (s, ms, us, ns) is given; without one, time
stamps whose median step means a rate outside 2 Hz..100 kHz are refused (probably another unit).
A time column that is a host's clock (lines stamped as they arrived) is told from a device's
stamps and the samples placed on the device's clock (station.imports.timing). How each file was
read (delimiter, lines skipped, orientation, MATLAB version, bad frames, the clock) is kept in the
metadata's `import.notes` and logged.

Units: each stream's numbers are in a `unit` given by the user: an SI unit (`m/s^2`, `rad/s`, `T`),
a known other one (`g`, `deg/s`, `uT`, `gauss`), or raw counts of a quantity, `counts:m/s^2`, with
their scale when known, `counts:m/s^2@415` (counts per SI unit; default 1: readings then stay in
counts, the calibration's `a` is in counts per SI unit). Numbers that are not raw counts are stored
as fixed-point integers, `FIXED_POINT` counts per unit given (an error below 5e-7 of that unit).
"""

import hashlib
import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.profile import SerialImuProfile, load_profile
from drivers.rotary_table import TableReading
from drivers.samples import SampleBlock
from drivers.wire.binary import BinaryFrameParser
from station.errors import CalibrationInputError, InputError
from station.files.jsonable import jsonable
from station.imports import npz
from station.imports.kalibr import recognise
from station.imports.tables import MAX_BYTES, read_csv, read_matrix
from station.imports.timing import timeline
from station.model.constants import STANDARD_GRAVITY
from station.session import SessionWriter, StreamSpec

log = logging.getLogger(__name__)

FIXED_POINT = 1e6
"""Counts per given unit for numbers that are not raw counts."""

UNITS = {"m/s^2": ("m/s^2", 1.0), "g": ("m/s^2", STANDARD_GRAVITY),
         "rad/s": ("rad/s", 1.0),
         "deg/s": ("rad/s", math.pi / 180), "T": ("T", 1.0), "uT": ("T", 1e-6),
         "gauss": ("T", 1e-4)}
"""unit -> (SI unit, SI units per unit)."""

TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
"""Time unit -> seconds per unit."""

PLAUSIBLE_RATE = (2.0, 1e5)
"""Sample rates (Hz) time stamps in seconds may give without an explicit time unit."""

MAX_TEXT_METADATA = 1 << 20
"""Largest string array of an .npz kept as metadata, bytes."""

DUMP_CHUNK = 1 << 20
"""Bytes of a binary dump given to the frame parser at once."""

NPZ_KEYS = {"y": 3, "lsb": None, "fs": 0, "t0": 1, "rate_cmd": 1, "c_cmd": 0, "seg_static": 1,
            "seg_spinup": 1, "seg_settle": 1, "seg_rotating": 1, "seg_spindown": 1,
            "a_nominal": 2}
"""Required keys of a rotary array file and their number of dimensions (None: 0 or 1)."""
OPTIONAL_NPZ_KEYS = ("angle", "temperature")
"""Optional arrays of a rotary array file: the table's reported angle ((k,) or (n, k), rad) and
the unit's recorded temperature ((n, k), K; read by `station diagnose`, not by `station import`,
which names it among the arrays it leaves out)."""


@dataclass(frozen=True)
class Unit:
    """What the numbers of a stream are: `si` unit, `raw` counts or not, and the counts per SI
    unit of the stored integers."""

    si: str
    raw: bool
    counts_per_unit: float

    @classmethod
    def parse(cls, spec: str) -> "Unit":
        """`m/s^2`, `deg/s`, ..., or `counts:<SI unit>[@<counts per SI unit>]`."""
        match = re.fullmatch(r"counts:([^@]+)(?:@(.+))?", spec.strip())
        if match:
            si, scale = match.group(1), match.group(2)
            if si not in ("m/s^2", "rad/s", "T"):
                raise CalibrationInputError(f"unit {spec!r}: raw counts of {si!r}?",
                                            "Write counts:m/s^2, counts:rad/s or counts:T.")
            try:
                value = 1.0 if scale is None else float(scale)
            except ValueError:
                value = math.nan
            if not (math.isfinite(value) and value > 0):
                raise CalibrationInputError(f"unit {spec!r}: scale {scale!r} is not positive.",
                                            "Give counts per SI unit, e.g. counts:m/s^2@415.")
            return cls(si, True, value)
        if spec not in UNITS:
            raise CalibrationInputError(
                f"unknown unit {spec!r}.",
                f"Use one of {', '.join(UNITS)} or counts:<SI unit>[@<counts per SI unit>].")
        si, factor = UNITS[spec]
        return cls(si, False, FIXED_POINT / factor)


def import_text(out, streams: dict, units: dict, *, unit_serial: str = "IMPORTED",
                fs: float | None = None, time_unit: str | None = None,
                delimiter: str | None = None, skip_rows: int = 0, columns: dict | None = None,
                untimed: bool = False) -> Path:
    """Import tables `t x y z ...` (one file per stream: name -> path) into a new session `out`.

    units : stream name -> unit spec (see the module docstring). Streams must share their time
    stamps when there are several. fs: nominal rate (default: from the median time step).
    time_unit: of the first column (see the module docstring); delimiter and skip_rows: of text
    files (station.imports.tables.read_matrix). columns : stream name -> 0-based indices of its
    value columns in its file (default: every column but the time), so one file can hold several
    streams. untimed: the files have no time column; the rows are samples at `fs`.
    """
    _check_names(streams, units)
    if untimed and fs is None:
        raise CalibrationInputError("tables without a time column need the sample rate.",
                                    "Give --fs HZ.")
    read = {name: read_matrix(path, delimiter=delimiter, skip_rows=skip_rows)
            for name, path in streams.items()}
    for name, table in read.items():
        if table.values.shape[1] < 2 and not untimed:
            raise CalibrationInputError(
                f"{streams[name]} holds one column; a time column and values are expected.",
                "Give a table t x y z ... (one row or column per sample), or --no-time.")
    notes = [note for table in read.values() for note in table.notes]
    tables = {name: table.values for name, table in read.items()}
    times = {name: np.arange(len(t)) / fs if untimed else
             _seconds(t[:, 0], time_unit, str(streams[name])) for name, t in tables.items()}
    first = next(iter(times.values()))
    for name, t in times.items():
        if t.shape != first.shape or not np.array_equal(t, first):
            raise CalibrationInputError(f"stream {name!r} has other time stamps than the first.",
                                        "Import streams recorded on different clocks separately.")
    values = {name: _values(t, (columns or {}).get(name), int(not untimed), streams[name])
              for name, t in tables.items()}
    sources = {name: str(path) for name, path in streams.items()}
    if not untimed:
        clock = timeline(first, None, fs, ", ".join(str(p) for p in streams.values()))
        first, fs, notes = clock.t, clock.rate_hz, notes + clock.notes
    return _write(out, "text", sources, values, units, first, None, fs, unit_serial, notes)


def _values(table, columns, first: int, path) -> np.ndarray:
    """The value columns of a text table: `columns` (0-based, checked), else from `first` on."""
    if columns is None:
        return table[:, first:]
    if not columns or min(columns) < 0 or max(columns) >= table.shape[1]:
        raise CalibrationInputError(f"{path} has {table.shape[1]} columns; columns "
                                    f"{[c + 1 for c in columns]} were asked for.",
                                    "Count the columns from 1, the time column included.")
    return table[:, list(columns)]


def import_csv(out, path, streams: dict, units: dict, *, time_column: str | None = None,
               index_column: str | None = None, fs: float | None = None,
               unit_serial: str = "IMPORTED", time_unit: str | None = None,
               delimiter: str | None = None, skip_rows: int | None = None,
               progress=None) -> Path:
    """Import a delimited text file with a header row into a new session `out`.

    streams : stream name -> list of column names (e.g. {"acc": ["acc_x", "acc_y", "acc_z"]})
    units   : stream name -> unit spec
    Time: `time_column` (in `time_unit`; a host's stamps are told from a device's and the
    samples placed by `index_column`, the device's counter, or at `fs` when given:
    station.imports.timing), or `index_column` (sample numbers) with `fs`, or rows at `fs`.
    delimiter (None: sniffed) and skip_rows (None: the header line is searched for):
    station.imports.tables.read_csv (and its `progress`). No streams, time column or rate: a
    Kalibr/EuRoC IMU CSV, recognised by its header (station.imports.kalibr), streams gyro
    and acc at its nanosecond time stamps.
    """
    path = Path(path)
    recognised = []
    if not streams and time_column is None and index_column is None and fs is None:
        layout = recognise(path)
        streams, units, time_column = layout.streams, layout.units, layout.time_column
        time_unit, delimiter, recognised = "ns", delimiter or ",", [layout.note]
    _check_names(streams, units)
    wanted = [c for cols in streams.values() for c in cols]
    for extra in (time_column, index_column):
        if extra is not None:
            wanted.append(extra)
    if time_column is None and fs is None:
        raise CalibrationInputError("give a time column or a sample rate fs.",
                                    "Use --time COLUMN (seconds) or --fs HZ (with --index COLUMN).")
    if time_unit is not None and time_column is None:
        raise CalibrationInputError("a time unit without a time column.",
                                    "Give --time COLUMN with --time-unit, or drop --time-unit.")
    read = read_csv(path, wanted, delimiter=delimiter, skip_rows=skip_rows, progress=progress)
    table = read.values
    by_name = {c: table[:, i] for i, c in enumerate(wanted)}
    seq = None if index_column is None else \
        _integers(by_name[index_column], f"{path}: column {index_column!r}")
    clock = []
    if time_column is not None:
        where = f"{path.name}: column {time_column!r}"
        found = timeline(_seconds(by_name[time_column], time_unit, where), seq, fs, where)
        t, seq, fs, clock = found.t, found.seq, found.rate_hz, found.notes
    elif seq is not None:
        t = seq / fs
    else:
        t = np.arange(len(table)) / fs
    values = {name: np.column_stack([by_name[c] for c in cols]) for name, cols in streams.items()}
    return _write(out, "csv", {name: str(path) for name in streams}, values, units, t, seq, fs,
                  unit_serial, recognised + list(read.notes) + clock)


def import_npz(out, path, *, unit_serial: str = "IMPORTED", max_bytes: int = MAX_BYTES) -> Path:
    """Import a rotary array file (docs/simulator.md) into a new session `out` that
    `station.reduce.rotary.rotary_readings` reduces like `station.reduce.eq18.reduce_arrays`."""
    arrays = read_npz(path, max_bytes)
    y, lsb, fs = arrays["y"], arrays["lsb"], float(arrays["fs"])
    n, k, m = y.shape
    start = np.round(arrays["t0"] * fs).astype(np.int64)
    if np.any(np.diff(start) < k):
        raise CalibrationInputError(f"{path}: positions overlap in time (t0 steps shorter than "
                                    f"{k} samples at {fs:g} Hz).", "Check t0, fs and y.")
    angle = arrays.get("angle")
    if angle is None:
        rate = arrays["rate_cmd"]
        angle = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]))]) / fs
    angle = np.broadcast_to(angle, (n, k))
    swept = angle[:, -1] - angle[:, 0]  # the table's angle keeps counting across positions
    angle = angle - angle[:, :1] + np.concatenate([[0.0], np.cumsum(swept)[:-1]])[:, None]
    spec = StreamSpec([f"g{i + 1}" for i in range(m)], "rad/s", 1.0 / np.broadcast_to(lsb, (m,)),
                      fs, "int64" if y.dtype.itemsize > 4 else "int32", "imported-npz")
    extra, notes = npz_metadata(path, max_bytes)
    metadata = {"protocol": "rotary", "unit_serial": unit_serial,
                "a_nominal": arrays["a_nominal"].tolist(),
                "settings": {"rate": float(arrays["c_cmd"])},
                "table_timing": "sample",  # one table state at each sample's instant, exact
                "import": {"format": "npz", "source": str(path), "sha256": _sha256(path),
                           "metadata": extra, "notes": notes}}
    _log_notes(notes)
    with SessionWriter.create(out, metadata, {"imu": spec}, clock=_Fixed(start[0] / fs)) as w:
        for j in range(n):
            seq = start[j] + np.arange(k)
            t = seq / fs
            w.append("imu", SampleBlock(y[j].astype(np.int64), seq, t, t, spec.channels))
            w.append_table(_table_states(t, arrays, angle[j]))
            _rotary_events(w, j, start[j], fs, arrays, angle[j])
    return Path(out)


def read_npz(path, max_bytes: int = MAX_BYTES) -> dict:
    """The checked arrays of a rotary array file: headers first (no object arrays, at most
    `max_bytes` each), then loaded without pickle, then types, shapes and values."""
    path = Path(path)
    headers = _npz_headers(path, max_bytes)
    missing = sorted(set(NPZ_KEYS) - set(headers))
    if missing:
        raise CalibrationInputError(f"{path} lacks the arrays {missing}.",
                                    "Give a rotary array file (docs/simulator.md).")
    with np.load(path, allow_pickle=False) as f:
        arrays = {key: f[key] for key in [*NPZ_KEYS, *optional_arrays(headers)]}
    for key, ndim in NPZ_KEYS.items():
        a = arrays[key]
        dims_ok = a.ndim <= 1 if ndim is None else a.ndim == ndim
        if a.dtype.kind not in "iuf" or not dims_ok or not np.all(np.isfinite(a)):
            raise CalibrationInputError(f"{path}: {key} is a {a.ndim}-D {a.dtype} array (finite "
                                        f"numbers of {ndim if ndim is not None else '0 or 1'} "
                                        "dimensions expected).", "Check the file's writer.")
    y = arrays["y"]
    if y.dtype.kind not in "iu" or 0 in y.shape:
        raise CalibrationInputError(f"{path}: y is a {y.dtype} array of shape {y.shape}.",
                                    "y holds integer counts, (positions, samples, sensors).")
    n, k, m = y.shape
    shapes = {"lsb": [(), (m,)], "t0": [(n,)], "rate_cmd": [(k,)], "a_nominal": [(3, m)],
              "angle": [(k,), (n, k)], "temperature": [(n, k)]}
    for key, allowed in shapes.items():
        if key in arrays and arrays[key].shape not in allowed:
            raise CalibrationInputError(f"{path}: {key} has shape {arrays[key].shape}, expected "
                                        f"{' or '.join(map(str, allowed))}.", "Check the file.")
    for key in OPTIONAL_NPZ_KEYS:
        if key in arrays and (arrays[key].dtype.kind not in "iuf"
                              or not np.all(np.isfinite(arrays[key]))):
            raise CalibrationInputError(f"{path}: {key} holds NaN, infinite or non-numeric "
                                        "values.", "Check it.")
    if not (np.all(arrays["lsb"] > 0) and arrays["fs"] > 0):
        raise CalibrationInputError(f"{path}: lsb and fs must be positive.", "Check the file.")
    for key in (k for k in NPZ_KEYS if k.startswith("seg_")):
        s = arrays[key]
        if s.shape != (2,) or s.dtype.kind not in "iu" or not 0 <= s[0] < s[1] <= k:
            raise CalibrationInputError(f"{path}: {key} = {s.tolist()} is not a [start, stop) "
                                        f"window within 0..{k}.", "Check the file.")
    return arrays


def optional_arrays(headers: dict) -> list:
    """The OPTIONAL_NPZ_KEYS an .npz holds as arrays (headers: `_npz_headers`); one that is a
    single number or a string (a `temperature = 21.5` tag) is metadata (`npz_metadata`)."""
    return [k for k in OPTIONAL_NPZ_KEYS if k in headers and len(headers[k][0]) >= 1]


def npz_metadata(path, max_bytes: int = MAX_BYTES) -> tuple:
    """({name: value}, notes) of the arrays of an .npz that are not rotary data: fixed-width
    strings (as a string or a list of them) and single numbers are kept, loaded without pickle;
    other numeric arrays are named in the notes and left out."""
    headers = _npz_headers(path, max_bytes)
    names = sorted(set(headers) - set(NPZ_KEYS) - set(optional_arrays(headers)))
    kept, notes = {}, []
    with np.load(path, allow_pickle=False) as f:
        for name in names:
            shape, dtype = headers[name]
            if dtype.kind in "US" and math.prod(shape) * dtype.itemsize <= MAX_TEXT_METADATA:
                kept[name] = _strings(f[name])
            elif dtype.kind in "iufb" and math.prod(shape) == 1:
                kept[name] = f[name].reshape(()).item()
            else:
                notes.append(f"{Path(path).name}: array {name!r} {shape} {dtype} left out (only "
                             "strings and single numbers are kept as metadata)")
    if kept:
        notes.append(f"{Path(path).name}: kept as metadata: {', '.join(kept)}")
    return jsonable(kept), notes


def import_binary(out, path, profile, *, unit_serial: str = "IMPORTED") -> Path:
    """Import a raw dump of a serial IMU's binary frames into a new session `out`, stream "imu"
    as a live recording with the same device profile writes it (channels, units, scale).

    profile: a SerialImuProfile, a profile path or a bundled name (`[serial] protocol = "binary"`).
    The drivers' own frame parser decodes the dump (the live link's decoder); frames failing
    their check, cut short or misaligned are counted and skipped. Sample times are the device
    time stamps (unwrapped), or sequence number / rate_hz when the frames carry none.
    """
    prof = profile if isinstance(profile, SerialImuProfile) else SerialImuProfile.load(profile)
    if prof.serial.protocol != "binary":
        raise CalibrationInputError(f"profile {prof.source} describes text lines, not binary "
                                    "frames.", "Give a binary device profile (--profile), or "
                                    "import the text with `station import csv`.")
    parser = BinaryFrameParser(prof.serial.frame, prof.imu.channels, prof.imu.scale)
    blocks = []
    with open(path, "rb") as f:
        while data := f.read(DUMP_CHUNK):
            blocks.append(parser.decode(data, 0.0).block)
    blocks.append(parser.decode(b"", 0.0, final=True).block)
    block, stats = SampleBlock.concat(blocks), parser.stats
    if len(block) < 2:
        raise CalibrationInputError(
            f"{path}: {len(block)} frame(s) of profile {Path(prof.source).name} in {stats.bytes} "
            f"bytes ({stats.crc_failures} sync candidates failed their check).",
            "Check that --profile describes the device that wrote the dump (sync, layout, byte "
            "order, checksum, channel count).")
    timed = math.isfinite(prof.serial.frame.time_tick)  # a "time" field, in any profile style
    t = block.device_time if timed else block.seq / prof.imu.rate_hz
    if np.any(np.diff(t) <= 0):
        raise CalibrationInputError(f"{path}: the device time stamps do not increase.",
                                    "Check the profile's time field (time_type, its place in the "
                                    "layout); a device restarted mid-dump needs splitting.")
    link = _link_figures(block, stats, parser.size, t)
    notes = [f"{Path(path).name}: {len(block)} frames decoded with {Path(prof.source).name}, "
             f"{stats.crc_failures} bad frame candidates skipped, {stats.resyncs} resyncs, "
             f"{stats.dropped} sequence numbers missing, {link['unused_bytes']} bytes unused; "
             f"{link['duration_s']:.3f} s at {link['rate_hz']:.4f} Hz "
             f"({'device time stamps' if timed else 'sequence numbers'})"]
    metadata = {"protocol": "import", "unit_serial": unit_serial,
                "profiles": {"imu": load_profile(prof.source).tables},
                "import": {"format": "binary", "profile": prof.source, "link": link,
                           "sources": {"imu": {"path": str(path), "sha256": _sha256(path)}},
                           "notes": notes}}
    _log_notes(notes)
    spec = StreamSpec.from_profile(prof.imu, "int64")
    with SessionWriter.create(out, metadata, {"imu": spec}, clock=_Fixed(t[0])) as w:
        w.append("imu", SampleBlock(block.counts, block.seq, block.device_time, t, spec.channels))
    return Path(out)


# ----------------------------------------------------------------------------------- internals


class _Fixed:
    """A clock standing at one time (the recording's start): imported events carry their own."""

    def __init__(self, t: float):
        self.t = float(t)

    def now(self) -> float:
        return self.t


def _write(out, fmt, sources, values, units, t, seq, fs, unit_serial, notes) -> Path:
    """One session: a stream per entry of `values` ((K, c) numbers in the units given); `notes`
    (how the files were read) kept in the metadata and logged."""
    t = np.asarray(t, float)
    if len(t) < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise CalibrationInputError("the time stamps are not strictly increasing (or fewer than 2 "
                                    "samples).", "Sort the rows by time and drop repeated rows.")
    rate = float(fs) if fs is not None else 1.0 / float(np.median(np.diff(t)))
    if not (math.isfinite(rate) and rate > 0):
        raise CalibrationInputError(f"sample rate {fs!r} is not positive.", "Give fs in Hz.")
    seq = np.arange(len(t), dtype=np.int64) if seq is None else np.asarray(seq, np.int64)
    specs, blocks, stream_notes = {}, {}, {}
    for name, v in values.items():
        unit = Unit.parse(units[name])
        counts = _counts(v, unit, name)
        specs[name] = StreamSpec([f"{name}{i + 1}" for i in range(v.shape[1])], unit.si,
                                 unit.counts_per_unit, rate, "int64", f"imported-{fmt}")
        blocks[name] = SampleBlock(counts, seq, t, t, specs[name].channels)
        stream_notes[name] = {"unit": units[name], "raw_counts": unit.raw}
    metadata = {"protocol": "import", "unit_serial": unit_serial,
                "import": {"format": fmt, "streams": stream_notes,
                           "sources": {n: {"path": p, "sha256": _sha256(p)}
                                       for n, p in sources.items()}, "notes": notes}}
    _log_notes(notes)
    with SessionWriter.create(out, metadata, specs, clock=_Fixed(t[0])) as w:
        for name, block in blocks.items():
            w.append(name, block)
    return Path(out)


def _seconds(t, unit: str | None, what: str) -> np.ndarray:
    """Time stamps in seconds. Without a unit they are taken as seconds if their median step
    means a plausible sample rate (PLAUSIBLE_RATE), else refused: probably ms, us or ns."""
    t = np.asarray(t, float)
    if unit is not None:
        if unit not in TIME_UNITS:
            raise CalibrationInputError(f"unknown time unit {unit!r}.",
                                        f"Give --time-unit as one of {', '.join(TIME_UNITS)}.")
        return t * TIME_UNITS[unit]
    step = float(np.median(np.diff(t))) if len(t) > 1 else math.nan
    low, high = PLAUSIBLE_RATE
    if step > 0 and not low <= 1.0 / step <= high:
        raise CalibrationInputError(
            f"{what}: the time stamps step by {step:g} (median), {1.0 / step:g} Hz if they are "
            "seconds.", "Give their unit: --time-unit ms, us or ns (or --time-unit s if that "
            "rate is right).")
    return t


def _link_figures(block, stats, frame_size: int, t) -> dict:
    """What decoding a dump found: frames, bad candidates, resyncs, missing sequence numbers,
    bytes in no frame (garbage, damaged and cut frames), duration and rate of the time stamps."""
    return {"frames": len(block), "bad_frames": stats.crc_failures, "resyncs": stats.resyncs,
            "gaps": stats.gaps, "dropped": stats.dropped, "bytes": stats.bytes,
            "unused_bytes": stats.bytes - len(block) * frame_size,
            "duration_s": float(t[-1] - t[0]), "rate_hz": 1.0 / float(np.median(np.diff(t)))}


def _strings(a: np.ndarray):
    """A fixed-width string array as a str (0-d) or nested lists of str; bytes decoded as UTF-8
    (undecodable bytes replaced)."""
    if a.dtype.kind == "S":
        a = np.char.decode(a, "utf-8", errors="replace")
    return a.tolist()


def _log_notes(notes) -> None:
    for note in notes:
        log.info("import: %s", note)


def _counts(values, unit: Unit, name: str) -> np.ndarray:
    """Integer counts of `values`: exact raw counts, or fixed point."""
    v = np.asarray(values, float)
    if unit.raw:
        return _integers(v, f"stream {name!r} (raw counts)")
    scaled = v * FIXED_POINT
    if np.any(np.abs(scaled) >= 2.0**62):
        raise CalibrationInputError(f"stream {name!r} holds numbers too large for its unit.",
                                    "Check the unit given for it.")
    return np.rint(scaled).astype(np.int64)


def _integers(v, what: str) -> np.ndarray:
    v = np.asarray(v, float)
    if not np.all(v == np.round(v)) or np.any(np.abs(v) >= 2.0**62):
        raise CalibrationInputError(f"{what} holds numbers that are not integers.",
                                    "Give a physical unit for it instead of counts.")
    return v.astype(np.int64)


def _check_names(streams: dict, units: dict) -> None:
    if not streams:
        raise CalibrationInputError("no stream to import.", "Name at least one stream.")
    for name in streams:
        if not re.fullmatch(r"[a-z][a-z0-9_]{0,31}", str(name)) or name == "table":
            raise CalibrationInputError(f"stream name {name!r} is not a lower-case identifier.",
                                        "Use e.g. accel, gyro, acc (not table).")
        if name not in units:
            raise CalibrationInputError(f"no unit given for stream {name!r}.",
                                        f"Give one, e.g. --unit {name}=m/s^2 or counts:m/s^2.")


def _npz_headers(path: Path, max_bytes: int) -> dict:
    """{name: (shape, dtype)} of an .npz from its headers, before anything is inflated
    (`station.imports.npz.headers`)."""
    try:
        return npz.headers(path, max_bytes)
    except CalibrationInputError:
        raise
    except InputError as exc:
        raise CalibrationInputError(f"{exc}.", "Give an array file written by numpy.savez.") \
            from None


def _table_states(t, arrays, angle) -> list:
    """One table state per sample of a position: the commanded rate and the table's angle."""
    rate, c = arrays["rate_cmd"], float(arrays["c_cmd"])
    settle, rotating = arrays["seg_settle"], arrays["seg_rotating"]
    return [TableReading(t[i], rate[i], angle[i], c if rate[i] else 0.0, bool(rate[i]), True,
                         bool(rate[i]), bool(settle[0] <= i < rotating[1]), False)
            for i in range(len(t))]


def _rotary_events(w, j, start, fs, arrays, angle) -> None:
    """Events of position j: window edges half a sample before their first and after their last
    sample (clock = sample number / fs), as the rotary protocol records them."""
    def edge(i):
        return (start + i - 0.5) / fs

    static, rotating = arrays["seg_static"], arrays["seg_rotating"]
    w.event("position_start", j, time=edge(0))
    w.event("static_start", j, time=edge(static[0]))
    w.event("static_end", j, time=edge(static[1]))
    w.event("rotate_start", j, {"angle": float(angle[rotating[0]])}, time=edge(rotating[0]))
    w.event("rotate_end", j, {"angle": float(angle[rotating[1] - 1])}, time=edge(rotating[1]))
    w.event("position_done", j, time=edge(len(arrays["rate_cmd"])))


def _sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
