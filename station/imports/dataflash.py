"""An ArduPilot DataFlash `.bin` log's IMU samples into a session (`station import dataflash`), read
with pymavlink's DFReader_binary.

Format: ArduPilot's "Log file format" documentation (ardupilot.org, dev docs, and
libraries/AP_Logger/LogStructure.h): every message starts with 0xA3 0x95 and its type; FMT
messages (type 0x80) define the others (name, struct characters, column names). The IMU
messages (libraries/AP_InertialSensor/LogStructure.h) carry `TimeUS` (microseconds since boot;
`TimeMS`, milliseconds, before ArduPilot 3.3), `GyrX/Y/Z` (rad/s), `AccX/Y/Z` (m/s^2) and `T`
(deg C, when logged): one message `IMU` with an instance field `I` (ArduPilot 4.1 on), or `IMU`,
`IMU2`, `IMU3` for instances 0, 1, 2 (earlier logs). The
instance is `--instance N` (default the first); a wrong one, or a log without IMU messages (a
board that logged none, another vehicle's log), is refused listing the messages it holds.
The accelerometer's and gyro's device ids come from the parameters INS_ACC_ID, INS_ACC2_ID, ...,
INS_GYR_ID, ... when the log holds them. With `batch`, the batch sampler's raw-rate samples
(ISBH/ISBD, `batch_series`) instead of the IMU messages. The samples go through
station.imports.flightlog.
"""

import contextlib
import io
from importlib.metadata import version
from pathlib import Path

import numpy as np

from station.errors import CalibrationInputError
from station.imports.flightlog import Series, summary, write_session
from station.imports.tables import MAX_BYTES

IMU_MESSAGES = {"IMU": 0, "IMU2": 1, "IMU3": 2}
"""IMU message names and the instance each stands for when it has no `I` field."""

TIME_FIELDS = {"TimeUS": 1, "TimeMS": 1000}
"""Time fields of the IMU messages -> microseconds per count (TimeMS: before ArduPilot 3.3)."""

FIELDS = {"acc": (("AccX", "AccY", "AccZ"), "m/s^2", "ACC"),
          "gyro": (("GyrX", "GyrY", "GyrZ"), "rad/s", "GYR")}
"""Stream -> (IMU message fields, SI unit, INS_<x>_ID parameter stem)."""

NUMERIC = set("bBhHiIqQfda")
"""DataFlash format characters of plain numbers (no multiplier; `a`: int16[32]; LogStructure.h)."""

FIX = ("Give the .bin log of a flight controller that logged its IMU (LOG_BITMASK bit IMU, "
       "or IMU_RAW); a text .log or tlog is not a DataFlash .bin.")


def import_dataflash(out, path, *, instance: int | None = None, batch: bool = False,
                     unit_serial: str = "IMPORTED") -> Path:
    """Import the accelerometer and gyro of one IMU instance of a DataFlash log into a new
    session `out` (streams acc, gyro on the IMU messages' TimeUS or TimeMS; `batch`: the batch
    sampler's raw-rate samples instead, `batch_series`)."""
    path = Path(path)
    reader, notes = _open(path)
    if batch:
        return write_session(out, path, "dataflash", batch_series(reader, path, instance, notes),
                             f"pymavlink {version('pymavlink')}", notes, unit_serial=unit_serial)
    rows = _imu_rows(reader, path, notes)
    chosen = _instance(path, reader, rows, instance)
    name, table = rows[chosen]
    notes.append(f"{path.name}: IMU instance {chosen}: {len(table['time_us'])} messages {name}"
                 + ("" if table["time"] == "TimeUS" else
                    f" (time {table['time']}: milliseconds, as ArduPilot logged before 3.3)"))
    params = _params(reader, path, notes)
    series = {}
    for stream, (fields, unit, stem) in FIELDS.items():
        origin = {"message": name, "instance": chosen, "time": table["time"]}
        device = params.get(f"INS_{stem}{chosen + 1 if chosen else ''}_ID")
        if device is not None:
            origin["device_id"] = int(device)
        if "T" in table and np.isfinite(table["T"]).any():
            origin["temperature"] = summary(table["T"])
        series[stream] = Series(table["time_us"],
                                np.column_stack([table[f] for f in fields]), unit,
                                f"message {name} instance {chosen}", origin)
    return write_session(out, path, "dataflash", series, f"pymavlink {version('pymavlink')}",
                         notes, unit_serial=unit_serial)


def batch_series(reader, path: Path, instance, notes: list) -> dict:
    """Series acc and gyro of the batch sampler (INS_LOG_BAT_*: raw samples at the sensor's
    rate, in batches with gaps between them): each ISBH header (`type` 0 accelerometer, 1 gyro,
    `instance`, `mul` counts per SI unit, `smp_cnt` samples from `SampleUS` at `smp_rate` Hz)
    followed by its ISBD blocks (`seqno` 0, 1, ... of 32 int16 samples per axis), as pymavlink's
    tools/mavfft_isb.py reads them. A batch with a missing block or cut short is left out and
    counted; the counts are kept with `mul` as their scale."""
    for name in ("ISBH", "ISBD"):
        if name not in reader.name_to_id:
            raise CalibrationInputError(
                f"{path} holds no {name} messages (the batch sampler's).",
                "Log them (INS_LOG_BAT_MASK, LOG_BITMASK bit IMU_RAW), or import the IMU "
                "messages: leave out --batch.")
    heads, head_at = _messages(reader, path, "ISBH", ("N", "type", "instance", "mul", "smp_cnt",
                                                     "SampleUS", "smp_rate"))
    blocks, block_at = _messages(reader, path, "ISBD", ("N", "seqno", "x", "y", "z"))
    present = sorted({int(i) for i in heads["instance"]})
    chosen = present[0] if instance is None and present else instance
    if chosen not in present:
        raise CalibrationInputError(f"{path}: no batch sampler instance {instance} (instances: "
                                    f"{', '.join(map(str, present)) or 'none'}).",
                                    "Give --instance N with one of the instances listed, or "
                                    "import the IMU messages: leave out --batch.")
    owner = np.searchsorted(head_at, block_at) - 1  # the header each block follows
    owner[(owner < 0) | (heads["N"][np.maximum(owner, 0)] != blocks["N"])] = -1
    out = {}
    for kind, (name, unit) in enumerate((("acc", "m/s^2"), ("gyro", "rad/s"))):
        mine = np.flatnonzero((heads["type"] == kind) & (heads["instance"] == chosen))
        times, counts, scales, left = [], [], set(), 0
        for j in mine:
            h = heads[j]
            part = blocks[owner == j]
            part = part[np.argsort(part["seqno"], kind="stable")]
            n, rate = int(h["smp_cnt"]), float(h["smp_rate"])
            if not (np.array_equal(part["seqno"], np.arange(len(part))) and 32 * len(part) >= n
                    and n > 0 and rate > 0 and h["mul"] > 0):
                left += 1
                continue
            counts.append(np.stack([part["x"], part["y"], part["z"]], -1).reshape(-1, 3)[:n])
            times.append(float(h["SampleUS"]) + np.arange(n) * 1e6 / rate)
            scales.add(float(h["mul"]))
        if left:
            notes.append(f"{path.name}: batch sampler {name} instance {chosen}: {left} of "
                         f"{len(mine)} batches left out (a block missing, or cut short)")
        if len(scales) > 1:
            raise CalibrationInputError(f"{path}: the {name} batches of instance {chosen} change "
                                        f"their multiplier ({sorted(scales)}).",
                                        "Import the IMU messages (leave out --batch).")
        where = f"batch sampler {name} instance {chosen}"
        out[name] = Series(np.concatenate(times or [np.empty(0)]),
                           np.concatenate(counts or [np.empty((0, 3))]), unit, where,
                           {"message": "ISBH/ISBD", "instance": chosen, "batches": len(counts),
                            "time": "SampleUS + i / smp_rate"},
                           scale=scales.pop() if scales else 1.0)
    return out


def _open(path: Path) -> tuple:
    """(DFReader_binary without its clock search, notes): the reader's exceptions turned into a
    CalibrationInputError, what it prints (skipped bytes, parse failures) into notes."""
    from pymavlink.DFReader import DFReader_binary

    class DFReaderTimeUS(DFReader_binary):
        """pymavlink's reader without the search for a GPS time base (in a log without a GPS
        week, a bench log, it parses every message of the log in Python: 25 s per million;
        the importer takes the IMU messages' own TimeUS), indexing in Python."""

        def init_clock(self):
            self.clock = None

        def init_arrays_fast(self, progress_callback=None):
            """The pure-Python indexer (0.3 s per million messages): the Cython one prints its
            complaints about damaged bytes on the process's stderr, past redirect_stderr."""
            self.init_arrays(progress_callback)

    size = path.stat().st_size
    if size > MAX_BYTES or size < 3:
        raise CalibrationInputError(f"{path} holds {size} bytes (a DataFlash log of 3 to "
                                    f"{MAX_BYTES} bytes expected).", FIX)
    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            reader = DFReaderTimeUS(str(path), zero_time_base=True)
    except Exception as exc:  # the reader raises what its parsing meets
        raise CalibrationInputError(
            f"{path} is not a DataFlash log pymavlink can read ({type(exc).__name__}: {exc}).",
            FIX) from None
    return reader, _said(path, said)


def _imu_rows(reader, path: Path, notes: list) -> dict:
    """{instance: (message name, {field: (K,) float64, "time_us": (K,) time stamps in us, "time":
    the time field's name})} of the log's IMU messages, in log order:
    the reader's index of each message type (its offsets) read as numpy records of the struct
    its FMT defines (`_record`; DFReader decodes message by message, 100x slower); a message cut
    by the end of the file left out and noted."""
    out, end = {}, _end_of_messages(reader)
    for name in (n for n in IMU_MESSAGES if n in reader.name_to_id):
        fmt = reader.formats[reader.name_to_id[name]]
        time = next((f for f in TIME_FIELDS if f in fmt.colhash), "TimeUS")
        wanted = [time, *FIELDS["acc"][0], *FIELDS["gyro"][0],
                  *[f for f in ("I", "T") if f in fmt.colhash]]
        rows, _ = _messages(reader, path, name, wanted)
        with np.errstate(invalid="ignore"):  # a signalling NaN of a damaged log: refused later
            table = {f: rows[f].astype(float) for f in wanted}
        table["time_us"] = table.pop(time) * TIME_FIELDS[time]
        instances = _instances(path, name, table["I"]) if "I" in table else \
            np.full(len(rows), IMU_MESSAGES[name])
        for i in np.unique(instances):
            out[int(i)] = (name, {"time": time,
                                  **{f: v[instances == i] for f, v in table.items()}})
    if end < reader.data_len:
        notes.append(f"{path.name}: the log ends inside a message ({reader.data_len - end} "
                     "bytes after the last whole one left out; a log cut by a power loss)")
    return out


def _messages(reader, path: Path, name: str, fields) -> tuple:
    """(records (K,), file offsets (K,)) of every whole message `name` of the log, in log order:
    the reader's index of the type read as numpy records of the struct its FMT defines; refused
    unless each of `fields` is a plain number (or `a`, int16[32]) there."""
    fmt = reader.formats[reader.name_to_id[name]]
    record = _record(path, fmt)  # first: its columns and format characters match
    missing = [f for f in fields if f not in fmt.colhash or
               fmt.msg_fmts[fmt.colhash[f]] not in NUMERIC or
               fmt.msg_mults[fmt.colhash[f]] is not None]
    if missing:
        raise CalibrationInputError(
            f"{path}: message {name} has no numeric {', '.join(missing)} (its FMT says "
            f"{fmt.format!r}: {','.join(fmt.columns)}).", f"The log's {name} message is not "
            "ArduPilot's: " + FIX)
    offsets = [o for o in reader.offsets[fmt.type] if o + fmt.len <= reader.data_len]
    data = reader.data_map
    return (np.frombuffer(b"".join(data[o + 3:o + fmt.len] for o in offsets), record),
            np.array(offsets, np.int64))


def _record(path: Path, fmt) -> np.dtype:
    """The packed little-endian numpy record of a message type: its FMT's columns and format
    characters, each of the struct code pymavlink's FORMAT_TO_STRUCT gives it (`a`: int16[32])."""
    from pymavlink.DFReader import FORMAT_TO_STRUCT

    def code(char):
        text = FORMAT_TO_STRUCT[char][0]
        return ("<i2", (32,)) if char == "a" else \
            (f"V{text[:-1]}",) if text.endswith("s") else ("<" + text,)

    try:
        record = np.dtype([(column, *code(char))
                           for column, char in zip(fmt.columns, fmt.msg_fmts, strict=True)])
    except (KeyError, ValueError, TypeError) as exc:
        raise CalibrationInputError(f"{path}: the FMT of message {fmt.name} is not one numpy "
                                    f"can lay out ({exc}).", FIX) from None
    if record.itemsize != fmt.len - 3:
        raise CalibrationInputError(f"{path}: message {fmt.name}'s FMT says {fmt.len} bytes, its "
                                    f"format {fmt.format!r} {record.itemsize + 3}.", FIX)
    return record


def _instances(path: Path, name: str, field: np.ndarray) -> np.ndarray:
    """The instance numbers of an `I` field, refused unless each is an integer 0..255."""
    bad = ~np.isfinite(field) | (field != np.round(field)) | (field < 0) | (field > 255)
    if bad.any():
        raise CalibrationInputError(f"{path}: {int(bad.sum())} {name} messages have an instance "
                                    "field I that is no instance number (a damaged log?).", FIX)
    return field.astype(int)


def _end_of_messages(reader) -> int:
    """The file offset after the last whole message the reader's index holds."""
    ends = [o + reader.formats[t].len for t, offsets in enumerate(reader.offsets)
            if t in reader.formats for o in offsets[-1:]]
    return max([e for e in ends if e <= reader.data_len], default=0)


def _params(reader, path: Path, notes: list) -> dict:
    """The log's parameters (PARM messages), read through the reader; none when it cannot (said
    in `notes`: the device ids are then left out)."""
    if "PARM" not in reader.name_to_id:
        return {}
    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            while reader.recv_match(type="PARM") is not None:
                pass
    except Exception as exc:  # the reader raises what its parsing meets
        notes.append(f"{path.name}: the parameters (PARM) are unreadable ({type(exc).__name__}: "
                     f"{exc}); no device ids")
        return {}
    return {k: v for k, v in reader.params.items() if isinstance(v, (int, float))}


def _instance(path: Path, reader, rows: dict, instance) -> int:
    """The instance to import: `instance`, or the first; refused listing what the log holds."""
    if rows and (instance is None or instance in rows):
        return min(rows) if instance is None else instance
    held = ", ".join(f"instance {i}: {len(table['time_us'])} messages"
                     for i, (_, table) in sorted(rows.items()))
    if held:
        raise CalibrationInputError(f"{path}: no IMU instance {instance} ({held}).",
                                    "Give --instance N with one of the instances listed.")
    counts = {reader.id_to_name[i]: c for i, c in enumerate(reader.counts)
              if c > 0 and i in reader.id_to_name}
    listed = ", ".join(f"{n} {c}" for n, c in sorted(counts.items(), key=lambda x: -x[1])[:15])
    defined = [n for n in IMU_MESSAGES if n in reader.name_to_id]
    empty = f"defined but empty: {', '.join(defined)}; " if defined else ""
    raise CalibrationInputError(f"{path} holds no IMU messages ({empty}messages: "
                                f"{listed or 'none'}).", FIX)


def _said(path: Path, said: io.StringIO) -> list:
    """What the reader printed, as (at most 5) notes."""
    return [f"{path.name}: pymavlink says: {line}" for line in said.getvalue().splitlines()
            if line.strip()][:5]
