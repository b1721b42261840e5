"""Binary frames of serial IMUs, parsed in bulk.

Binary frame (from the device profile, `[serial.binary]`):

    sync | fields | check

The fields are typed (drivers/wire/fields.py): channels, sequence number, device time, constants
(message id, length byte), status words; the one-block layout of earlier profiles
(sync | sequence number | length | device time | m channel counts | CRC) is a special case. The
check is any frame check of `drivers.wire.crc.CHECKSUMS` (a CRC, a byte sum, XOR, Fletcher), and
every constant field must hold its value (a frame with another message id or length is refused
like one failing its check). Parsing is vectorised with numpy: every position where the sync word
occurs is a candidate, all candidates' checks are computed at once, and the frames are decoded
through a structured dtype. Frames without a sequence field count their device time in
`seq_step` ticks instead.

CRC-16 alone accepts about one corrupted candidate in 65 536. A CRC-valid candidate is therefore
accepted only if its sequence number is also consistent with a neighbour: the previous or the next
CRC-valid candidate that does not overlap it must be 1..max_gap sequence numbers away (modulo the
counter width). A false lock (a sync word inside the payload or in garbage whose CRC happens to
match) then also needs a sequence field within max_gap of a neighbour's, a further factor
max_gap / 2**bits. The decision depends only on the byte stream, not on how it was cut into reads.

A candidate whose header (sync, sequence) survived but whose payload was corrupted so that CRC-16
still matches cannot be told from an intact frame by any check on this format; a profile may choose
`crc32` to make that 2**16 times rarer. Weaker checks (8-bit sums, XOR) make the sequence check
carry more of the load: `bench/serial.py` measures both.
"""

import bisect
from typing import NamedTuple

import numpy as np
from numpy.lib.stride_tricks import as_strided

from drivers.samples import SampleBlock, restart_seq
from drivers.wire import Decoded, SerialStats
from drivers.wire.crc import CHECKSUMS
from drivers.wire.fields import FrameLayout


def encode_frames(fmt, seq, ticks, counts, channels=None, scale=None) -> bytes:
    """Bytes of consecutive frames: raw sequence numbers, raw device-time ticks, counts (k, m).

    Values are wrapped to the field widths for seq and ticks; counts must fit their fields.
    `channels` and `scale` are the `[imu]` channel names and counts per SI unit (needed by
    profiles whose fields name channels or convert them).
    """
    counts = np.asarray(counts)
    layout = FrameLayout(fmt, channels or [f"c{j}" for j in range(counts.shape[1])], scale)
    frames = layout.records(seq, ticks, counts)
    raw = frames.view(np.uint8).reshape(len(frames), layout.dtype.itemsize)
    crc = CHECKSUMS[fmt.crc]
    frames["crc"] = crc.rows(raw[:, _crc_start(fmt):layout.dtype.itemsize - crc.size])
    return frames.tobytes()


def _crc_start(fmt) -> int:
    """First byte of a frame covered by the CRC."""
    return 0 if fmt.crc_covers_sync else len(fmt.sync)


def _unwrap(raw: np.ndarray, steps: np.ndarray, restart: np.ndarray, last: int,
            modulus: int) -> np.ndarray:
    """Unwrapped counter values: `last` plus the forward `steps`, except that each `restart`
    begins a new segment at `restart_seq` (the counter values before are not moved)."""
    out = last + np.cumsum(steps)
    for i in np.flatnonzero(restart):  # rare: a device reset
        before = out[i - 1] if i else last
        out[i:] += restart_seq(int(raw[i]), int(before), modulus) - out[i]
    return out


def _within(a: np.ndarray, b: np.ndarray, gap: int, modulus: int) -> np.ndarray:
    """Whether counter value b (int64) is 1..gap steps forward from a, modulo the counter width
    (equal values are `modulus` steps apart)."""
    return (b - a - 1) % modulus < gap


def _windows(a: np.ndarray, width: int) -> np.ndarray:
    """Every run of `width` consecutive items of the 1-d array `a`, as rows of a read-only view
    (numpy's sliding_window_view without its checks, which cost more than a small read's
    parsing)."""
    stride = a.strides[0]
    return as_strided(a, (max(len(a) - width + 1, 0), width), (stride, stride), writeable=False)


def _where(array: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """The items of `array` where `keep` holds: `array` itself when it holds everywhere (the
    usual case of a clean stream, without a copy)."""
    return array if keep.all() else array[keep]


class _Frames(NamedTuple):
    """Decoded frames: raw sequence numbers and device-time ticks (int64, ticks 0 without a time
    field), counts (k, m) int64 and the device's validity."""

    seq: np.ndarray
    ticks: np.ndarray
    counts: np.ndarray
    valid: np.ndarray

    def where(self, keep: np.ndarray) -> "_Frames":
        """The frames where `keep` holds."""
        return self if keep.all() else _Frames(*(a[keep] for a in self))


class _HostTimes:
    """Host time of each received chunk, to stamp a frame with the read that completed it."""

    def __init__(self):
        self._ends = []  # absolute end offset of each chunk, increasing
        self._times = []

    def add(self, end: int, host_time: float) -> None:
        self._ends.append(end)
        self._times.append(host_time)

    def at(self, ends: np.ndarray) -> np.ndarray:
        """Host time of the chunk holding byte `end - 1` for each absolute end offset."""
        return np.array(self._times, float)[np.searchsorted(self._ends, ends, side="left")]

    def drop_before(self, offset: int) -> None:
        """Forget the chunks that end at or before `offset`."""
        done = bisect.bisect_right(self._ends, offset)
        del self._ends[:done], self._times[:done]


REPEATS = 16
"""A frame equal to one of the last this many (number, device time and counts) is a duplicate."""


class BinaryFrameParser:
    """Incremental bulk parser of a binary frame stream (rules in the module docstring).

    `decode(data, host_time)` returns the frames accepted by the call (the wire package's
    contract: `Decoded(used, block)`). A CRC-valid
    candidate whose previous neighbour does not vouch for it waits until the next CRC-valid
    candidate starting within `horizon` bytes has arrived (or cannot arrive any more); its bytes
    stay buffered meanwhile.
    """

    def __init__(self, fmt, channels, scale=None):
        self.fmt = fmt
        self.channels = tuple(channels)
        self.layout = FrameLayout(fmt, self.channels, scale)
        self.dtype = self.layout.dtype
        self.size = self.dtype.itemsize
        self.horizon = 16 * self.size
        self.crc = CHECKSUMS[fmt.crc]
        self.sync = np.frombuffer(fmt.sync, dtype=np.uint8)
        self.seq_modulus = self.layout.seq_modulus
        self.time_modulus = self.layout.time_modulus
        self.length_rule = self.layout.length_rule()
        self._others = {}  # absolute position -> bytes of checked other messages not yet passed
        self.stats = SerialStats()
        self._base = 0  # absolute stream offset of the first buffered byte
        self._buf = b""
        self._last = None  # last accepted frame: (absolute end, raw seq, seq, raw ticks, ticks)
        # keys (raw seq, raw ticks, counts) of the last REPEATS frames; at first rows of -1,
        # which no frame equals (raw ticks are >= 0)
        self._recent = np.full((REPEATS, 2 + len(self.channels)), -1, np.int64)
        self.reset()

    def reset(self) -> None:
        """Forget buffered bytes (a new connection); counters and sequence unwrapping go on."""
        self._base += len(self._buf)
        self._buf = b""
        self._connection_start = self._base
        self._context = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, bool))
        self._host = _HostTimes()

    def decode(self, data: bytes, host_time: float, final: bool = False) -> Decoded:
        """Add received bytes; the bytes decided and the frames accepted by this call (possibly
        none). `final`: no more bytes will come (device lost): decide everything now."""
        self.stats.bytes += len(data)
        self._host.add(self._base + len(self._buf) + len(data), host_time)
        buf = np.frombuffer(self._buf + bytes(data), dtype=np.uint8)
        n, size = len(buf), self.size

        starts = self._sync_positions(buf)
        complete = starts[starts + size <= n]
        rows = _windows(buf, size)[complete]
        records = rows.view(self.dtype).reshape(-1)
        crc_ok = (self.crc.rows(rows[:, _crc_start(self.fmt) : size - self.crc.size])
                  == records["crc"])
        crc_ok &= self.layout.constants_hold(records)
        valid, frames = _where(complete, crc_ok), self._decoded(_where(records, crc_ok))

        ctx_pos, ctx_seq, ctx_acc = self._context
        n_ctx = len(ctx_pos)
        pos = np.concatenate([ctx_pos - self._base, valid])
        seq = np.concatenate([ctx_seq, frames.seq])
        links, near = self._links(pos, seq)
        accept = self._without_overlaps(pos, seq, np.concatenate([ctx_acc, links[n_ctx:]]), n_ctx)
        cut = n if final else self._cut(pos, links, near, n_ctx, n, starts)
        if self.length_rule:
            cut = self._other_messages(buf, self._outside(starts, valid), cut, final)
        decided = np.concatenate([np.ones(n_ctx, bool), valid < cut])
        accept &= decided

        taken = accept[n_ctx:]
        block = self._emit(_where(valid, taken), frames.where(taken))
        failed = complete[~crc_ok]
        self._count_crc_failures(failed[failed < cut], pos[accept])
        self._keep(pos, seq, accept, decided, cut, buf)
        return Decoded(int(cut), block)

    def _decoded(self, records: np.ndarray) -> _Frames:
        """The frames of check-passing records."""
        return _Frames(self.layout.seq(records), self.layout.ticks(records),
                       *self.layout.samples(records))

    def _other_messages(self, buf: np.ndarray, starts: np.ndarray, cut: int, final: bool) -> int:
        """Remember the messages of other ids before `cut` whose check holds over the length their
        length field gives (absolute position -> bytes); the cut, moved back to the first one not
        complete yet (so that its bytes stay buffered until it is)."""
        if not len(starts) or starts[0] >= cut:  # the usual case: none before the cut
            return cut
        offset, code, adds = self.length_rule
        n, first, check = len(buf), _crc_start(self.fmt), self.crc
        width = np.dtype(code).itemsize
        known = starts[starts + offset + width <= n]
        total = np.zeros(len(known), np.int64)
        if len(known):
            fields = _windows(buf, width)[known + offset]
            total = fields.copy().view(code).reshape(-1).astype(np.int64) + adds
        complete = known + total <= n
        if not final:
            waiting = [*starts[starts + offset + width > n][:1], *known[~complete][:1]]
            cut = min([cut, *waiting])
        order = "<" if (self.fmt.crc_byte_order or self.fmt.byte_order) == "little" else ">"
        for length in np.unique(total[complete & (known < cut) & (total > first + check.size)]):
            at = known[complete & (known < cut) & (total == length)]
            rows = _windows(buf, int(length))[at]
            sent = rows[:, length - check.size :].copy().view(f"{order}u{check.size}").reshape(-1)
            ok = check.rows(rows[:, first : length - check.size]) == sent
            self._others.update(zip((at[ok] + self._base).tolist(), [int(length)] * int(ok.sum()),
                                    strict=True))
        if len(self._others) > 100_000:  # a long run of other messages only: its gap is skipped
            self._others.clear()
        return cut

    def _outside(self, starts: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """The sync positions that lie in no frame passing its check and constants (only those
        can begin other messages between accepted frames)."""
        if not len(valid):
            return starts
        i = np.searchsorted(valid, starts, side="right") - 1
        return starts[(i < 0) | (starts >= valid[np.maximum(i, 0)] + self.size)]

    def _tiled(self, previous_ends: np.ndarray, starts: np.ndarray) -> np.ndarray:
        """Whether the bytes between each accepted frame and the one before are exactly a chain of
        other messages (skipped by their length, counted in `other_messages`, not a resync)."""
        tiled = np.zeros(len(starts), bool)
        if not self.length_rule:
            return tiled
        for i in np.flatnonzero(starts > previous_ends):
            at, chain = int(previous_ends[i]), 0
            while at < starts[i] and at in self._others:
                at, chain = at + self._others[at], chain + 1
            if at == starts[i]:
                tiled[i] = True
                self.stats.other_messages += chain
        if len(starts):
            self._others = {p: t for p, t in self._others.items() if p >= starts[-1]}
        return tiled

    def _sync_positions(self, buf: np.ndarray) -> np.ndarray:
        """Every offset where the whole sync word starts."""
        k = len(self.sync)
        if len(buf) < k:
            return np.zeros(0, dtype=np.int64)
        hit = buf[: len(buf) - k + 1] == self.sync[0]
        for i in range(1, k):
            hit &= buf[i : len(buf) - k + 1 + i] == self.sync[i]
        return np.flatnonzero(hit)

    def _links(self, pos: np.ndarray, seq: np.ndarray) -> tuple:
        """Whether each CRC-valid candidate's sequence number is consistent with a neighbour, and
        whether its next neighbour is known.

        Neighbours: the nearest CRC-valid candidates ending before it starts (previous) and
        starting after it ends, within `horizon` bytes (next); consistent = 1..max_gap steps.
        """
        if len(pos) == 0:
            return np.zeros(0, bool), np.zeros(0, bool)
        size, gap, last = self.size, self.fmt.max_gap, len(pos) - 1
        prev = np.searchsorted(pos, pos - size, side="right") - 1
        nxt = np.searchsorted(pos, pos + size, side="left")
        back = (prev >= 0) & _within(seq[prev], seq, gap, self.seq_modulus)
        near = (nxt <= last) & (pos[np.minimum(nxt, last)] < pos + self.horizon)
        fwd = near & _within(seq, seq[np.minimum(nxt, last)], gap, self.seq_modulus)
        return back | fwd, near

    def _cut(self, pos, links, near, n_ctx, n, starts) -> int:
        """First buffer offset not yet decided: a possible partial sync word at the end, an
        incomplete candidate, a candidate some overlapping candidate could still come for, or one
        overlapping a candidate still waiting for its next neighbour."""
        size, new_pos = self.size, pos[n_ctx:]
        waiting = ~links[n_ctx:] & ~near[n_ctx:] & (n < new_pos + self.horizon + size - 1)
        unsettled = new_pos + 2 * size - 1 > n
        overlapping_waiting = (new_pos[new_pos > new_pos[waiting][0] - size][:1]
                               if waiting.any() else [])
        incomplete = starts[starts + size > n]
        return max(0, min([n - len(self.sync) + 1, *incomplete[:1], *new_pos[unsettled][:1],
                           *overlapping_waiting]))

    def _without_overlaps(self, pos, seq, accept, n_ctx) -> np.ndarray:
        """Resolve accepted candidates that overlap (context ones are final).

        If the later one's sequence number follows the earlier one's, the earlier frame lost bytes
        and its CRC matched by chance: drop it. Otherwise the later one is a false lock inside the
        earlier frame: drop it. Only damage or false locks overlap, so this loop rarely runs.
        """
        accepted = np.flatnonzero(accept)
        if np.all(np.diff(pos[accepted]) >= self.size):
            return accept
        accept, kept = accept.copy(), []
        for i in accepted:
            while kept and pos[i] < pos[kept[-1]] + self.size:
                j = kept[-1]
                if j >= n_ctx and _within(seq[j], seq[i], self.fmt.max_gap, self.seq_modulus):
                    accept[j] = False
                    kept.pop()
                else:
                    accept[i] = False
                    break
            else:
                kept.append(i)
        return accept

    def _emit(self, rel_pos: np.ndarray, frames: _Frames) -> SampleBlock:
        """SampleBlock of newly accepted frames; updates unwrapping state and counters.

        Before unwrapping, each frame is compared with the last `REPEATS` frames accepted before
        it: the same sequence number, device time and counts as one of them is a duplicate (a
        CRC-valid resend of a frame or of a buffer of frames: dropped, counted); a number that
        goes back, or a device time that goes back, is a restart of the device (a new segment,
        `restart_seq`; the frames before keep their numbers); only a forward jump is a gap.
        """
        ends = self._base + rel_pos + self.size
        if len(ends) and self._last is None:  # the very first frame: 1 step after a virtual one
            seq_raw, ticks_raw = frames.seq[0], frames.ticks[0]
            self._last = (self._connection_start, (seq_raw - 1) % self.seq_modulus,
                          seq_raw - 1, ticks_raw, ticks_raw)
        if len(ends):
            self._count_skips(ends)
            fresh = self._fresh(frames)
            self.stats.duplicates += int(np.count_nonzero(~fresh))
            ends, frames = _where(ends, fresh), frames.where(fresh)
        seq, device_time = self._unwrapped(frames)
        valid = frames.valid
        samples = int(np.count_nonzero(valid))
        self.stats.invalid += len(valid) - samples
        self.stats.samples += samples
        return SampleBlock(
            counts=_where(frames.counts, valid),
            seq=_where(seq, valid),
            device_time=_where(device_time, valid),
            host_time=self._host.at(_where(ends, valid)),
            channels=self.channels,
        )

    def _unwrapped(self, frames: _Frames) -> tuple:
        """(sequence numbers, device times in seconds) of fresh frames, unwrapped after the last
        accepted frame; counts restarts, gaps and dropped frames."""
        k, stats = len(frames.seq), self.stats
        if k == 0:
            return np.zeros(0, np.int64), np.zeros(0)
        seq_raw, ticks_raw = frames.seq, frames.ticks
        _, last_seq_raw, last_seq, last_ticks_raw, last_ticks = self._last
        steps = (seq_raw - np.concatenate([[last_seq_raw], seq_raw[:-1]])) % self.seq_modulus
        restart = (steps == 0) | (steps > self.seq_modulus // 2)
        if self.time_modulus:
            dt = (ticks_raw - np.concatenate([[last_ticks_raw], ticks_raw[:-1]])) \
                % self.time_modulus
            restart |= dt > self.time_modulus // 2  # the device clock went back
        seq = _unwrap(seq_raw, steps, restart, last_seq, self.seq_modulus)
        stats.restarts += int(np.count_nonzero(restart))
        stats.gaps += int(np.count_nonzero((steps > 1) & ~restart))
        stats.dropped += int(np.sum(np.where(restart, 0, steps - 1)))
        if self.time_modulus:
            ticks = _unwrap(ticks_raw, dt, restart, last_ticks, self.time_modulus)
            device_time = ticks * self.fmt.time_tick
        else:
            ticks = np.zeros(k, np.int64)
            device_time = np.full(k, np.nan)
        self._last = (self._last[0], int(seq_raw[-1]), int(seq[-1]),
                      int(ticks_raw[-1]), int(ticks[-1]))
        return seq, device_time

    def _fresh(self, frames: _Frames) -> np.ndarray:
        """Which frames repeat none of the `REPEATS` frames before them (earlier blocks' kept in
        `_recent`) in raw sequence number, raw ticks and counts.

        Where every step between consecutive numbers is 1..modulus / REPEATS (modulo the
        counter), no number can equal one of the REPEATS before it: nothing to compare."""
        numbers = np.concatenate([self._recent[:, 0], frames.seq])
        steps = np.diff(numbers) % self.seq_modulus
        if steps.min() >= 1 and steps.max() * REPEATS < self.seq_modulus:
            self._recent = np.concatenate([self._recent, self._keys(frames, -REPEATS)])[-REPEATS:]
            return np.ones(len(frames.seq), bool)
        rows = np.concatenate([self._recent, self._keys(frames, 0)])
        numbers = _windows(rows[:, 0], REPEATS + 1)  # each frame's and those before
        same = numbers[:, :-1] == numbers[:, -1:]  # (frame, earlier frame) of the same number
        frame, earlier = np.nonzero(same)  # the whole rows compared only there
        same[frame, earlier] = np.all(rows[frame + REPEATS] == rows[frame + earlier], axis=1)
        self._recent = rows[-REPEATS:]
        return ~same.any(axis=1)

    @staticmethod
    def _keys(frames: _Frames, first: int) -> np.ndarray:
        """Rows (raw seq, raw ticks, counts...) of the frames from index `first` on."""
        return np.column_stack([frames.seq[first:], frames.ticks[first:], frames.counts[first:]])

    def _count_skips(self, ends: np.ndarray) -> None:
        """Count the bytes between accepted frames (ending at `ends`) and the resyncs; the last
        frame's end is kept in `_last`."""
        last_end = self._last[0]
        starts = ends - self.size
        previous_ends = np.concatenate([[max(last_end, self._connection_start)], ends[:-1]])
        skipped = np.where(self._tiled(previous_ends, starts), 0, starts - previous_ends)
        self.stats.skipped_bytes += int(np.sum(np.maximum(skipped, 0)))
        resynced = skipped != 0
        if last_end <= self._connection_start:
            resynced[0] = False  # first frame of a new connection
        self.stats.resyncs += int(np.count_nonzero(resynced))
        self._last = (int(ends[-1]), *self._last[1:])

    def _count_crc_failures(self, failed: np.ndarray, accepted: np.ndarray) -> None:
        """Count CRC-failing candidates that do not lie inside an accepted frame."""
        if len(accepted):
            i = np.searchsorted(accepted, failed, side="right") - 1
            failed = failed[(i < 0) | (failed >= accepted[np.maximum(i, 0)] + self.size)]
        self.stats.crc_failures += len(failed)

    def _keep(self, pos, seq, accept, decided, cut, buf) -> None:
        """Buffer the undecided bytes and remember the decided candidates later ones may neighbour:
        the last one ending before the cut and all that overlap it."""
        tail = decided & (pos > cut - self.size)
        before = np.flatnonzero(decided & (pos <= cut - self.size))
        if len(before):
            tail[before[-1]] = True
        self._context = (pos[tail] + self._base, seq[tail], accept[tail])
        self._buf = bytes(buf[cut:])
        self._base += cut
        self._host.drop_before(self._base)
