"""When each recorded sample was taken: sampling instants on the session clock from sequence
numbers and arrival times.

A recorded stream holds, per sample, the device's sequence number and the host's arrival time. The
arrival is later than the sampling by a latency that grows when the host is busy; the sequence
number is exact up to a constant. A lost device (reconnected) or a resumed session starts a new
segment of the stream, in which the numbering may jump or restart: the events after which it does
are `SEGMENT_EVENTS`, and `sample_times` works the instants out per segment.
"""

import numpy as np

SEGMENT_EVENTS = ("resume", "session_resumed")
"""Events after which the IMU stream is a new segment (see `sample_times`)."""


def arrival_offset(seq, host_time, rate_hz: float) -> float:
    """The smallest host_time - seq / rate_hz: sampling instant of sample 0 on the host clock.

    host_time is the arrival time: later than the sampling by a latency that grows when the host
    is busy, and one time for all samples read together. seq / rate_hz is exact up to a constant
    (and the device's clock error: 50 ppm is 35 ms over a 700 s session, well inside a protocol's
    guard times); the least delayed sample gives the constant.
    """
    return float(np.min(np.asarray(host_time, float) - np.asarray(seq, float) / rate_hz))


def sample_times(seq, host_time, rate_hz: float, breaks=()) -> np.ndarray:
    """Sampling instants (clock s) of samples numbered `seq` at `rate_hz`, read at `host_time`.

    The stream is cut into segments, each with its own `arrival_offset`: before each clock time
    in `breaks` (a reconnection, a resumed session) and wherever `seq` does not increase (a device
    that restarted its numbering). A sample received after a break but taken before it (a device
    or a buffer that held samples back while the station was down: they arrive in a burst after
    the resume) is NaN: it belongs to no window of either side. On a resumed session's clock,
    which continues after the file's last instant, such samples would otherwise fall onto the
    windows recorded before the interruption.
    """
    seq, host_time = np.asarray(seq), np.asarray(host_time, float)
    starts = np.concatenate([[-np.inf], np.sort(np.asarray(breaks, float))])
    offsets = {}
    for rows, segment, _ in _segments(seq, host_time, starts):
        for k in np.unique(segment):
            part = segment == k
            offset = arrival_offset(seq[rows][part], host_time[rows][part], rate_hz)
            offsets[k] = min(offsets.get(k, np.inf), offset)
    lookup = np.full(max(offsets, default=-1) + 1, np.nan)
    lookup[list(offsets)] = list(offsets.values())
    times = np.empty(len(seq))
    for rows, segment, after in _segments(seq, host_time, starts):
        part = seq[rows] / rate_hz + lookup[segment]
        part[part < starts[after]] = np.nan
        times[rows] = part
    return times


BLOCK = 1 << 16
"""Samples `sample_times` works on at a time (its memory beyond the result is a few blocks)."""


def _segments(seq, host_time, starts):
    """(rows, segment, after) per block of `BLOCK` samples: the block's slice, the segment of
    each of its samples (the breaks before it plus the places before it where `seq` does not
    increase) and the index in `starts` of the break before it."""
    restarts = 0
    for first in range(0, len(seq), BLOCK):
        rows = slice(first, first + BLOCK)
        after = np.searchsorted(starts[1:], host_time[rows], side="right")
        steps = np.cumsum(np.diff(seq[max(first - 1, 0):first + BLOCK]) <= 0)
        count = restarts + (np.concatenate([[0], steps]) if first == 0 else steps)
        restarts = int(count[-1])
        yield rows, after + count, after


def segment_breaks(events) -> list:
    """Clock times of the recorded `events` after which the stream is a new segment."""
    return [e.time for e in events if e.kind in SEGMENT_EVENTS]
