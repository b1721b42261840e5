"""Windows of a recorded stream found by time and read by row range, so that a reduction costs
time linear in the session and holds one window's samples at a time.

A window [t0, t1] (clock s) holds the samples whose sampling instant (`station.reduce.timeline.
sample_times`) lies in it. The instants increase within a segment of the stream, are NaN for the
samples that belong to no window (held back across a resume), and may start over at a segment's
start (a resumed session's clock, a device that restarted): so the stream is cut into runs of
increasing instants, and a window is, per run, the row range `np.searchsorted` finds in it -
the same rows, in the same order, as the mask `(t >= t0) & (t <= t1)` over the whole stream.
`StreamWindows` reads the stream's timing columns once, keeps the instants, and cuts each
window's counts from blocks of the file's rows (`RowBlocks`: `BLOCK_BYTES` read at once by
`station.session.Session.stream`, one refresh of the datasets each, sliced in memory);
`table_angle` cuts the table states around a window from blocks likewise (`table_blocks`). A pass
over the windows in order thus makes a few large reads, not one per window (a 2000-position
session made about 6000), and holds one block beside the window.
"""

import numpy as np

from station.reduce.timeline import sample_times, segment_breaks

BLOCK_BYTES = 1 << 23
"""Bytes of a column set read from the file at once (8 MB: a replay's peak RSS stays within issue
17's 200 MB + 0.2 x the file's size; 32 MB took a 2000-position replay from 174 to 256 MB)."""


def increasing_runs(t) -> np.ndarray:
    """(r, 2) [start, stop) row ranges of `t` over which it is finite and strictly increasing,
    covering every finite value, in row order."""
    t = np.asarray(t, float)
    rising = t[1:] > t[:-1]  # False where either is NaN
    finite = np.isfinite(t)
    first = np.flatnonzero(finite & np.concatenate([[True], ~rising]))
    last = np.flatnonzero(finite & np.concatenate([~rising, [True]]))
    return np.column_stack([first, last + 1])


def window_ranges(t, runs, t0: float, t1: float, closed: bool = True) -> list:
    """[(start, stop), ...] row ranges of the values of `t` in [t0, t1] ([t0, t1) unless
    `closed`), in row order; `runs`: `increasing_runs(t)`. The rows are those of
    `np.flatnonzero((t >= t0) & (t <= t1))` (`t < t1` unless `closed`)."""
    ranges = []
    for a, b in runs:
        part = t[a:b]
        lo = a + int(np.searchsorted(part, t0, side="left"))
        hi = a + int(np.searchsorted(part, t1, side="right" if closed else "left"))
        if hi > lo:
            ranges.append((lo, hi))
    return ranges


class StreamWindows:
    """A recorded stream's sampling instants, and its samples read window by window.

    t    : (k,) sampling instant of each clock row (the rows whose timing columns read back
           intact; NaN: in no window)
    rows : (k,) the file row of each clock row (None: row i, no chunk damaged)
    Only these are held (8 or 16 bytes a sample); the timing columns themselves are read and let go,
    unless the caller passes them in as `clock` (`Session.stream` with at least the columns
    "seq" and "host_time").
    """

    def __init__(self, session, name: str, events, clock=None):
        self._session, self._name = session, name
        if clock is None:
            clock = session.stream(name, columns=("seq", "host_time"))
        self.spec, self.rows = clock.spec, clock.rows
        self.t = sample_times(clock.seq, clock.host_time, self.spec.rate_hz,
                              segment_breaks(events))
        del clock  # the timing columns go before the runs are found (unless the caller keeps them)
        self._runs = increasing_runs(self.t)
        width = len(self.spec.channels) * np.dtype(self.spec.dtype).itemsize
        self._counts = RowBlocks(self._read_counts, BLOCK_BYTES // max(width, 1))

    def _read_counts(self, start: int, stop: int) -> tuple:
        """([counts], rows) of the stream's file rows [start, stop) (`Session.stream`)."""
        part = self._session.stream(self._name, start, stop, columns=("counts",))
        return [part.counts], part.rows

    def ranges(self, t0: float, t1: float, closed: bool = True) -> list:
        """Row ranges of the clock rows whose instant lies in [t0, t1] ([t0, t1) unless
        `closed`), in order (`window_ranges`)."""
        return window_ranges(self.t, self._runs, t0, t1, closed)

    def index(self, t0: float, t1: float) -> np.ndarray:
        """The clock rows whose instant lies in [t0, t1], in order (their counts not read)."""
        return _concat([np.arange(a, b) for a, b in self.ranges(t0, t1)], np.int64)

    def count(self, t0: float, t1: float, closed: bool = True) -> int:
        """How many clock rows have their instant in the window (`ranges`)."""
        return sum(b - a for a, b in self.ranges(t0, t1, closed))

    def first(self, t0: float) -> int:
        """The first clock row at or after instant t0 (the row count if none is): on a stream of
        one run, `np.searchsorted(t, t0)`."""
        found = self.ranges(t0, np.inf)
        return found[0][0] if found else len(self.t)

    def read(self, t0: float, t1: float) -> tuple:
        """(index, counts): the clock rows whose instant lies in [t0, t1] (`read_rows`)."""
        return self.read_rows(self.ranges(t0, t1))

    def read_rows(self, ranges) -> tuple:
        """(index, counts): the clock rows of `ranges` ([(start, stop), ...]) whose counts read
        back intact (rows of a damaged chunk are left out, as the whole-stream read leaves them),
        and their counts (len(index), m), cut from the file's rows read in blocks (`RowBlocks`)."""
        index, counts = [], []
        for a, b in ranges:
            rows = np.arange(a, b) if self.rows is None else self.rows[a:b]
            (part,), got = self._counts(int(rows[0]), int(rows[-1]) + 1)
            keep = np.arange(a, b)
            if got is not None:  # rows of a damaged counts chunk: left out
                keep = keep[np.isin(rows, got)]
            index.append(keep)
            counts.append(part)
        m = len(self.spec.channels)
        return _concat(index, np.int64), _concat(counts, np.dtype(self.spec.dtype), (0, m))


def _concat(parts: list, dtype, empty=(0,)) -> np.ndarray:
    """The parts joined along the first axis; an empty array of `dtype` and shape `empty` when
    there are none."""
    return np.concatenate(parts) if parts else np.zeros(empty, dtype)


class RowBlocks:
    """Rows [start, stop) of a set of columns of a file, read at least `size` rows at a time and
    cut in memory: `read(start, stop)` -> (columns, rows), the rows that read back intact as
    `Session.stream` and `Session.table` give them (rows: the file row of each value, None: all
    of [start, stop)). A request (rows of the file) inside the block read last is cut from it;
    any other reads a new block from its start. Rows of damaged chunks are found per chunk, so a
    cut gives what a read of [start, stop) itself gives."""

    def __init__(self, read, size: int):
        self._read, self._size = read, max(int(size), 1)
        self._start, self._stop, self._columns, self._rows = 0, 0, [], None

    def __call__(self, start: int, stop: int) -> tuple:
        """(columns, rows) of the file rows [start, stop)."""
        if start < self._start or stop > self._stop:
            self._start, self._stop = start, max(stop, start + self._size)
            self._columns, self._rows = self._read(self._start, self._stop)
        if self._rows is None:
            cut = slice(start - self._start, stop - self._start)
            return [c[cut] for c in self._columns], None
        lo, hi = np.searchsorted(self._rows, (start, stop))
        whole = hi - lo == stop - start  # every row of the range read back: rows None, as a read
        return [c[lo:hi] for c in self._columns], None if whole else self._rows[lo:hi]


def table_blocks(session) -> RowBlocks:
    """The table's states (time, angle) of an open session read in blocks (`RowBlocks`), for
    `table_angle`."""
    def read(start: int, stop: int) -> tuple:
        part = session.table(start, stop)
        return [part.time, part.angle], part.rows

    return RowBlocks(read, BLOCK_BYTES // 40)  # 5 columns of 8 bytes a state


def table_angle(blocks, times, t) -> np.ndarray:
    """The recorded table angle interpolated at the instants `t` as `np.interp` over all the
    table's states does, reading only the states from the last one at or before min(t) to the
    first one at or after max(t); `blocks`: `table_blocks(session)`, `times`:
    `session.table_times()`."""
    time, rows = times
    if np.size(t) == 0:
        return np.zeros(0)
    lo = max(int(np.searchsorted(time, np.min(t), side="right")) - 1, 0)
    hi = min(int(np.searchsorted(time, np.max(t), side="left")) + 1, len(time))
    first, last = time[lo], time[hi - 1]
    while True:
        start, last_row = (int(i if rows is None else rows[i]) for i in (lo, hi - 1))
        (state_time, angle), _ = blocks(start, last_row + 1)
        whole = lo == 0 and hi == len(time)
        if whole or (len(state_time) and state_time[0] <= first and state_time[-1] >= last):
            return np.interp(t, state_time, angle)
        lo, hi = max(2 * lo - hi, 0), min(2 * hi - lo, len(time))  # damaged states: widen
