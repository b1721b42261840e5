"""CRCs and checksums of the binary wire format, computed for many frames at once (numpy).

`CRCS` names the CRCs (table-driven), `CHECKSUMS` every algorithm a device profile may choose
(`[serial.binary] crc`): the CRCs and the byte sums some devices send instead (OpenShoe/MIMU
arrays: the 16-bit sum of the bytes).
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
        """(crc of n zero bytes, table (n, 256) of what byte value b at position j adds).

        A CRC is affine over GF(2): crc(d) = crc(0) ^ XOR_j T[j, d_j] for messages of length n.
        """
        unit = np.zeros((n, 256, n), dtype=np.uint8)
        unit[np.arange(n), :, np.arange(n)] = np.arange(256, dtype=np.uint8)
        zero = self.bytewise(np.zeros((1, n), np.uint8))[0]
        return zero, (self.bytewise(unit.reshape(n * 256, n)) ^ zero).reshape(n, 256)

    def rows(self, data: np.ndarray) -> np.ndarray:
        """CRC of every row of `data` (N, n) uint8, all rows at once -> (N,) uint32."""
        zero, table = self.positional(data.shape[1])
        if data.shape[0] == 0:
            return np.zeros(0, np.uint32)
        return np.bitwise_xor.reduce(table[np.arange(data.shape[1]), data], axis=1) ^ zero

    def of(self, data: bytes) -> int:
        """CRC of one byte string."""
        return int(self.rows(np.frombuffer(data, dtype=np.uint8)[None, :])[0])


CRCS = {
    "crc16-ccitt-false": Crc(16, 0x1021, 0xFFFF, False, 0x0000),
    "crc16-xmodem": Crc(16, 0x1021, 0x0000, False, 0x0000),
    "crc16-modbus": Crc(16, 0x8005, 0xFFFF, True, 0x0000),
    "crc32": Crc(32, 0x04C11DB7, 0xFFFFFFFF, True, 0xFFFFFFFF),
}


@dataclass(frozen=True)
class ByteSum:
    """The sum of the bytes modulo 2**width: the checksum, not a CRC, of devices such as the
    OpenShoe/MIMU arrays. It misses reordered bytes and errors that cancel, so the parser's
    sequence check matters more with it."""

    width: int

    @property
    def size(self) -> int:
        """Bytes the checksum occupies in a frame."""
        return self.width // 8

    def rows(self, data: np.ndarray) -> np.ndarray:
        """Checksum of every row of `data` (N, n) uint8 -> (N,) uint32."""
        total = np.asarray(data, dtype=np.uint8).sum(axis=1, dtype=np.uint64)
        return (total % (1 << self.width)).astype(np.uint32)

    def of(self, data: bytes) -> int:
        """Checksum of one byte string."""
        return int(self.rows(np.frombuffer(data, dtype=np.uint8)[None, :])[0])


CHECKSUMS = {**CRCS, "sum16": ByteSum(16)}
"""Every frame check a profile may choose: the CRCs and the 16-bit byte sum."""
