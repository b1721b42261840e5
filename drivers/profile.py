"""Device profiles: one TOML file per device model, read with the stdlib `tomllib`.

A profile is a set of sections (`[imu]`, `[serial]`, `[can]`, `[table]`, ...). This module has the
generic part - `load_profile` and `Section`, a checked view of one table whose errors name the file,
the key and the fix - and the sections of serial IMUs: `ImuSection` (`[imu]`: channels, SI units,
scale) and `SerialSection` (`[serial]` with `[serial.binary]` or `[serial.ascii]`).

Another device adds its section as a dataclass with a `parse(section: Section)` classmethod and
reads it with `profile.section("name", TheSection.parse)`.
"""

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.errors import ProfileError
from drivers.wire.binary import INT_TYPES
from drivers.wire.crc import CHECKSUMS

BUNDLED = Path(__file__).parent / "profiles"
_REQUIRED = object()


class Section:
    """One table of a profile, read key by key with type checks; `finish()` rejects unknown keys
    (usually typos)."""

    def __init__(self, source: str, name: str, table: dict):
        self.source, self.name, self.table = source, name, table
        self._read = set()

    def error(self, key: str, problem: str) -> ProfileError:
        """An error about `key` of this section, naming the file."""
        return ProfileError(f"{self.source}: [{self.name}] {key}: {problem}")

    def has(self, key: str) -> bool:
        return key in self.table

    def get(self, key: str, kind: type, default=_REQUIRED, choices=None):
        """The value of `key`, of type `kind` (str, int, float or bool; an int is a valid float)."""
        self._read.add(key)
        if key not in self.table:
            if default is _REQUIRED:
                raise self.error(key, f"missing; add `{key} = <{kind.__name__}>` to the section")
            return default
        value = self.table[key]
        if not _is(value, kind):
            raise self.error(key, f"must be {kind.__name__}, got {value!r}")
        if choices is not None and value not in choices:
            raise self.error(key, f"must be one of {', '.join(map(repr, choices))}; got {value!r}")
        return float(value) if kind is float else value

    def get_list(self, key: str, kind: type, length=None, default=_REQUIRED) -> tuple:
        """The list value of `key` with items of type `kind`; a single value is repeated
        `length` times when `length` is given."""
        self._read.add(key)
        value = self.table.get(key, default)
        if value is _REQUIRED:
            raise self.error(key, f"missing; add `{key} = [...]` to the section")
        if length is not None and _is(value, kind):
            value = [value] * length
        if not isinstance(value, list) or not all(_is(v, kind) for v in value):
            raise self.error(key, f"must be a list of {kind.__name__}, got {value!r}")
        if length is not None and len(value) != length:
            raise self.error(key, f"has {len(value)} entries; give one per channel ({length}) "
                                  "or a single value for all")
        return tuple(float(v) if kind is float else v for v in value)

    def get_rows(self, key: str, rows: int, columns: int, default=_REQUIRED) -> tuple:
        """The matrix value of `key`: `rows` lists of `columns` numbers each."""
        value = self.table.get(key, _REQUIRED)
        if value is _REQUIRED:
            return self.get(key, list, default)  # the missing-key error, or the default
        self._read.add(key)
        if not (isinstance(value, list) and len(value) == rows and all(
                isinstance(r, list) and len(r) == columns and all(_is(v, float) for v in r)
                for r in value)):
            raise self.error(key, f"must be {rows} lists of {columns} numbers, got {value!r}")
        return tuple(tuple(float(v) for v in r) for r in value)

    def sub(self, key: str) -> "Section":
        """The sub-table `[name.key]`."""
        self._read.add(key)
        value = self.table.get(key)
        if not isinstance(value, dict):
            raise self.error(key, f"missing; add a [{self.name}.{key}] table")
        return Section(self.source, f"{self.name}.{key}", value)

    def finish(self) -> None:
        """Raise if the table has keys nobody read."""
        unknown = sorted(set(self.table) - self._read)
        if unknown:
            raise ProfileError(f"{self.source}: [{self.name}] has unknown keys {unknown}; "
                               f"known keys are {sorted(self._read)} (see docs/devices.md)")


def _is(value, kind: type) -> bool:
    """isinstance with TOML's types: bool is not an int, an int is a float."""
    if kind is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind is int:
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, kind)


@dataclass(frozen=True)
class Profile:
    """A loaded device profile: the file it came from and its top-level tables."""

    source: str
    tables: dict

    def section(self, name: str, parse):
        """The `[name]` section, parsed by `parse(Section)`."""
        table = self.tables.get(name)
        if not isinstance(table, dict):
            raise ProfileError(f"{self.source}: no [{name}] section; this device needs one "
                               "(see docs/devices.md)")
        return parse(Section(self.source, name, table))


def load_profile(path_or_name) -> Profile:
    """Read a profile from a file path, or by bundled name (`"imu12_serial"` means
    drivers/profiles/imu12_serial.toml)."""
    path = Path(path_or_name)
    if not path.exists() and (BUNDLED / f"{path_or_name}.toml").exists():
        path = BUNDLED / f"{path_or_name}.toml"
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        bundled = sorted(p.stem for p in BUNDLED.glob("*.toml"))
        raise ProfileError(f"cannot read device profile {path}: {exc.strerror}; give a TOML file "
                           f"path or a bundled profile name {bundled}") from None
    except UnicodeDecodeError:
        raise ProfileError(f"{path}: not UTF-8 text; a device profile is a TOML file") from None
    try:
        return Profile(str(path), tomllib.loads(text))
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(f"{path}: invalid TOML ({exc}); fix the syntax") from None


# --------------------------------------------------------------------------------------------------
# [imu]

SI_UNITS = {"angular_rate": "rad/s", "acceleration": "m/s^2", "magnetic_field": "T"}


@dataclass(frozen=True)
class ImuSection:
    """`[imu]`: what the channels measure.

    name     : device model name
    channels : channel names, in column order of the samples
    units    : SI unit of each channel (rad/s, m/s^2 or T)
    scale    : counts per SI unit of each channel (positive; axis signs belong to the calibration)
    rate_hz  : nominal sample rate
    """

    name: str
    channels: tuple
    units: tuple
    scale: tuple
    rate_hz: float

    @classmethod
    def parse(cls, s: Section) -> "ImuSection":
        name = s.get("name", str)
        channels = s.get_list("channels", str)
        m = len(channels)
        if m == 0 or len(set(channels)) != m or not all(channels):
            raise s.error("channels", "must be a non-empty list of distinct, non-empty names")
        quantity = s.get("quantity", str, default=None, choices=tuple(SI_UNITS))
        units = s.get_list("units", str, length=m)
        allowed = {SI_UNITS[quantity]} if quantity else set(SI_UNITS.values())
        if not set(units) <= allowed:
            raise s.error("units", f"must be SI ({' or '.join(sorted(allowed))}); convert with "
                                   f"`scale` (counts per SI unit); got {sorted(set(units))}")
        scale = s.get_list("scale", float, length=m)
        if not all(math.isfinite(v) and v > 0 for v in scale):
            raise s.error("scale", "counts per SI unit must be finite and positive")
        rate_hz = s.get("rate_hz", float)
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise s.error("rate_hz", "must be a positive sample rate in Hz")
        s.finish()
        return cls(name, channels, units, scale, rate_hz)

    def to_si(self, counts) -> np.ndarray:
        """Counts (k, m) converted to SI units."""
        return np.asarray(counts, dtype=float) / np.asarray(self.scale)


# --------------------------------------------------------------------------------------------------
# [serial]


@dataclass(frozen=True)
class BinaryFormat:
    """`[serial.binary]`: layout of one frame.

    sync            : sync word bytes (1-4), e.g. [0xA5, 0x5A]
    layout          : field order, "sync" first and "crc" last; "seq" and "counts" required,
                      "time" and "length" optional
    byte_order      : "little" or "big" (all multi-byte fields, CRC included)
    seq_type        : unsigned type of the sequence counter (uint8, uint16, uint32)
    time_type       : unsigned type of the device time, or None without a "time" field
    time_tick       : seconds per device-time tick (1 / the device clock's tick rate)
    count_type      : integer type of each channel count
    crc             : frame check (a name in drivers.wire.crc.CHECKSUMS: a CRC or "sum16")
    crc_covers_sync : whether the CRC covers the sync word (otherwise it starts after it)
    max_gap         : largest sequence step still counted as consistent (dropped frames + 1)
    length_type     : unsigned type of the length field, or None without a "length" field
    length_value    : the value every frame carries in its length field (a frame with another
                      value is refused like one failing its CRC)
    """

    sync: bytes
    layout: tuple
    byte_order: str
    seq_type: str
    time_type: object
    time_tick: float
    count_type: str
    crc: str
    crc_covers_sync: bool
    max_gap: int
    length_type: object = None
    length_value: int = 0

    @classmethod
    def parse(cls, s: Section) -> "BinaryFormat":
        sync = s.get_list("sync", int)
        if not 1 <= len(sync) <= 4 or not all(0 <= b <= 255 for b in sync):
            raise s.error("sync", "must be 1 to 4 byte values (0-255), e.g. [0xA5, 0x5A]")
        layout = s.get_list("layout", str)
        middle = layout[1:-1]
        optional = set(middle) - {"counts", "seq"}
        if ((layout[:1], layout[-1:]) != (("sync",), ("crc",)) or len(set(middle)) != len(middle)
                or not {"counts", "seq"} <= set(middle) or not optional <= {"time", "length"}):
            raise s.error("layout", "must start with \"sync\", end with \"crc\" and hold \"seq\", "
                                    "\"counts\" and optionally \"time\" and \"length\" once each; "
                                    f"got {list(layout)}")
        unsigned = tuple(t for t in INT_TYPES if t.startswith("u"))
        has_time = "time" in layout
        length_type, length_value = None, 0
        if "length" in layout:
            length_type = s.get("length_type", str, choices=unsigned)
            length_value = s.get("length_value", int)
            if not 0 <= length_value < 1 << 8 * int(INT_TYPES[length_type][1]):
                raise s.error("length_value", f"must fit the {length_type} length field")
        seq_type = s.get("seq_type", str, choices=unsigned)
        time_type = s.get("time_type", str, choices=unsigned) if has_time else None
        time_tick = s.get("time_tick", float) if has_time else math.nan
        if has_time and not (math.isfinite(time_tick) and time_tick > 0):
            raise s.error("time_tick", "must be the positive duration of one device-time tick, s")
        seq_modulus = 1 << 8 * int(INT_TYPES[seq_type][1])
        max_gap = s.get("max_gap", int, default=min(32, seq_modulus // 8))
        if not 1 <= max_gap <= seq_modulus // 8:
            raise s.error("max_gap", f"must be 1..{seq_modulus // 8} (an eighth of the {seq_type} "
                                     "range) for the sequence check to mean anything")
        fmt = cls(
            sync=bytes(sync),
            layout=layout,
            byte_order=s.get("byte_order", str, choices=("little", "big")),
            seq_type=seq_type,
            time_type=time_type,
            time_tick=time_tick,
            count_type=s.get("count_type", str, choices=tuple(INT_TYPES)),
            crc=s.get("crc", str, choices=tuple(CHECKSUMS)),
            crc_covers_sync=s.get("crc_covers_sync", bool, default=False),
            max_gap=max_gap,
            length_type=length_type,
            length_value=length_value,
        )
        s.finish()
        return fmt


@dataclass(frozen=True)
class AsciiFormat:
    """`[serial.ascii]`: one sample per line.

    delimiter  : "," ";" "\\t" or " " (" " means any run of spaces and tabs)
    timestamp  : "none", "first" or "last" column
    time_scale : seconds per unit of the timestamp column (0.001 for milliseconds)
    decimals   : counts are the printed values times 10**decimals (exact fixed point)
    """

    delimiter: str
    timestamp: str
    time_scale: float
    decimals: int

    @classmethod
    def parse(cls, s: Section) -> "AsciiFormat":
        time_scale = s.get("time_scale", float, default=1.0)
        if not (math.isfinite(time_scale) and time_scale > 0):
            raise s.error("time_scale", "must be the positive number of seconds per time unit")
        decimals = s.get("decimals", int, default=0)
        if not 0 <= decimals <= 9:
            raise s.error("decimals", "must be 0..9")
        fmt = cls(
            delimiter=s.get("delimiter", str, default=",", choices=(",", ";", "\t", " ")),
            timestamp=s.get("timestamp", str, default="none", choices=("none", "first", "last")),
            time_scale=time_scale,
            decimals=decimals,
        )
        s.finish()
        return fmt


@dataclass(frozen=True)
class SerialSection:
    """`[serial]`: port settings and the wire format (`frame`, a BinaryFormat or AsciiFormat)."""

    baudrate: int
    protocol: str
    frame: object

    @classmethod
    def parse(cls, s: Section) -> "SerialSection":
        baudrate = s.get("baudrate", int)
        if baudrate <= 0:
            raise s.error("baudrate", "must be positive")
        protocol = s.get("protocol", str, choices=("binary", "ascii"))
        other = "ascii" if protocol == "binary" else "binary"
        if s.has(other):
            raise s.error(other, f"protocol is {protocol!r}: remove [serial.{other}] or change it")
        frame = (BinaryFormat if protocol == "binary" else AsciiFormat).parse(s.sub(protocol))
        s.finish()
        return cls(baudrate, protocol, frame)


@dataclass(frozen=True)
class SerialImuProfile:
    """Everything a serial IMU driver and its twin need: `[imu]` and `[serial]`."""

    source: str
    imu: ImuSection
    serial: SerialSection

    @classmethod
    def load(cls, path_or_name) -> "SerialImuProfile":
        """Read and check a serial IMU profile (path or bundled name)."""
        profile = load_profile(path_or_name)
        return cls(profile.source, profile.section("imu", ImuSection.parse),
                   profile.section("serial", SerialSection.parse))
