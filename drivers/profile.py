"""Device profiles: one TOML file per device model, read with the stdlib `tomllib`.

A profile is a set of sections (`[imu]`, `[serial]`, `[can]`, `[table]`, ...). This module has the
generic part - `load_profile` and `Section`, a checked view of one table whose errors name the file,
the key and the fix - and the sections of serial IMUs: `ImuSection` (`[imu]`: channels, SI units,
scale) and `SerialSection` (`[serial]` with `[serial.binary]` or `[serial.ascii]`).

Another device adds its section as a dataclass with a `parse(section: Section)` classmethod and
reads it with `profile.section("name", TheSection.parse)`.
"""

import dataclasses
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.errors import ProfileError
from drivers.wire.crc import CHECKSUMS
from drivers.wire.fields import INT_TYPES, SPECIAL, TYPES, Field, FrameLayout, seq_modulus

BUNDLED = Path(__file__).parent / "profiles"
_REQUIRED = object()
MAX_BYTES = 1 << 20
"""Largest profile file: the bundled ones are under 10 KB."""
MAX_DEPTH = 16
"""Deepest nesting of arrays and inline tables in a profile (a register map's is 3): tomllib
parses them recursively, so a deeper file is refused from its text first (`_nesting`)."""
MAX_CHANNELS = 1024
"""Most channels of one IMU stream ([imu] channels)."""
_TOML_TOKENS = re.compile(r'"""[\s\S]*?"""|\'\'\'[\s\S]*?\'\'\'|"(?:[^"\\\n]|\\.)*"'
                          r"|'[^'\n]*'|#[^\n]*|[\[\]{}]")
"""A TOML string (multi-line, basic or literal) or a comment, skipped whole, or a bracket."""


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
        if path.stat().st_size > MAX_BYTES:
            raise ProfileError(f"{path}: {path.stat().st_size} bytes; a device profile is at most "
                               f"{MAX_BYTES} bytes of TOML: is it the right file?")
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        bundled = sorted(p.stem for p in BUNDLED.glob("*.toml"))
        raise ProfileError(f"cannot read device profile {path}: {exc.strerror}; give a TOML file "
                           f"path or a bundled profile name {bundled}") from None
    except UnicodeDecodeError:
        raise ProfileError(f"{path}: not UTF-8 text; a device profile is a TOML file") from None
    _nesting(text, path)
    try:
        return Profile(str(path), tomllib.loads(text))
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(f"{path}: invalid TOML ({exc}); fix the syntax") from None


def _nesting(text: str, path) -> None:
    """Refuse TOML text whose arrays and inline tables nest deeper than MAX_DEPTH, counted from
    the text (strings and comments skipped) before the recursive parser sees it."""
    depth = 0
    for match in _TOML_TOKENS.finditer(text):
        token = match.group()
        if token in "[{":
            depth += 1
            if depth > MAX_DEPTH:
                line = text.count("\n", 0, match.start()) + 1
                raise ProfileError(f"{path}: line {line}: arrays or inline tables nested more "
                                   f"than {MAX_DEPTH} deep; a profile nests at most {MAX_DEPTH}")
        elif token in "]}":
            depth = max(0, depth - 1)


# --------------------------------------------------------------------------------------------------
# [imu]

SI_UNITS = {"angular_rate": "rad/s", "acceleration": "m/s^2", "magnetic_field": "T",
            "temperature": "K"}


@dataclass(frozen=True)
class ImuSection:
    """`[imu]`: what the channels measure.

    name     : device model name
    channels : channel names, in column order of the samples
    units    : SI unit of each channel (rad/s, m/s^2, T, or K for a temperature channel)
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
        if not 0 < m <= MAX_CHANNELS or len(set(channels)) != m or not all(channels):
            raise s.error("channels", f"must be a list of 1 to {MAX_CHANNELS} distinct, non-empty "
                                      f"names (got {m} names)")
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
    fields          : typed fields between sync and check (drivers/wire/fields.py), given instead
                      of `layout` and the *_type keys as `[[serial.binary.fields]]` tables
    crc_byte_order  : byte order of the check when it differs from `byte_order` ("" = the same)
    seq_step        : without a "seq" field, device-time ticks per frame (the frame counter is
                      the device time counted in steps)
    length_field    : name of the (unsigned) field holding a message's length, so that messages
                      of other ids are skipped by their length ("" for none)
    length_adds     : bytes of a message beyond its length field's value (header and check)
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
    fields: tuple = ()
    crc_byte_order: str = ""
    seq_step: int = 0
    length_field: str = ""
    length_adds: int = 0

    @classmethod
    def parse(cls, s: Section) -> "BinaryFormat":
        sync = s.get_list("sync", int)
        if not 1 <= len(sync) <= 4 or not all(0 <= b <= 255 for b in sync):
            raise s.error("sync", "must be 1 to 4 byte values (0-255), e.g. [0xA5, 0x5A]")
        if s.has("fields"):
            return _parse_fields(cls, s, bytes(sync))
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
            crc_byte_order=s.get("crc_byte_order", str, default="", choices=("little", "big")),
        )
        s.finish()
        return fmt


def _parse_fields(cls, s: Section, sync: bytes) -> BinaryFormat:
    """A BinaryFormat given as typed fields (`[[serial.binary.fields]]`)."""
    tables = s.get("fields", list)
    if not tables or not all(isinstance(t, dict) for t in tables):
        raise s.error("fields", "must be a list of [[serial.binary.fields]] tables")
    fields = tuple(_parse_field(Section(s.source, f"{s.name}.fields[{i}]", t))
                   for i, t in enumerate(tables))
    names = [f.name for f in fields if f.name in SPECIAL]
    if len(set(names)) != len(names):
        raise s.error("fields", "\"seq\" and \"time\" may each be given once")
    has_time = "time" in names
    time_tick = s.get("time_tick", float) if has_time else math.nan
    if has_time and not (math.isfinite(time_tick) and time_tick > 0):
        raise s.error("time_tick", "must be the positive duration of one device-time tick, s")
    seq_step = 0
    if "seq" not in names:
        if not has_time:
            raise s.error("fields", "need a \"seq\" field, or a \"time\" field and `seq_step` "
                                    "(device-time ticks per frame) to count frames by")
        seq_step = s.get("seq_step", int)
        time_field = next(f for f in fields if f.name == "time")
        if not 1 <= seq_step <= time_field.modulus // 64:
            raise s.error("seq_step", "must be the positive number of device-time ticks per frame")
    fmt = cls(sync=sync, layout=(), byte_order=s.get("byte_order", str, choices=("little", "big")),
              seq_type="", time_type=None, time_tick=time_tick, count_type="",
              crc=s.get("crc", str, choices=tuple(CHECKSUMS)),
              crc_covers_sync=s.get("crc_covers_sync", bool, default=False), max_gap=1,
              fields=fields, seq_step=seq_step,
              crc_byte_order=s.get("crc_byte_order", str, default="", choices=("little", "big")))
    length_field = s.get("length_field", str, default="")
    length_adds = s.get("length_adds", int) if length_field else 0
    named = {f.name: f for f in fields}
    if length_field and (length_field not in named or named[length_field].type not in (
            "uint8", "uint16", "uint32")):
        raise s.error("length_field", "must name a uint8, uint16 or uint32 field of the frame")
    if length_field and not 1 <= length_adds <= 64:
        raise s.error("length_adds", "must be the bytes of a message beyond its length value "
                                     "(header and check), 1..64")
    fmt = dataclasses.replace(fmt, length_field=length_field, length_adds=length_adds)
    modulus = seq_modulus(fmt)
    max_gap = s.get("max_gap", int, default=min(32, modulus // 8))
    if not 1 <= max_gap <= modulus // 8:
        raise s.error("max_gap", f"must be 1..{modulus // 8} (an eighth of the sequence range) "
                                 "for the sequence check to mean anything")
    s.finish()
    return dataclasses.replace(fmt, max_gap=max_gap)


def _parse_field(s: Section) -> Field:
    """One `[[serial.binary.fields]]` table."""
    name = s.get("name", str)
    kind = s.get("type", str, choices=tuple(TYPES))
    if name in ("sync", "crc", "counts") or not name:
        raise s.error("name", f"{name!r} is not a field name: the sync word and the check are "
                              "keys of [serial.binary]; name a channel of [imu], \"seq\", "
                              "\"time\" or anything else")
    is_float, unsigned = kind.startswith("float"), kind.startswith("uint")
    if name in SPECIAL and not unsigned:
        raise s.error("type", f"the {name} field must be an unsigned integer type")
    value = s.get("value", int, default=None)
    mask = s.get("valid_mask", int, default=None)
    valid_value = s.get("valid_value", int, default=0)
    if (value is not None or mask is not None) and not unsigned:
        raise s.error("value" if value is not None else "valid_mask",
                      "constants and status words must be unsigned integer fields")
    bits = 24 if kind.endswith("24") else 8 * np.dtype(TYPES[kind]).itemsize
    for key, v in (("value", value), ("valid_mask", mask), ("valid_value", valid_value)):
        if v is not None and not 0 <= v < 1 << bits:
            raise s.error(key, f"must fit the {kind} field (0..{(1 << bits) - 1})")
    converted = is_float or s.has("scale") or s.has("offset")
    scale = s.get("scale", float, default=1.0)
    offset = s.get("offset", float, default=0.0)
    if not (math.isfinite(scale) and scale != 0 and math.isfinite(offset)):
        raise s.error("scale", "scale must be finite and non-zero, offset finite (SI = raw * "
                               "scale + offset)")
    field = Field(name, kind, s.get("byte_order", str, default="", choices=("little", "big")),
                  value, scale, offset, converted, mask, valid_value)
    s.finish()
    return field


@dataclass(frozen=True)
class AsciiFormat:
    """`[serial.ascii]`: one sample per line.

    delimiter  : "," ";" "\\t" or " " (" " means any run of spaces and tabs)
    timestamp  : "none", "first" or "last" column
    time_scale : seconds per unit of the timestamp column (0.001 for milliseconds)
    decimals   : counts are the printed values times 10**decimals (exact fixed point); values
                 with fewer decimals are exact too
    sentence   : NMEA-style sentences: the address ("VNIMU" for `$VNIMU,...*hh`); each line must
                 end in `*hh`, the XOR of the bytes between `$` and `*` (NMEA 0183); sentences
                 with another address are skipped. "" for plain lines
    columns    : what each value column is, in order: a channel name of [imu], or "" for a
                 column the station does not record; default: the channels in order
    """

    delimiter: str
    timestamp: str
    time_scale: float
    decimals: int
    sentence: str = ""
    columns: tuple = ()

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
            sentence=s.get("sentence", str, default=""),
            columns=s.get_list("columns", str, default=[]),
        )
        if fmt.sentence and not (fmt.sentence.isascii() and fmt.sentence.isalnum()):
            raise s.error("sentence", "must be the sentence address, letters and digits (e.g. "
                                      "\"VNIMU\" for $VNIMU,...*hh)")
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
        loaded = cls(profile.source, profile.section("imu", ImuSection.parse),
                     profile.section("serial", SerialSection.parse))
        frame = loaded.serial.frame
        if loaded.serial.protocol == "ascii" and frame.columns:
            named = [c for c in frame.columns if c]
            if sorted(named) != sorted(loaded.imu.channels):
                raise ProfileError(f"{loaded.source}: [serial.ascii] columns must name every "
                                   f"[imu] channel once (\"\" for other columns); got {named}")
        if loaded.serial.protocol == "binary":
            try:
                FrameLayout(loaded.serial.frame, loaded.imu.channels, loaded.imu.scale)
            except ProfileError as exc:
                raise ProfileError(f"{loaded.source}: {exc}") from None
        return loaded
