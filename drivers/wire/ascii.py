"""Text lines of serial IMUs, one sample per line.

Comma-, semicolon-, tab- or space-separated values with an optional timestamp column (layout from
the device profile, `[serial.ascii]`), optionally as NMEA-style sentences `$ADDR,v1,...,vn*hh`
whose `hh` is the XOR of the bytes between `$` and `*` (NMEA 0183; VectorNav's ASCII outputs).
Columns the station does not record are named "" in the profile's `columns`. The first line after
opening is discarded (it is usually partial).
"""

import numpy as np

from drivers.samples import SampleBlock
from drivers.wire import Decoded, SerialStats


def encode_lines(fmt, times, counts, channels=None) -> bytes:
    """Text lines of samples: optional timestamp (in the profile's time unit) and the counts,
    written with `fmt.decimals` decimals (counts / 10**decimals); columns the station does not
    record are written as 0; sentences get their `$ADDR,` and `*hh`."""
    sep = fmt.delimiter
    where = _column_of(fmt, channels or [f"c{j}" for j in range(np.shape(counts)[1])])
    lines = []
    for t, row in zip(np.asarray(times, float), np.asarray(counts, np.int64), strict=False):
        values = [_fixed(int(row[j]), fmt.decimals) if j >= 0 else "0" for j in where]
        if fmt.timestamp == "first":
            values.insert(0, repr(float(t) / fmt.time_scale))
        elif fmt.timestamp == "last":
            values.append(repr(float(t) / fmt.time_scale))
        line = sep.join(values)
        if fmt.sentence:
            body = f"{fmt.sentence}{sep}{line}"
            line = f"${body}*{_xor(body.encode('ascii')):02X}"
        lines.append(line + "\r\n")
    return "".join(lines).encode("ascii")


def _column_of(fmt, channels) -> list:
    """For each value column, the index of its channel, or -1 for a column not recorded."""
    if not fmt.columns:
        return list(range(len(channels)))
    return [channels.index(c) if c else -1 for c in fmt.columns]


def _xor(data: bytes) -> int:
    """XOR of the bytes (the NMEA 0183 checksum)."""
    value = 0
    for b in data:
        value ^= b
    return value


def _fixed(count: int, decimals: int) -> str:
    """count / 10**decimals written exactly."""
    if decimals == 0:
        return str(count)
    sign, digits = ("-" if count < 0 else ""), str(abs(count)).rjust(decimals + 1, "0")
    return f"{sign}{digits[:-decimals]}.{digits[-decimals:]}"


def _parse_fixed(token: str, decimals: int) -> int:
    """Exact count from a decimal token with at most `decimals` decimals; ValueError otherwise."""
    sign = -1 if token[:1] == "-" else 1
    body = token[1:] if token[:1] in "+-" else token
    whole, dot, frac = body.partition(".")
    digits = whole.isascii() and whole.isdigit() and (not dot or frac.isascii() and frac.isdigit())
    if not digits or len(frac) > decimals:
        raise ValueError(f"not a number with at most {decimals} decimals: {token!r}")
    return sign * int(whole + frac.ljust(decimals, "0"))


class AsciiLineParser:
    """Incremental parser of one-sample-per-line text streams.

    Lines whose field count or values are wrong are counted in `bad_lines` and skipped; a line
    longer than `max_line` bytes is discarded (a resync). The sequence number is the host's count
    of accepted lines: text protocols carry none, so gaps cannot be detected.
    """

    max_line = 4096

    def __init__(self, fmt, channels):
        self.fmt = fmt
        self.channels = tuple(channels)
        self.where = np.array(_column_of(fmt, self.channels))
        self.fields = len(self.where) + (fmt.timestamp != "none")
        self.stats = SerialStats()
        self._next_seq = 0
        self.reset()

    def reset(self) -> None:
        """Forget buffered bytes; the next line is discarded as probably partial."""
        self._buf = b""
        self._partial = True

    def decode(self, data: bytes, host_time: float, final: bool = False) -> Decoded:
        """Add received bytes; the bytes decided and the samples of the lines completed by them.
        `final`: no more bytes will come; an unterminated last line is dropped."""
        self.stats.bytes += len(data)
        held = len(self._buf) + len(data)
        *lines, self._buf = (self._buf + bytes(data)).split(b"\n")
        if final:
            self.stats.skipped_bytes += len(self._buf)
            self._buf = b""
        if self._partial and lines:
            self.stats.skipped_bytes += len(lines[0]) + 1
            lines, self._partial = lines[1:], False
        if len(self._buf) > self.max_line:
            self.stats.skipped_bytes += len(self._buf)
            self.stats.resyncs += 1
            self._buf, self._partial = b"", True
        rows = [row for row in map(self._parse, lines) if row is not None]
        k = len(rows)
        values = np.array([r[0] for r in rows], dtype=np.int64).reshape(k, len(self.channels))
        seq = self._next_seq + np.arange(k, dtype=np.int64)
        self._next_seq += k
        self.stats.samples += k
        return Decoded(held - len(self._buf), SampleBlock(
            counts=values,
            seq=seq,
            device_time=np.array([r[1] for r in rows], dtype=float),
            host_time=np.full(k, float(host_time)),
            channels=self.channels,
        ))

    def _parse(self, line: bytes):
        """(counts, device time) of one line, or None (counted) if the line is not a sample."""
        if not line.strip():
            return None
        try:
            text = line.decode("ascii")
            if self.fmt.sentence:
                text = self._sentence(text.strip())
                if text is None:
                    return None
            tokens = (text.split() if self.fmt.delimiter.isspace()
                      else text.split(self.fmt.delimiter))
            tokens = [t.strip() for t in tokens]
            if len(tokens) != self.fields:
                raise ValueError(f"{len(tokens)} fields, expected {self.fields}")
            time = np.nan
            if self.fmt.timestamp == "first":
                time, tokens = float(tokens[0]) * self.fmt.time_scale, tokens[1:]
            elif self.fmt.timestamp == "last":
                time, tokens = float(tokens[-1]) * self.fmt.time_scale, tokens[:-1]
            if self.fmt.timestamp != "none" and not np.isfinite(time):
                raise ValueError("timestamp is not finite")
            values = [_parse_fixed(t, self.fmt.decimals) if j >= 0 else 0
                      for t, j in zip(tokens, self.where, strict=True)]
            if any(abs(c) >= 2**63 for c in values):
                raise ValueError("count does not fit 64 bits")
            counts = [0] * len(self.channels)
            for value, j in zip(values, self.where, strict=True):
                if j >= 0:
                    counts[j] = value
        except (UnicodeDecodeError, ValueError):
            self.stats.bad_lines += 1
            return None
        return counts, time

    def _sentence(self, text: str):
        """The values part of a `$ADDR,values*hh` sentence of the profile's address; None for
        another address; ValueError if it is not a sentence or its checksum does not hold."""
        body, star, check = text[1:].rpartition("*")
        if text[:1] != "$" or not star or len(check) != 2:
            raise ValueError("not a $...*hh sentence")
        address, sep, values = body.partition(self.fmt.delimiter)
        if int(check, 16) != _xor(body.encode("ascii")):
            raise ValueError("sentence checksum does not match")
        return values if address == self.fmt.sentence and sep else None
