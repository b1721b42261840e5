"""CRCs and checksums of the binary wire format, computed for many frames at once (numpy).

`CRCS` names the CRCs (table-driven), `CHECKSUMS` every algorithm a device profile may choose
(`[serial.binary] crc`): the CRCs and the simpler checks devices send instead - byte sums
(OpenShoe/MIMU arrays: the 16-bit sum), the two's-complement sum (Xsens Xbus), XOR and
Fletcher-16 (both the original modulo-255 form and the modulo-256 form of u-blox UBX and
MicroStrain MIP). Each check has `size` (bytes in a frame), `rows(data)` (N, n) uint8 -> (N,)
uint32 and `of(data)` for one byte string.
"""

from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np


@dataclass(frozen=True)
class Crc:
    """A CRC in the Rocksoft/Williams parametrisation (width, poly, init, reflected, xorout)."""

    width: int
    poly: int
    init: int
    reflected: bool
    xorout: int

    @property
    def size(self) -> int:
        """Bytes the CRC occupies in a frame."""
        return self.width // 8

    @cached_property
    def table(self) -> np.ndarray:
        """The 256-entry byte table of the table-driven algorithm."""
        mask = (1 << self.width) - 1
        table = np.zeros(256, dtype=np.uint32)
        if self.reflected:
            poly = int(f"{self.poly:0{self.width}b}"[::-1], 2)
            for byte in range(256):
                c = byte
                for _ in range(8):
                    c = (c >> 1) ^ poly if c & 1 else c >> 1
                table[byte] = c
        else:
            top = 1 << (self.width - 1)
            for byte in range(256):
                c = byte << (self.width - 8)
                for _ in range(8):
                    c = ((c << 1) ^ self.poly) if c & top else (c << 1)
                table[byte] = c & mask
        return table

    def bytewise(self, data: np.ndarray) -> np.ndarray:
        """CRC of every row of `data` (N, n) uint8 by the byte-at-a-time algorithm -> (N,)
        uint32."""
        table, mask, shift = self.table, np.uint32((1 << self.width) - 1), self.width - 8
        crc = np.full(data.shape[0], self.init, dtype=np.uint32)
        for column in np.ascontiguousarray(data.T):
            if self.reflected:
                crc = (crc >> 8) ^ table[(crc ^ column) & 0xFF]
            else:
                crc = ((crc << 8) & mask) ^ table[((crc >> shift) ^ column) & 0xFF]
        return crc ^ np.uint32(self.xorout)

    # Cached per (instance, n): the instances are the module constants of CRCS, alive for the whole
    # program anyway, so the cache holding them leaks nothing.
    @lru_cache(maxsize=8)  # noqa: B019
    def positional(self, n: int) -> tuple:
        """(crc of n zero bytes, table (n * 256,) of what byte value b at position j adds at
        j * 256 + b, the offsets j * 256 (n,)); table and offsets of the narrowest type that
        holds them (a gather from a small table of small indexes is the fast part of `rows`).

        A CRC is affine over GF(2): crc(d) = crc(0) ^ XOR_j T[j, d_j] for messages of length n.
        """
        unit = np.zeros((n, 256, n), dtype=np.uint8)
        unit[np.arange(n), :, np.arange(n)] = np.arange(256, dtype=np.uint8)
        zero = self.bytewise(np.zeros((1, n), np.uint8))[0]
        table = (self.bytewise(unit.reshape(n * 256, n)) ^ zero).astype(
            np.uint16 if self.width <= 16 else np.uint32)
        offsets = np.arange(n) * 256
        return zero, table, offsets.astype(np.uint16 if n <= 256 else np.intp)

    def rows(self, data: np.ndarray) -> np.ndarray:
        """CRC of every row of `data` (N, n) uint8, all rows at once -> (N,) uint32."""
        zero, table, offsets = self.positional(data.shape[1])
        if data.shape[0] == 0 or data.shape[1] == 0:
            return np.full(data.shape[0], zero, np.uint32)
        added = np.take(table, data + offsets)  # take: twice as fast as indexing here
        return (np.bitwise_xor.reduce(added, axis=1) ^ zero).astype(np.uint32)

    def of(self, data: bytes) -> int:
        """CRC of one byte string."""
        return int(self.rows(np.frombuffer(data, dtype=np.uint8)[None, :])[0])


CRCS = {
    "crc8": Crc(8, 0x07, 0x00, False, 0x00),  # CRC-8/SMBUS
    "crc8-maxim": Crc(8, 0x31, 0x00, True, 0x00),  # CRC-8/MAXIM-DOW (1-Wire)
    "crc16-ccitt-false": Crc(16, 0x1021, 0xFFFF, False, 0x0000),
    "crc16-kermit": Crc(16, 0x1021, 0x0000, True, 0x0000),
    "crc16-arc": Crc(16, 0x8005, 0x0000, True, 0x0000),
    "crc16-xmodem": Crc(16, 0x1021, 0x0000, False, 0x0000),
    "crc16-modbus": Crc(16, 0x8005, 0xFFFF, True, 0x0000),
    "crc32": Crc(32, 0x04C11DB7, 0xFFFFFFFF, True, 0xFFFFFFFF),
    "crc32c": Crc(32, 0x1EDC6F41, 0xFFFFFFFF, True, 0xFFFFFFFF),
}


class _Check:
    """What every simple check shares: its size and `of` (one byte string) from `rows`."""

    width = 8

    @property
    def size(self) -> int:
        """Bytes the checksum occupies in a frame."""
        return self.width // 8

    def of(self, data: bytes) -> int:
        """Checksum of one byte string."""
        return int(self.rows(np.frombuffer(data, dtype=np.uint8)[None, :])[0])


@dataclass(frozen=True)
class ByteSum(_Check):
    """The sum of the bytes modulo 2**width: the checksum, not a CRC, of devices such as the
    OpenShoe/MIMU arrays. It misses reordered bytes and errors that cancel, so the parser's
    sequence check matters more with it. `negate`: the two's complement of the sum, so that the
    bytes and the checksum add up to 0 (Xsens Xbus, MT Low-Level Communication Protocol, section
    "Checksum")."""

    width: int
    negate: bool = False

    def rows(self, data: np.ndarray) -> np.ndarray:
        """Checksum of every row of `data` (N, n) uint8 -> (N,) uint32."""
        total = np.asarray(data, dtype=np.uint8).sum(axis=1, dtype=np.uint64)
        if self.negate:
            total = -total.astype(np.int64)
        return (total % (1 << self.width)).astype(np.uint32)


@dataclass(frozen=True)
class Xor8(_Check):
    """The XOR of all bytes (NMEA 0183's `*hh`, and binary devices' "XOR checksum"). Any even
    number of flips of one bit position cancels."""

    def rows(self, data: np.ndarray) -> np.ndarray:
        """Checksum of every row of `data` (N, n) uint8 -> (N,) uint32."""
        data = np.asarray(data, dtype=np.uint8)
        if data.shape[1] == 0:
            return np.zeros(len(data), np.uint32)
        return np.bitwise_xor.reduce(data, axis=1).astype(np.uint32)


@dataclass(frozen=True)
class Fletcher16(_Check):
    """Fletcher's checksum of bytes: s1 = sum d_j, s2 = sum of the running s1 = sum (n - j) d_j
    (j = 0..n-1), both modulo `modulus`. Modulus 255 is Fletcher's original (RFC 1146), sent as
    s2 << 8 | s1; modulus 256 is the form of u-blox UBX (CK_A, CK_B) and MicroStrain MIP, sent
    s1 first: s1 << 8 | s2."""

    modulus: int
    width = 16

    def rows(self, data: np.ndarray) -> np.ndarray:
        """Checksum of every row of `data` (N, n) uint8 -> (N,) uint32."""
        data = np.asarray(data, dtype=np.uint64)
        weights = np.arange(data.shape[1], 0, -1, dtype=np.uint64)
        s1 = data.sum(axis=1, dtype=np.uint64) % self.modulus
        s2 = (data @ weights) % self.modulus
        high, low = (s2, s1) if self.modulus == 255 else (s1, s2)
        return ((high << np.uint64(8)) | low).astype(np.uint32)


CHECKSUMS = {**CRCS, "sum8": ByteSum(8), "sum16": ByteSum(16), "sum8-twos": ByteSum(8, True),
             "xor8": Xor8(), "fletcher16": Fletcher16(255), "fletcher16-mod256": Fletcher16(256)}
"""Every frame check a profile may choose: the CRCs, byte sums, two's-complement sum, XOR and
Fletcher-16."""
