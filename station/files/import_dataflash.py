"""An ArduPilot DataFlash `.bin` log's IMU samples into a session (`station import dataflash`), read
with pymavlink's DFReader_binary.

Format: ArduPilot's "Log file format" documentation (ardupilot.org, dev docs, and
libraries/AP_Logger/LogStructure.h): every message starts with 0xA3 0x95 and its type; FMT
messages (type 0x80) define the others (name, struct characters, column names). The IMU
messages (libraries/AP_InertialSensor/LogStructure.h) carry `TimeUS` (microseconds since boot),
`GyrX/Y/Z` (rad/s), `AccX/Y/Z` (m/s^2) and `T` (deg C): one message `IMU` with an instance field
`I` (ArduPilot 4.1 on), or `IMU`, `IMU2`, `IMU3` for instances 0, 1, 2 (earlier logs). The
instance is `--instance N` (default the first); a wrong one, or a log without IMU messages (a
board that logged none, another vehicle's log), is refused listing the messages it holds.
The accelerometer's and gyro's device ids come from the parameters INS_ACC_ID, INS_ACC2_ID, ...,
INS_GYR_ID, ... when the log holds them. The samples go through station.files.flightlog.
"""

import contextlib
import io
from importlib.metadata import version
from pathlib import Path

import numpy as np

from station.errors import CalibrationInputError
from station.files.flightlog import Series, write_session
from station.files.tables import MAX_BYTES

IMU_MESSAGES = {"IMU": 0, "IMU2": 1, "IMU3": 2}
"""IMU message names and the instance each stands for when it has no `I` field."""

FIELDS = {"acc": (("AccX", "AccY", "AccZ"), "m/s^2", "ACC"),
          "gyro": (("GyrX", "GyrY", "GyrZ"), "rad/s", "GYR")}
"""Stream -> (IMU message fields, SI unit, INS_<x>_ID parameter stem)."""

FIX = ("Give the .bin log of a flight controller that logged its IMU (LOG_BITMASK bit IMU, "
       "or IMU_RAW); a text .log or tlog is not a DataFlash .bin.")


def import_dataflash(out, path, *, instance: int | None = None,
                     unit_serial: str = "IMPORTED") -> Path:
    """Import the accelerometer and gyro of one IMU instance of a DataFlash log into a new
    session `out` (streams acc, gyro on the IMU messages' TimeUS)."""
    path = Path(path)
    reader, notes = _open(path)
    rows, params = _imu_rows(reader, path, notes)
    chosen = _instance(path, reader, rows, instance)
    notes.append(f"{path.name}: IMU instance {chosen}: {len(rows[chosen])} messages")
    msgs = rows[chosen]
    t = np.array([m[0] for m in msgs], np.int64)
    series = {}
    for name, (fields, unit, stem) in FIELDS.items():
        origin = {"message": msgs[0][1], "instance": chosen, "time": "TimeUS"}
        device = params.get(f"INS_{stem}{chosen + 1 if chosen else ''}_ID")
        if device is not None:
            origin["device_id"] = int(device)
        temperature = np.array([m[2].get("T", np.nan) for m in msgs], float)
        if np.isfinite(temperature).any():
            origin["temperature"] = {"first": float(temperature[0]),
                                     "min": float(np.nanmin(temperature)),
                                     "mean": float(np.nanmean(temperature)),
                                     "max": float(np.nanmax(temperature))}
        values = np.array([[m[2][f] for f in fields] for m in msgs], float)
        series[name] = Series(t, values, unit, f"message {msgs[0][1]} instance {chosen}", origin)
    return write_session(out, path, "dataflash", series, f"pymavlink {version('pymavlink')}",
                         notes, unit_serial=unit_serial)


def _open(path: Path) -> tuple:
    """(DFReader_binary, notes): the reader's exceptions turned into a CalibrationInputError,
    what it prints (skipped bytes, parse failures) into notes."""
    from pymavlink.DFReader import DFReader_binary

    size = path.stat().st_size
    if size > MAX_BYTES or size < 3:
        raise CalibrationInputError(f"{path} holds {size} bytes (a DataFlash log of 3 to "
                                    f"{MAX_BYTES} bytes expected).", FIX)
    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            reader = DFReader_binary(str(path), zero_time_base=True)
    except Exception as exc:  # the reader raises what its parsing meets
        raise CalibrationInputError(
            f"{path} is not a DataFlash log pymavlink can read ({type(exc).__name__}: {exc}).",
            FIX) from None
    return reader, _said(path, said)


def _imu_rows(reader, path: Path, notes: list) -> tuple:
    """({instance: [(TimeUS, message name, {field: value})]}, parameters) of the log's IMU
    messages, in log order."""
    rows, names = {}, [n for n in IMU_MESSAGES if n in reader.name_to_id]
    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            while (m := reader.recv_match(type=[*names, "PARM"])) is not None:
                name = m.get_type()
                if name == "PARM":
                    continue
                values = m.to_dict()
                missing = [f for f in ("TimeUS", *FIELDS["acc"][0], *FIELDS["gyro"][0])
                           if not isinstance(values.get(f), (int, float))]
                if missing:
                    raise CalibrationInputError(
                        f"{path}: message {name} has no numeric {', '.join(missing)} (its FMT "
                        f"says {reader.formats[reader.name_to_id[name]].format}).",
                        "The log's IMU message is not ArduPilot's: " + FIX)
                i = int(values["I"]) if "I" in values else IMU_MESSAGES[name]
                rows.setdefault(i, []).append((int(values["TimeUS"]), name, values))
    except CalibrationInputError:
        raise
    except Exception as exc:
        raise CalibrationInputError(f"{path}: pymavlink fails reading the IMU messages "
                                    f"({type(exc).__name__}: {exc}).", FIX) from None
    notes += _said(path, said)
    if (left := reader.data_len - reader.offset) > 0:
        notes.append(f"{path.name}: the log ends inside a message ({left} bytes after the last "
                     "whole one left out; a log cut by a power loss)")
    return rows, dict(reader.params)


def _instance(path: Path, reader, rows: dict, instance) -> int:
    """The instance to import: `instance`, or the first; refused listing what the log holds."""
    if rows and (instance is None or instance in rows):
        return min(rows) if instance is None else instance
    held = ", ".join(f"instance {i}: {len(r)} messages" for i, r in sorted(rows.items()))
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
