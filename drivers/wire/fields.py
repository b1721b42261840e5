"""Typed fields of a binary frame: the frame between the sync word and the check as a list of
fields, each with its own type and byte order, decoded for many frames at once (numpy).

A field is one of
- a channel of the device profile's `[imu]` (`name` = the channel): an integer is the channel's
  count as sent; a float, or a field with `scale`/`offset`, is converted to SI
  (`raw * scale + offset`) and then to counts of the `[imu]` scale (`round(SI * counts per SI)`);
- "seq" (the frame counter) or "time" (the device time, in ticks of the profile's `time_tick`);
- a constant (`value`): message ids, lengths, data identifiers; a frame holding another value is
  refused like one failing its check (this is how sync + id + length framing selects the
  configured message and refuses every other);
- a status word (`valid_mask`, `valid_value`): a frame whose `status & valid_mask != valid_value`
  is a sample the device itself marks invalid; it is not returned (counted in `stats.invalid`);
- anything else (reserved bytes, outputs the station does not record): read and ignored.

The one-block layout of earlier profiles (`layout = ["sync", "seq", "time", "counts", "crc"]`) is
the special case of a "counts" field repeated once per channel (`layout_fields`).
"""

import collections
from dataclasses import dataclass

import numpy as np

from drivers.errors import ProfileError
from drivers.wire.crc import CHECKSUMS

INT_TYPES = {"uint8": "u1", "uint16": "u2", "uint32": "u4", "uint64": "u8",
             "int8": "i1", "int16": "i2", "int32": "i4", "int64": "i8"}
"""Profile integer type name -> numpy type code."""
TYPES = {**INT_TYPES, "float32": "f4", "float64": "f8", "int24": "u1", "uint24": "u1"}
"""Every field type -> numpy type code (24-bit fields are three bytes, assembled here)."""
SPECIAL = ("seq", "time")
MAX_BITS = 62
"""Counters wider than this (64-bit times) are unwrapped as 62-bit ones, so that the parser's
int64 arithmetic cannot overflow: they wrap after 146 years of nanoseconds."""


@dataclass(frozen=True)
class Field:
    """One field of a frame (see the module docstring). `count` > 1 only for the one-block
    layout's "counts" (one value per channel)."""

    name: str
    type: str
    byte_order: str = ""  # "" means the frame's
    value: object = None
    scale: float = 1.0
    offset: float = 0.0
    converted: bool = False
    valid_mask: object = None
    valid_value: int = 0
    count: int = 1
    block: bool = False  # the one-block layout's counts: one value per channel

    @property
    def size(self) -> int:
        """Bytes of the field in a frame."""
        return (3 if self.type.endswith("24") else np.dtype(TYPES[self.type]).itemsize) * self.count

    @property
    def modulus(self) -> int:
        """How many values the (unsigned) field holds, capped at 2**MAX_BITS."""
        return 1 << min(8 * self.size, MAX_BITS)


def layout_fields(fmt) -> tuple:
    """The fields of a one-block `layout` profile (sync and crc are not fields)."""
    kinds = {"seq": lambda: Field("seq", fmt.seq_type),
             "length": lambda: Field("length", fmt.length_type, value=fmt.length_value),
             "time": lambda: Field("time", fmt.time_type),
             "counts": lambda: Field("counts", fmt.count_type, block=True)}
    return tuple(kinds[name]() for name in fmt.layout if name in kinds)


def frame_fields(fmt) -> tuple:
    """The fields of `fmt` (a profile's BinaryFormat), whichever way the profile gave them."""
    return fmt.fields or layout_fields(fmt)


def seq_modulus(fmt) -> int:
    """Values of the sequence: the "seq" field's, or the time field's counted in `seq_step`s."""
    by_name = {f.name: f for f in frame_fields(fmt)}
    if "seq" in by_name:
        return by_name["seq"].modulus
    return by_name["time"].modulus // fmt.seq_step


class FrameLayout:
    """The structured dtype of one frame and the conversions between records and samples.

    fmt      : a profile's BinaryFormat
    channels : the `[imu]` channel names
    scale    : the `[imu]` counts per SI unit of each channel (needed by converted fields)
    """

    def __init__(self, fmt, channels, scale=None):
        self.fmt, self.channels = fmt, tuple(channels)
        m = len(self.channels)
        self.fields = tuple(Field(f.name, f.type, count=m, block=True) if f.block else f
                            for f in frame_fields(fmt))
        self.by_name = {f.name: i for i, f in enumerate(self.fields) if f.name in SPECIAL}
        self.columns = self._columns()
        self.counts_per_si = np.ones(m) if scale is None else np.broadcast_to(
            np.asarray(scale, float), (m,))
        if scale is None and any(self.fields[i].converted for i, _ in self.columns):
            raise ValueError("the frame has converted (float or scaled) channel fields: give the "
                             "[imu] scale (counts per SI unit)")
        order = "<" if fmt.byte_order == "little" else ">"
        check = CHECKSUMS[fmt.crc].size
        crc_order = {"little": "<", "big": ">"}.get(fmt.crc_byte_order, order)
        self.dtype = np.dtype(
            [("sync", f"V{len(fmt.sync)}")]
            + [(f"f{i}", self._code(f, order), (f.count * 3,) if f.type.endswith("24")
                else (f.count,)) for i, f in enumerate(self.fields)]
            + [("crc", f"{crc_order}u{check}")])
        self.time_modulus = self.fields[self.by_name["time"]].modulus if "time" in self.by_name \
            else 0
        self.seq_modulus = seq_modulus(fmt)
        self._constants = self._constant_bytes()
        self._converted = self._conversion()

    def _conversion(self):
        """(fields, their channel columns, raw -> SI scale and offset per column, each field's
        first column among them, its width) of the converted channel fields, or None."""
        converted = [(i, cols) for i, cols in self.columns if self.fields[i].converted]
        if not converted:
            return None
        fields = [i for i, _ in converted]
        widths = np.array([len(cols) for _, cols in converted])
        cols = np.concatenate([cols for _, cols in converted])
        scale, offset = (np.repeat([getattr(self.fields[i], key) for i in fields], widths)
                         for key in ("scale", "offset"))
        return fields, cols, scale, offset, np.cumsum(widths) - widths, widths

    def _constant_bytes(self) -> tuple:
        """(byte offsets in a frame, the bytes there) of every constant field (the profile
        refuses a constant its field cannot hold)."""
        frame, offsets = np.zeros(1, self.dtype), []
        for i, f in enumerate(self.fields):
            if f.value is not None:
                self._put(frame, i, np.full((1, f.count), f.value))
                start = self.dtype.fields[f"f{i}"][1]
                offsets += range(start, start + f.size)
        offsets = np.array(offsets, np.intp)
        return offsets, frame.view(np.uint8)[offsets]

    def _columns(self) -> list:
        """(field index, channel columns) of every field that carries channels."""
        where = {name: j for j, name in enumerate(self.channels)}
        columns, seen = [], []
        for i, f in enumerate(self.fields):
            if f.block:
                columns.append((i, np.arange(len(self.channels))))
                seen += list(self.channels)
            elif f.name in where:
                columns.append((i, np.array([where[f.name]])))
                seen.append(f.name)
        times = collections.Counter(seen)  # linear: a profile may list many channels
        missing = [c for c in self.channels if c not in times]
        twice = sorted(c for c, n in times.items() if n > 1)
        if missing or twice:
            raise ProfileError(f"[serial.binary] fields: every [imu] channel needs exactly one "
                               f"field; missing {missing}, more than once {twice}")
        return columns

    @staticmethod
    def _code(f: Field, order: str) -> str:
        byte_order = {"little": "<", "big": ">"}.get(f.byte_order, order)
        return byte_order + TYPES[f.type]

    def _raw(self, records: np.ndarray, i: int) -> np.ndarray:
        """Values (k, count) of field i: int64 for integers, float64 for floats."""
        f, data = self.fields[i], records[f"f{i}"]
        if f.type.startswith("float"):
            with np.errstate(invalid="ignore"):  # signalling NaNs of damaged frames
                return data.astype(np.float64)
        if not f.type.endswith("24"):
            return data.astype(np.int64)
        b = data.reshape(len(records), f.count, 3).astype(np.int64)
        big = {"little": False, "big": True}.get(f.byte_order, self.fmt.byte_order == "big")
        value = (b[..., 0] << 16 | b[..., 1] << 8 | b[..., 2]) if big else (
            b[..., 2] << 16 | b[..., 1] << 8 | b[..., 0])
        return value - (value & 0x800000) * 2 if f.type == "int24" else value

    def length_rule(self):
        """(byte offset of the length field in a frame, its numpy type, bytes of a message beyond
        its length value), or None when the profile names no `length_field`."""
        if not self.fmt.length_field:
            return None
        offset = len(self.fmt.sync)
        for i, f in enumerate(self.fields):
            if f.name == self.fmt.length_field:
                return offset, self.dtype[f"f{i}"].base.str, self.fmt.length_adds
            offset += f.size
        raise ProfileError(f"[serial.binary] length_field: no field named "
                           f"{self.fmt.length_field!r}")

    def constants_hold(self, records: np.ndarray) -> np.ndarray:
        """Whether each record holds every constant field's value (its bytes, all at once)."""
        offsets, expected = self._constants
        size = self.dtype.itemsize
        raw = np.ascontiguousarray(records).view(np.uint8).reshape(len(records), size)
        return np.all(raw[:, offsets] == expected, axis=1)

    def seq(self, records: np.ndarray) -> np.ndarray:
        """Raw sequence numbers (int64) of the records."""
        if "seq" in self.by_name:
            return self._raw(records, self.by_name["seq"])[:, 0]
        step = self.fmt.seq_step
        return ((self.ticks(records) + step // 2) // step) % self.seq_modulus

    def ticks(self, records: np.ndarray) -> np.ndarray:
        """Raw device-time ticks (int64, zero without a time field)."""
        if "time" not in self.by_name:
            return np.zeros(len(records), np.int64)
        return self._raw(records, self.by_name["time"])[:, 0] % self.time_modulus

    def samples(self, records: np.ndarray) -> tuple:
        """(counts (k, m) int64, valid (k,) bool) of the records: the device's status rules and
        converted values that are not finite or do not fit 64 bits make a sample invalid."""
        k = len(records)
        counts, valid = np.zeros((k, len(self.channels)), np.int64), np.ones(k, bool)
        for i, f in enumerate(self.fields):
            if f.valid_mask is not None:
                valid &= (self._raw(records, i)[:, 0] & f.valid_mask) == f.valid_value
        for i, cols in self.columns:
            if not self.fields[i].converted:
                counts[:, cols] = self._raw(records, i)
        if self._converted:
            cols, value, fits = self._converted_counts(records)
            valid &= fits
            counts[:, cols] = value
        return counts, valid

    def _converted_counts(self, records: np.ndarray) -> tuple:
        """(channel columns, counts, whether every value fits) of the converted fields: counts
        that are not finite or do not fit 64 bits make their whole field 0 (and the sample
        invalid)."""
        fields, cols, scale, offset, starts, widths = self._converted
        raw = np.concatenate([self._raw(records, i) for i in fields], axis=1)
        value = np.rint((raw * scale + offset) * self.counts_per_si[cols])
        ok = np.isfinite(value) & (np.abs(value) < 2.0**62)
        if ok.all():  # the usual case, checked at once
            return cols, value, np.ones(len(value), bool)
        fits = np.all(ok, axis=1)
        bad = np.flatnonzero(~fits)  # rare: the fields of these samples one by one
        field_ok = np.logical_and.reduceat(ok[bad], starts, axis=1)
        value[bad] = np.where(np.repeat(field_ok, widths, axis=1), value[bad], 0)
        return cols, value, fits

    def records(self, seq, ticks, counts) -> np.ndarray:
        """Records (check left zero) of frames with raw sequence numbers `seq`, raw device-time
        ticks and counts (k, m); constants and status words hold their valid values."""
        counts = np.asarray(counts)
        k = len(counts)
        out = np.zeros(k, dtype=self.dtype)
        out["sync"] = np.frombuffer(self.fmt.sync, dtype=f"V{len(self.fmt.sync)}")[0]
        for i, cols in self.columns:
            f, values = self.fields[i], counts[:, cols]
            if f.converted:
                values = (values / self.counts_per_si[cols] - f.offset) / f.scale
                if not f.type.startswith("float"):
                    values = np.rint(values)
            self._put(out, i, values)
        for i, f in enumerate(self.fields):
            if f.name == "seq":
                self._put(out, i, np.asarray(seq, np.int64)[:, None] % f.modulus)
            elif f.name == "time":
                self._put(out, i, np.asarray(ticks, np.int64)[:, None] % f.modulus)
            elif f.value is not None or f.valid_mask is not None:
                value = f.value if f.value is not None else f.valid_value
                self._put(out, i, np.full((k, f.count), value))
        return out

    def _put(self, out: np.ndarray, i: int, values: np.ndarray) -> None:
        """Store values (k, count) into field i, refusing integers outside its range."""
        f = self.fields[i]
        if f.type.startswith("float"):
            out[f"f{i}"] = values
            return
        bits = 8 * f.size // f.count
        low, high = (-(1 << bits - 1), (1 << bits - 1) - 1) if f.type.startswith("int") else (
            0, (1 << bits) - 1)
        values = np.asarray(values)
        if values.size and (values.min() < low or values.max() > high):
            raise ValueError(f"values of field {f.name!r} outside the {f.type} range "
                             f"[{low}, {high}]; scale the source or choose a wider type")
        values = values.astype(np.int64)
        if not f.type.endswith("24"):
            out[f"f{i}"] = values
            return
        u = values & 0xFFFFFF
        parts = [(u >> 16) & 0xFF, (u >> 8) & 0xFF, u & 0xFF]
        big = {"little": False, "big": True}.get(f.byte_order, self.fmt.byte_order == "big")
        out[f"f{i}"] = np.stack(parts if big else parts[::-1], axis=-1).reshape(len(out), -1)
