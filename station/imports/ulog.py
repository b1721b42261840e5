"""A PX4 ULog file's IMU samples into a session (`station import ulog`), read with pyulog.

Format: docs.px4.io, "ULog File Format" (header, definitions: format, info, parameter and
add-logged messages; data messages of a topic instance, `multi_id`). Topic families (PX4's uORB
message definitions, msg/*.msg):

- `sensor_accel` and `sensor_gyro`: the raw sensors, one instance per chip; `x, y, z` in m/s^2
  and rad/s, time `timestamp_sample` (else `timestamp`), microseconds; `device_id` and
  `temperature` kept in the metadata (`import.origin`);
- `sensor_combined`: the primary IMU as the estimator sees it (PX4's default logging profile);
  `gyro_rad[3]` at `timestamp`, `accelerometer_m_s2[3]` at `timestamp` +
  `accelerometer_timestamp_relative` (samples marked invalid, INT32_MAX, left out);
- `vehicle_imu`: integrated `delta_angle[3]` / `delta_velocity[3]` over `delta_angle_dt` /
  `delta_velocity_dt` (microseconds), divided into rates (not exact: rounded, said in the notes);
  samples with a zero interval left out.

A family instance is a candidate when each of its topics holds at least 2 samples at that
`multi_id`. The importer takes the candidate of the highest sample rate (its topics' slowest
median step): PX4's default profile logs `sensor_accel`/`sensor_gyro` at about 1 Hz beside
`sensor_combined` at 200-250 Hz, and a 1 Hz recording calibrates nothing. Rates within
RATE_TIE of each other count as equal, and the family listed first above wins (the raw sensors:
exact values, device ids; vehicle_imu last: divided rates), then the lowest instance.
`--topic NAME` (any topic of a family) and `--instance N` narrow the choice; the candidates with
their samples and rates are said in the notes. A choice nothing matches is refused listing the
topics and instances the log holds. The samples go through station.imports.flightlog (checks,
exact scaling, the session).
"""

import contextlib
import io
import mmap
from dataclasses import dataclass
from importlib.metadata import version
from pathlib import Path

import numpy as np

from station.errors import CalibrationInputError
from station.imports.flightlog import Series, summary, write_session
from station.imports.tables import MAX_BYTES

FAMILIES = (("sensor_accel", "sensor_gyro"), ("sensor_combined",), ("vehicle_imu",))
"""IMU topic families, the preferred first at equal rates."""

TOPICS = tuple(t for family in FAMILIES for t in family)

RATE_TIE = 0.1
"""Candidates whose rates differ by less than this fraction count as equally fast."""

INVALID_RELATIVE = 2**31 - 1
"""sensor_combined.accelerometer_timestamp_relative of a sample without an accelerometer part."""

FIX = ("Log the IMU topics (PX4 logs sensor_combined by default; sensor_accel and sensor_gyro "
       "with SDLOG_PROFILE 'sensor comparison' or 'raw sensors'), or give the .ulg of the flight "
       "controller.")


def import_ulog(out, path, *, instance: int | None = None, topic: str | None = None,
                unit_serial: str = "IMPORTED") -> Path:
    """Import the accelerometer and gyro of a ULog file into a new session `out` (streams acc,
    gyro; the family and instance: the fastest candidate, or `topic` and `instance`; see the
    module docstring)."""
    path = Path(path)
    if topic is not None and topic not in TOPICS:
        raise CalibrationInputError(f"--topic {topic!r} is not an IMU topic the importer reads.",
                                    f"Give one of {', '.join(TOPICS)}.")
    ulog, notes = read(path)
    datasets = {(d.name, d.multi_id): d for d in ulog.data_list}
    family, chosen = _choose(path, ulog, datasets, instance, topic, notes)
    pick = {name: datasets[(name, chosen)] for name in family}
    series = (_raw(pick) if family == FAMILIES[0] else
              _combined(pick["sensor_combined"], notes, path) if family == FAMILIES[1] else
              _integrated(pick["vehicle_imu"], notes, path))
    return write_session(out, path, "ulog", series, f"pyulog {version('pyulog')}", notes,
                         unit_serial=unit_serial)


def read(path: Path) -> tuple:
    """(pyulog.ULog of the IMU topics, notes): the library's errors and printed complaints
    turned into a CalibrationInputError or a note; a cut or damaged log noted."""
    from pyulog import ULog

    size = path.stat().st_size
    if size > MAX_BYTES:
        raise CalibrationInputError(f"{path} holds {size} bytes, more than {MAX_BYTES}.",
                                    "Split the log (pyulog's ulog2csv) and import a part.")
    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            ulog = ULog(str(path), message_name_filter_list=list(TOPICS))
    except Exception as exc:  # pyulog raises what its parsing meets (struct, KeyError, ...)
        raise CalibrationInputError(
            f"{path} is not a ULog file pyulog can read ({type(exc).__name__}: {exc}).",
            "Give the .ulg file the flight controller wrote (docs.px4.io 'ULog File Format'); a "
            "log cut in its header cannot be read.") from None
    notes = [f"{path.name}: pyulog says: {line}" for line in said.getvalue().splitlines()
             if line.strip()][:5]
    if ulog.file_corruption:
        notes.append(f"{path.name}: the log is damaged (pyulog's file_corruption); the samples "
                     "pyulog could read are used")
    elif cut := _cut_bytes(path):
        notes.append(f"{path.name}: the log ends inside a message ({cut} bytes after the last "
                     "whole one left out; a log cut by a power loss)")
    return ulog, notes


def _cut_bytes(path: Path) -> int:
    """Bytes after the last whole message of a ULog file: its messages (after the 16-byte
    header) walked by their 3-byte headers (uint16 size, uint8 type; docs.px4.io "ULog File
    Format"); 0 when the file ends on a message's end."""
    with path.open("rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
        at = 16
        while at + 3 <= len(data):
            end = at + 3 + int.from_bytes(data[at:at + 2], "little")
            if end > len(data):
                break
            at = end
        return len(data) - at


@dataclass(frozen=True)
class Candidate:
    """A topic family at one instance with samples in every topic: the fewest samples and the
    lowest rate (Hz, from the median time stamp step) over its topics."""

    family: tuple
    instance: int
    samples: int
    rate_hz: float

    def __str__(self) -> str:
        return (f"{'+'.join(self.family)} instance {self.instance}: {self.samples} samples at "
                f"{self.rate_hz:.4g} Hz")


def candidates(datasets: dict) -> list:
    """Every `Candidate` of the log's data (`{(topic, multi_id): pyulog data}`), in FAMILIES
    order, then by instance."""
    out = []
    for family in FAMILIES:
        shared = set.intersection(*({i for (n, i) in datasets if n == name} for name in family))
        for i in sorted(shared):
            times = [_field(datasets[(name, i)], "timestamp").astype(float) for name in family]
            if min(len(t) for t in times) < 2:
                continue
            steps = [float(np.median(np.diff(t))) for t in times]
            rate = min(1e6 / step if step > 0 else 0.0 for step in steps)
            out.append(Candidate(family, i, min(len(t) for t in times), rate))
    return out


def _choose(path, ulog, datasets: dict, instance, topic, notes: list) -> tuple:
    """(topics, instance) to import: the fastest `candidates` (ties: the earlier family, the
    lower instance) among those of `topic`'s family and `instance` when given; the candidates
    and the choice said in `notes`; refused listing what the log holds when none fits."""
    found = candidates(datasets)
    fits = [c for c in found if (topic is None or topic in c.family)
            and (instance is None or c.instance == instance)]
    if not fits:
        asked = " and ".join(filter(None, (topic and f"topic {topic}",
                                            instance is not None and f"instance {instance}")))
        if not found:
            raise CalibrationInputError(
                f"{path} holds no IMU samples ({_holdings(ulog, datasets)}).", FIX)
        raise CalibrationInputError(
            f"{path}: no IMU candidate with {asked} (candidates: "
            f"{'; '.join(map(str, found))}; the log holds {_holdings(ulog, datasets)}).",
            "Give --topic and --instance of one of the candidates listed.")
    fastest = max(c.rate_hz for c in fits)
    best = next(c for c in fits if c.rate_hz >= (1 - RATE_TIE) * fastest)
    why = "the only one left" if len(fits) == 1 else "the highest rate"
    notes.append(f"{path.name}: IMU candidates: {'; '.join(map(str, found))}; chosen "
                 f"{'+'.join(best.family)} instance {best.instance} ({why}; --topic and "
                 "--instance choose another)")
    return best.family, best.instance


def _holdings(ulog, datasets: dict) -> str:
    """What the log holds of the IMU topics: samples per topic instance, topics defined empty."""
    held = [f"{n} instance {i}: {len(next(iter(d.data.values()), ()))} samples"
            for (n, i), d in sorted(datasets.items())]
    empty = sorted(set(TOPICS) & set(ulog.message_formats) - {n for n, _ in datasets})
    held += [f"{n}: no samples" for n in empty]
    return "; ".join(held) or "none of " + ", ".join(TOPICS)


def _raw(pick: dict) -> dict:
    """Series acc and gyro of topics sensor_accel and sensor_gyro."""
    out = {}
    for name, topic, unit in (("acc", "sensor_accel", "m/s^2"), ("gyro", "sensor_gyro", "rad/s")):
        d = pick[topic]
        time = "timestamp_sample" if "timestamp_sample" in d.data else "timestamp"
        origin = {"topic": topic, "instance": d.multi_id, "time": time}
        if "device_id" in d.data:
            ids = sorted({int(i) for i in _field(d, "device_id")})
            origin["device_id"] = ids[0] if len(ids) == 1 else ids
        if "temperature" in d.data:
            origin["temperature"] = summary(_field(d, "temperature"))
        out[name] = Series(_field(d, time), _columns(d, ("x", "y", "z")), unit,
                           f"topic {topic} instance {d.multi_id}", origin)
    return out


def _combined(d, notes: list, path) -> dict:
    """Series gyro (at timestamp) and acc (at timestamp + relative) of sensor_combined."""
    t = _field(d, "timestamp").astype(np.int64)
    relative = _field(d, "accelerometer_timestamp_relative").astype(np.int64)
    valid = relative != INVALID_RELATIVE
    if not valid.all():
        notes.append(f"{path.name}: sensor_combined: {int((~valid).sum())} samples without an "
                     "accelerometer part (relative time stamp invalid) left out of acc")
    where = f"topic sensor_combined instance {d.multi_id}"
    origin = {"topic": "sensor_combined", "instance": d.multi_id}
    return {"acc": Series((t + relative)[valid], _columns(d, _array("accelerometer_m_s2"))[valid],
                          "m/s^2", where, {**origin, "time": "timestamp + "
                                           "accelerometer_timestamp_relative"}),
            "gyro": Series(t, _columns(d, _array("gyro_rad")), "rad/s", where,
                           {**origin, "time": "timestamp"})}


def _integrated(d, notes: list, path) -> dict:
    """Series acc and gyro of vehicle_imu: the integrated deltas over their intervals."""
    t = _field(d, "timestamp_sample" if "timestamp_sample" in d.data else "timestamp")
    where = f"topic vehicle_imu instance {d.multi_id}"
    out = {}
    for name, delta, dt, unit, device in (
            ("acc", "delta_velocity", "delta_velocity_dt", "m/s^2", "accel_device_id"),
            ("gyro", "delta_angle", "delta_angle_dt", "rad/s", "gyro_device_id")):
        seconds = _field(d, dt).astype(float) * 1e-6
        valid = seconds > 0
        if not valid.all():
            notes.append(f"{path.name}: vehicle_imu: {int((~valid).sum())} samples with "
                         f"{dt} = 0 left out of {name}")
        origin = {"topic": "vehicle_imu", "instance": d.multi_id, "integrated": delta}
        if device in d.data:
            origin["device_id"] = int(_field(d, device)[0])
        out[name] = Series(t[valid], _columns(d, _array(delta))[valid] / seconds[valid, None],
                           unit, where, origin)
    return out


def _array(name: str) -> tuple:
    return tuple(f"{name}[{i}]" for i in range(3))


def _columns(d, fields) -> np.ndarray:
    """(K, 3) float64 of three numeric fields of a topic."""
    with np.errstate(invalid="ignore"):  # a signalling NaN of a damaged log: refused later
        return np.column_stack([_field(d, f).astype(float) for f in fields])


def _field(d, name: str) -> np.ndarray:
    """A numeric field of a topic instance, refused by name when missing or not numeric."""
    values = d.data.get(name)
    if values is None or values.dtype.kind not in "iuf":
        what = "no" if values is None else "a non-numeric"
        raise CalibrationInputError(
            f"topic {d.name} instance {d.multi_id} has {what} field {name!r} (fields: "
            f"{', '.join(list(d.data)[:20])}).",
            "The log's message definitions differ from PX4's: " + FIX)
    return values
