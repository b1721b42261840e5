"""Flight-controller logs written from the formats' public specifications, for the importers'
tests (tests/test_import_flightlogs.py): independent of the readers (pyulog, pymavlink) they test.

- ULog: docs.px4.io, "ULog File Format": a 16-byte header (magic "ULog" 0x01 0x12 0x35, version,
  start time in us), then messages of a 3-byte header (uint16 size, uint8 type): 'B' flag bits
  (first, version >= 1), 'F' formats ("name:type field;..."), 'I' info, 'A' add-logged
  (multi_id, msg_id, name), 'D' data (msg_id, the fields packed little-endian).
- DataFlash: ArduPilot's log format (libraries/AP_Logger/LogStructure.h): each message 0xA3 0x95
  type; FMT (type 0x80, struct "<BB4s16s64s": type, length with the header, name, format
  characters, column names) defines the others.
"""

import struct

import numpy as np

ULOG_MAGIC = b"ULog\x01\x12\x35"
ULOG_TYPES = {"uint64_t": "<u8", "int64_t": "<i8", "uint32_t": "<u4", "int32_t": "<i4",
              "uint16_t": "<u2", "int16_t": "<i2", "uint8_t": "u1", "int8_t": "i1",
              "float": "<f4", "double": "<f8"}

SENSOR_ACCEL = [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"),
                ("uint32_t", "device_id"), ("float", "x"), ("float", "y"), ("float", "z"),
                ("float", "temperature"), ("uint32_t", "error_count")]
"""PX4 msg/SensorAccel.msg (its leading fields; sensor_gyro has the same)."""

SENSOR_COMBINED = [("uint64_t", "timestamp"), ("float[3]", "gyro_rad"),
                   ("uint32_t", "gyro_integral_dt"),
                   ("int32_t", "accelerometer_timestamp_relative"),
                   ("float[3]", "accelerometer_m_s2"), ("uint32_t", "accelerometer_integral_dt")]
"""PX4 msg/SensorCombined.msg (its leading fields)."""

VEHICLE_IMU = [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"),
               ("uint32_t", "accel_device_id"), ("uint32_t", "gyro_device_id"),
               ("float[3]", "delta_angle"), ("float[3]", "delta_velocity"),
               ("uint16_t", "delta_angle_dt"), ("uint16_t", "delta_velocity_dt")]
"""PX4 msg/VehicleImu.msg (its leading fields)."""


def _dtype(fields) -> np.dtype:
    out = []
    for kind, name in fields:
        base, _, count = kind.partition("[")
        out.append((name, ULOG_TYPES[base], (int(count[:-1]),)) if count else
                   (name, ULOG_TYPES[base]))
    return np.dtype(out)


def _message(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def ulog(topics, start_us: int = 0, in_time_order: bool = True) -> bytes:
    """A ULog file: topics = [(name, fields [(type, field)], multi_id, rows)], rows a structured
    array of `records(fields, ...)` (an empty one: the topic subscribed, nothing logged). Data
    messages in time order across topics, as PX4's logger writes them (else in row order, topic
    by topic within a row: a sensor whose clock jumped)."""
    out = [ULOG_MAGIC, struct.pack("<BQ", 1, start_us),
           _message(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0))]
    defined = set()
    for name, fields, _, _ in topics:
        if name not in defined:
            text = name + ":" + "".join(f"{kind} {field};" for kind, field in fields)
            out.append(_message(b"F", text.encode()))
            defined.add(name)
    key = b"char[7] sys_name"
    out.append(_message(b"I", bytes([len(key)]) + key + b"PX4_SIM"))
    items = []
    for msg_id, (name, fields, multi_id, rows) in enumerate(topics):
        out.append(_message(b"A", struct.pack("<BH", multi_id, msg_id) + name.encode()))
        raw = np.ascontiguousarray(rows, _dtype(fields))
        for i, t in enumerate(raw["timestamp"]):
            items.append((int(t) if in_time_order else i, msg_id,
                          _message(b"D", struct.pack("<H", msg_id) + raw[i:i + 1].tobytes())))
    items.sort(key=lambda item: (item[0], item[1]))
    return b"".join(out + [item[2] for item in items])


def records(fields, **columns) -> np.ndarray:
    """A structured array of ULog rows: each field's column given (arrays (K,) or (K, 3))."""
    k = len(next(iter(columns.values())))
    rows = np.zeros(k, _dtype(fields))
    for name, value in columns.items():
        rows[name] = value
    return rows


DF_STRUCT = {"Q": "Q", "q": "q", "B": "B", "b": "b", "H": "H", "h": "h", "I": "I", "i": "i",
             "f": "f", "d": "d", "n": "4s", "N": "16s", "Z": "64s", "a": "32h"}
"""DataFlash format characters -> Python struct (LogStructure.h's table)."""

IMU_FORMAT = ("QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz")
"""ArduPilot 4.1+ IMU message (instance field I)."""

IMU_FORMAT_OLD = ("QffffffIIfBBHH", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz")
"""ArduPilot before 4.1: IMU, IMU2, IMU3 without an instance field."""

IMU_FORMAT_MS = ("IffffffII", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,ErrG,ErrA")
"""ArduPilot before 3.3 (3.2's LogStructure.h): IMU and IMU2 at TimeMS, milliseconds."""


def df_struct(chars: str) -> struct.Struct:
    return struct.Struct("<" + "".join(DF_STRUCT[c] for c in chars))


def df_fmt(type_id: int, name: str, chars: str, columns: str) -> bytes:
    """The FMT message defining message `type_id`."""
    body = struct.pack("<BB4s16s64s", type_id, 3 + df_struct(chars).size, name.encode(),
                       chars.encode(), columns.encode())
    return bytes([0xA3, 0x95, 0x80]) + body


def df_message(type_id: int, chars: str, values) -> bytes:
    return bytes([0xA3, 0x95, type_id]) + df_struct(chars).pack(*values)


ISBH = (140, "ISBH", "QHBBHHQf", "TimeUS,N,type,instance,mul,smp_cnt,SampleUS,smp_rate")
ISBD = (141, "ISBD", "QHHaaa", "TimeUS,N,seqno,x,y,z")
"""The batch sampler's header and data blocks (libraries/AP_InertialSensor/LogStructure.h)."""


def batch_log(batches, drop=()) -> bytes:
    """A DataFlash log of batch-sampler messages only: batches = [(kind 0 acc | 1 gyro, instance,
    multiplier, sample_us, rate_hz, counts (n, 3) int16)], each an ISBH then its ISBD blocks of 32
    samples per axis (the last one padded with zeros); `drop`: (batch, block) pairs not written."""
    out = [dataflash(None), df_fmt(*ISBH), df_fmt(*ISBD)]
    for number, (kind, instance, mul, sample_us, rate, counts) in enumerate(batches):
        n = len(counts)
        out.append(df_message(ISBH[0], ISBH[2], (sample_us + 500, number, kind, instance, mul, n,
                                                 sample_us, rate)))
        padded = np.zeros((32 * -(-n // 32), 3), np.int16)
        padded[:n] = counts
        for block in range(len(padded) // 32):
            if (number, block) in drop:
                continue
            rows = padded[32 * block:32 * block + 32]
            out.append(df_message(ISBD[0], ISBD[2], (sample_us + 900 + block, number, block,
                                                     *rows[:, 0], *rows[:, 1], *rows[:, 2])))
    return b"".join(out)


def dataflash(imu_rows, *, old: bool = False, params=(), extra=()) -> bytes:
    """A DataFlash log: FMT of FMT, PARM, the IMU message(s) and `extra` formats [(type, name,
    chars, columns, [values...])]; PARM messages for `params` (name, value); then one IMU
    message per row of each instance: imu_rows = {instance: (time_us (K,), gyro (K, 3) rad/s,
    acc (K, 3) m/s^2, temperature)}, in time order."""
    out = [df_fmt(0x80, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"),
           df_fmt(64, "PARM", "QNf", "TimeUS,Name,Value")]
    if old:
        for i in sorted(imu_rows):
            out.append(df_fmt(120 + i, ["IMU", "IMU2", "IMU3"][i], *IMU_FORMAT_OLD))
    elif imu_rows is not None:
        out.append(df_fmt(120, "IMU", *IMU_FORMAT))
    for type_id, name, chars, columns, _ in extra:
        out.append(df_fmt(type_id, name, chars, columns))
    for name, value in params:
        out.append(df_message(64, "QNf", (0, name.encode(), value)))
    for type_id, _, chars, _, rows in extra:
        out += [df_message(type_id, chars, row) for row in rows]
    items = []
    for i, (t, gyro, acc, temp) in (imu_rows or {}).items():
        for k in range(len(t)):
            tail = (0, 0, temp, 1, 1, 400, 400)
            if old:
                items.append((t[k], i, df_message(120 + i, IMU_FORMAT_OLD[0],
                                                  (t[k], *gyro[k], *acc[k], *tail))))
            else:
                items.append((t[k], i, df_message(120, IMU_FORMAT[0],
                                                  (t[k], i, *gyro[k], *acc[k], *tail))))
    items.sort(key=lambda item: (item[0], item[1]))
    return b"".join(out + [item[2] for item in items])
