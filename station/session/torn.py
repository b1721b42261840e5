"""Chunks whose rewrite a kill cut short: the rows their old checksum still vouches for.

A session's columns grow by appends, and HDF5 rewrites the last chunk of a column in place on
every flush: the chunk's data first, then the 4-byte fletcher32 checksum after it (HDF5 filter
H5Z_FILTER_FLETCHER32; the checksum is H5_checksum_fletcher32 over the chunk's bytes taken as
big-endian 16-bit words, sums with end-around carry, i.e. modulo 65535). A writer killed inside
that write leaves the new rows (some of them) beside the OLD checksum, and the chunk no longer
reads back: every row of it, the durable ones flushed before included, would be lost.

The old checksum was computed over the chunk as it stood after the last complete flush: its first
r rows and the fill value (zero bytes) after them. The rows the chunk still holds before r are the
same bytes (an append never rewrites earlier rows with other values), so the prefix r whose
checksum equals the stored one is found from prefix sums of the current bytes (one pass) and its
rows are intact; the rows after it are the interrupted flush's, never reported durable, and are
dropped. A damaged chunk (a flipped or zeroed block) matches no prefix, except by a chance
collision of the 32-bit checksum, and stays unreadable; a zero checksum (a zeroed chunk, or bytes
read past a truncated file's end) vouches for nothing.
"""

import numpy as np

MODULUS = 65535


def verified_rows(ds, start: int) -> np.ndarray | None:
    """The rows [start, start + r) of the chunk of `ds` that begins at row `start` which its
    stored checksum still vouches for (largest such r within the dataset's extent), or None when
    the chunk is not a fletcher32-only chunk with a zero fill, or no prefix matches."""
    if not _plain_fletcher32(ds):
        return None
    offset = (start,) + (0,) * (ds.ndim - 1)
    try:
        mask, raw = ds.id.read_direct_chunk(offset)
    except (OSError, KeyError, ValueError, RuntimeError):  # RuntimeError: HDF5's "addr overflow",
        return None  # a chunk whose new place a kill left beyond the file's end
    row_bytes = ds.dtype.itemsize * int(np.prod(ds.chunks[1:], dtype=np.int64))
    data = np.frombuffer(raw, np.uint8)[:-4]
    if mask != 0 or len(raw) < 4 or data.size != row_bytes * ds.chunks[0]:
        return None
    rows = min(ds.chunks[0], ds.shape[0] - start)
    sums = _prefix_sums(data, row_bytes, rows)
    stored = int.from_bytes(raw[-4:], "little")
    # a zero checksum is that of zero bytes: a zeroed chunk, or one read past a truncated
    # file's end, would vouch for rows of zeros; it vouches for nothing
    wanted = {_reduced(stored), _reduced(int.from_bytes(raw[-4:], "big"))} - {(0, 0)}
    r = next((r for r in range(rows, -1, -1) if sums[r] in wanted), None)
    if r is None:
        return None
    return data[:r * row_bytes].view(ds.dtype).reshape(r, *ds.shape[1:]).copy()


def tail_starts(ds) -> list:
    """First rows of the column's last two chunks: a flush rewrites the last one, and may fill
    it and start the next, so only these can be torn by a kill."""
    size, n = ds.chunks[0], ds.shape[0]
    last = (n - 1) // size * size if n else 0
    return [start for start in (last - size, last) if start >= 0]


def tail_rows(ds, start: int) -> np.ndarray | None:
    """`verified_rows` of the chunk at row `start` when it is one of the column's last two (a
    rewrite cut by a kill), None elsewhere: damage in earlier chunks is never read as a tear."""
    return verified_rows(ds, start) if start in tail_starts(ds) else None


def repair_tail(ds) -> int:
    """Before appending to `ds` again: when one of its last two chunks does not read back, cut
    the column at that chunk's start and write back the rows its checksum vouches for (with a
    fresh checksum); returns the rows dropped (0 when the tail reads back)."""
    n = ds.shape[0]
    torn = [start for start in tail_starts(ds) if not _reads(ds, start, n)]
    if not torn:
        return 0
    start = torn[0]
    rows = verified_rows(ds, start)
    kept = 0 if rows is None else len(rows)
    ds.resize(start, axis=0)
    if kept:
        ds.resize(start + kept, axis=0)
        ds[start:] = rows
    return n - start - kept


def _reads(ds, start: int, n: int) -> bool:
    """Whether the rows of the chunk at `start` read back (their checksum holds)."""
    try:
        ds[start:min(start + ds.chunks[0], n)]
    except (OSError, RuntimeError):
        return False
    return True


def _plain_fletcher32(ds) -> bool:
    """Chunked, fletcher32 the only filter, a zero fill value: the layout `verified_rows` reads."""
    filters = ds.id.get_create_plist().get_nfilters()
    fill = np.asarray(ds.fillvalue, ds.dtype).reshape(1)
    return (ds.chunks is not None and ds.fletcher32 and filters == 1
            and not np.any(fill.view(np.uint8)))


def _prefix_sums(data: np.ndarray, row_bytes: int, rows: int) -> list:
    """[(sum2, sum1) mod 65535 of the chunk's first r rows followed by zero bytes, r = 0..rows].

    Byte j lies in word j // 2, high byte when j is even: it adds c_j b_j to sum1 (c_j = 256 or
    1) and (W - j // 2) c_j b_j to sum2, W the chunk's number of words (each word's value enters
    sum2 once per word from it to the end)."""
    b = data.astype(np.int64)
    j = np.arange(b.size)
    words = (b.size + 1) // 2
    value = np.where(j % 2 == 0, 256, 1) * b
    s1 = np.concatenate([[0], np.cumsum(value)])
    s2 = np.concatenate([[0], np.cumsum((words - j // 2) * value)])
    ends = np.arange(rows + 1) * row_bytes
    return list(zip((s2[ends] % MODULUS).tolist(), (s1[ends] % MODULUS).tolist(), strict=True))


def _reduced(checksum: int) -> tuple:
    """(sum2, sum1) of a stored checksum, modulo 65535 (0xffff and 0 are the same residue)."""
    return (checksum >> 16) % MODULUS, (checksum & 0xFFFF) % MODULUS
