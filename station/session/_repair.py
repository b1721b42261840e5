"""Repair of a killed writer's file at the HDF5 level (h5py's `_hl` idea: low-level details kept
out of the public classes): the superblock's "open for write" flags and their checksum.

HDF5 file format specification, section II.A: signature, version, offset size, length size, file
consistency flags at byte 11, four addresses, then a Jenkins lookup3 checksum of the preceding
bytes (superblock versions 2 and 3).
"""

import io
import logging
import os
import struct

from station.errors import SessionFormatError

log = logging.getLogger(__name__)


def _superblock(path) -> tuple[bytearray, int]:
    """The first 48 bytes of the file and its HDF5 superblock version, signature checked, and for
    versions 2-3 the checksum (HDF5 file format specification, section II.A: signature, version,
    offset size, length size, file consistency flags at byte 11, four addresses, then a Jenkins
    lookup3 checksum of the preceding bytes). Checked here because HDF5's SWMR reader retries
    checksum failures for minutes instead of failing."""
    with open(path, "rb") as fh:
        head = bytearray(fh.read(48))
    if head[:8] != b"\x89HDF\r\n\x1a\n":
        raise SessionFormatError(f"{path} is not an HDF5 file (no HDF5 signature at offset 0); "
                                 "not a session file")
    version = head[8]
    if version >= 2 and (len(head) < 48 or head[9] != 8):
        raise SessionFormatError(f"{path}: unexpected HDF5 superblock (version {version}, offset "
                                 f"size {head[9]}); not a session file written by this software")
    if version >= 2 and struct.unpack_from("<I", head, 44)[0] != _lookup3(bytes(head[:44])):
        raise SessionFormatError(f"{path}: the HDF5 superblock checksum is wrong; the file is "
                                 "damaged")
    return head, version


def open_flags(path) -> int:
    """The superblock's file consistency flags: non-zero while a writer has the file open, or
    after it was killed. Superblocks before version 2 have none."""
    head, version = _superblock(path)
    return head[11] if version >= 2 else 0


def clear_open_flags(path) -> None:
    """Clear the 'open for (SWMR) write' flags a killed writer leaves in the superblock, as the
    HDF5 tool `h5clear -s` does, and rewrite the superblock checksum."""
    head, version = _superblock(path)
    if version != 3:
        raise SessionFormatError(f"{path}: HDF5 superblock version {version}, sessions are "
                                 "written with version 3 (libver v110)")
    if head[11] == 0:
        return
    log.info("%s: clearing the open-for-write flags a killed writer left", path)
    head[11] = 0
    struct.pack_into("<I", head, 44, _lookup3(bytes(head[:44])))
    with open(path, "r+b") as fh:
        fh.write(head)
        fh.flush()
        os.fsync(fh.fileno())


class FlagsCleared(io.RawIOBase):
    """A file read as `clear_open_flags` would leave it, without writing to it: the superblock's
    open-for-write flags read as cleared, its checksum rewritten; every other byte as stored. A
    read-only file object for h5py (`h5py.File(FlagsCleared(path), "r")`)."""

    def __init__(self, path):
        super().__init__()
        head, _ = _superblock(path)
        head[11] = 0
        struct.pack_into("<I", head, 44, _lookup3(bytes(head[:44])))
        self._head = bytes(head)
        self._file = open(path, "rb", buffering=0)  # noqa: SIM115 - closed by close()

    def readinto(self, buffer) -> int:
        """Read into `buffer` from the current offset, the superblock's first 48 bytes replaced."""
        at = self._file.tell()
        n = self._file.readinto(buffer)
        if at < len(self._head) and n:
            end = min(len(self._head), at + n)
            memoryview(buffer)[:end - at] = self._head[at:end]
        return n

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        return self._file.seek(offset, whence)

    def tell(self) -> int:
        return self._file.tell()

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def close(self) -> None:
        self._file.close()
        super().close()


def _lookup3(data: bytes, initval: int = 0) -> int:
    """Bob Jenkins' lookup3 `hashlittle`, the checksum of HDF5 metadata: mix() over each 12-byte
    block but the last, final() after adding the last (zero-padded) block."""
    mask = 0xFFFFFFFF

    def rot(x, k):
        return (x << k | x >> (32 - k)) & mask

    h = [(0xDEADBEEF + len(data) + initval) & mask] * 3  # a, b, c
    if not data:
        return h[2]
    padded = data + bytes(-len(data) % 12)
    blocks = [struct.unpack_from("<3I", padded, i) for i in range(0, len(padded), 12)]
    for block in blocks:
        h = [(x + w) & mask for x, w in zip(h, block, strict=True)]
        if block is blocks[-1]:
            break
        for i, r in enumerate((4, 6, 8, 16, 19, 4)):  # x -= z; x ^= rot(z, r); z += y
            x, y, z = i % 3, (i + 1) % 3, (i + 2) % 3
            h[x] = (h[x] - h[z]) & mask ^ rot(h[z], r)
            h[z] = (h[z] + h[y]) & mask
    for i, r in enumerate((14, 11, 25, 16, 4, 14, 24)):  # x ^= y; x -= rot(y, r)
        x = (2 + i) % 3
        y = (x + 2) % 3
        h[x] = (h[x] ^ h[y]) - rot(h[y], r) & mask
    return h[2]
