"""Virtual serial IMU: a pseudo-terminal pair streaming the profile's wire format.

The driver opens `twin.port` exactly as it would open /dev/ttyUSB0: the device end is a
`drivers.twins.pty.PtyLink` (a stable path to a pty slave in raw mode that survives the driver's
reopening; `unread_after` tells it when nobody reads).

Frames are paced by the shared clock: frame `seq` carries the data `source(times)` at
`time = start + seq / rate_hz`; with a ScaledClock the stream runs faster than real time; with a
SteppedClock the frames due are sent at each step of lockstep time, and time moves on only once
the station has read them (`drivers.clock`). Writes
wait while the pty is full (like hardware flow control); if the twin falls more than `max_lag`
seconds of clock time behind, it skips frames like a device whose buffer overflows. With
`unread_after`, a pty that has accepted nothing for that many wall seconds has no reader (the
station closed the port, or was killed): the frames due are lost, as the bytes of a real device
whose port nobody reads, until the pty takes bytes again - instead of a backlog of the whole
absence sent when the station reopens the port, which a loaded host may need the next minutes of
the session to catch up with.

Fault knobs (attributes, changeable while streaming):
- `corrupt`: fraction of frames mutated by `corrupt_frame` (bytes flipped, deleted or inserted);
- `drop`: fraction of frames not sent at all (the sequence number jumps);
- `pause(seconds)`: silence; the frames due meanwhile are lost;
- `unplug()` / `plug()`: the device disappears (the reader gets an error) and comes back;
- `duplicate`: fraction of frames sent twice in a row, byte for byte (their numbers in
  `duplicated`), as a USB-serial adapter that repeats a buffer;
- `restart()`: the device resets: from the next frame its sequence number and device time start
  again from 0 (the frame numbers of the log go on; `restarts` holds the first of each new run).
Every frame's fate is logged (`log()`), so tests know exactly what an ideal reader gets.
"""

import numpy as np

from drivers.clock import WallClock
from drivers.profile import SerialImuProfile
from drivers.twins.pty import PtyLink
from drivers.twins.streamer import Streamer
from drivers.wire.ascii import encode_lines
from drivers.wire.binary import encode_frames

# fates of frames in the log
SENT, CORRUPTED, DROPPED, PAUSED, OVERFLOW, UNPLUGGED = range(6)


def corrupt_frame(frame: bytes, rng: np.random.Generator) -> bytes:
    """A damaged copy of one frame, like a noisy line: one of, equally likely,
    flip 1-4 bytes (XOR with a non-zero value), delete a run of 1 to len/2 bytes, or insert 1 to len
    random bytes inside it."""
    data = bytearray(frame)
    n = len(data)
    kind = rng.integers(3)
    if kind == 0:
        for i in rng.choice(n, size=min(n, int(rng.integers(1, 5))), replace=False):
            data[i] ^= int(rng.integers(1, 256))
    elif kind == 1:
        start = int(rng.integers(n))
        del data[start : start + int(rng.integers(1, max(2, n // 2 + 1)))]
    else:
        at = int(rng.integers(1, max(2, n)))
        data[at:at] = rng.integers(0, 256, size=int(rng.integers(1, n + 1)),
                                   dtype=np.uint8).tobytes()
    return bytes(data)


class SerialTwin(Streamer):
    """A serial IMU of profile `profile` behind a pseudo-terminal (see the module docstring).

    source  : callable times (k,) in clock seconds -> counts (k, m) integers
    clock   : shared clock (WallClock or ScaledClock)
    rate_hz : frame rate in clock time (default: the profile's rate)
    seed    : seed of the fault generator
    max_lag : clock seconds the twin may fall behind before it skips frames (np.inf: never)
    unread_after : wall seconds after which a pty that takes no bytes counts as unread (None:
              never; see the module docstring)
    """

    max_batch = 4096  # frames encoded and written at once

    def __init__(self, profile, source, clock=None, rate_hz=None, seed=0, corrupt=0.0, drop=0.0,
                 max_lag=1.0, duplicate=0.0, unread_after=None):
        super().__init__()
        self.profile = (profile if isinstance(profile, SerialImuProfile)
                        else SerialImuProfile.load(profile))
        self.source = source
        self.clock = clock or WallClock()
        self.rate_hz = float(rate_hz or self.profile.imu.rate_hz)
        self.corrupt, self.drop, self.max_lag = corrupt, drop, max_lag
        self.duplicate = duplicate
        self.duplicated, self.restarts = [], []
        self._origin = 0  # frame number the device counts from (changed by `restart`)
        self.start_time = None
        self._rng = np.random.default_rng(seed)
        self._log = []
        self._pause = (np.inf, np.inf)  # clock-time window of silence
        self.link = PtyLink(unread_after)
        self.port = self.link.port

    # -- device life -----------------------------------------------------------------------------

    def restart(self) -> None:
        """The device resets: its numbering and clock start again from 0 at the next frame."""
        self._origin = None

    def pause(self, seconds: float) -> None:
        """Go silent for `seconds` of clock time; the frames due meanwhile are lost."""
        now = self.clock.now()
        self._pause = (now, now + seconds)

    def start(self, start_time=None) -> "SerialTwin":
        """Start streaming; frame 0 is at `start_time` (default: now)."""
        self.start_time = self.clock.now() if start_time is None else float(start_time)
        return self._launch("serial-twin")

    # -- what was sent ---------------------------------------------------------------------------

    def time_of(self, seq) -> np.ndarray:
        """Clock time of frame number `seq` (the time its data was sampled at)."""
        return self.start_time + np.asarray(seq, dtype=np.int64) / self.rate_hz

    def log(self) -> tuple:
        """(seq, fate) of every frame so far; fate is SENT, CORRUPTED, DROPPED, PAUSED, OVERFLOW
        or UNPLUGGED."""
        if not self._log:
            return np.zeros(0, np.int64), np.zeros(0, np.int8)
        seq, fate = zip(*self._log, strict=True)
        return np.concatenate(seq), np.concatenate(fate)

    # -- streaming -------------------------------------------------------------------------------

    def _run(self) -> None:
        try:
            self._stream()
        except Exception as exc:  # noqa: BLE001 - told at once (Streamer._failed)
            self._failed(exc)

    def _stream(self) -> None:
        """Send the frames due, then wait (`clock.pace`) until more are (on a stepped clock: each
        step, the first after start, so a driver opened at the start instant loses nothing)."""
        next_seq = 0
        if not self.clock.realtime:
            self.clock.pace(self._stop)
        while not self._stop.is_set():
            due = int(np.floor((self.clock.now() - self.start_time) * self.rate_hz)) + 1
            if due <= next_seq:
                self.clock.pace(self._stop)
                continue
            if self.link.unread():  # nobody reads the port: the frames due are lost
                skipped = np.arange(next_seq, due)
                self._log.append((skipped, np.full(len(skipped), OVERFLOW, np.int8)))
                next_seq = due
                self.clock.pace(self._stop)
                continue
            if due - next_seq > self.max_lag * self.rate_hz:  # buffer overflow: skip the oldest
                skipped = np.arange(next_seq, due - int(self.max_lag * self.rate_hz))
                self._log.append((skipped, np.full(len(skipped), OVERFLOW, np.int8)))
                next_seq = int(skipped[-1]) + 1
            seq = np.arange(next_seq, min(due, next_seq + self.max_batch))
            self._send(seq)
            next_seq = int(seq[-1]) + 1

    def _send(self, seq: np.ndarray) -> None:
        """Encode frames `seq`, apply the fault knobs, write them and log their fates."""
        times = self.time_of(seq)
        fate = np.full(len(seq), SENT, np.int8)
        fate[self._rng.random(len(seq)) < self.corrupt] = CORRUPTED
        fate[self._rng.random(len(seq)) < self.drop] = DROPPED
        fate[(times >= self._pause[0]) & (times < self._pause[1])] = PAUSED
        frames = self._encode(seq[fate <= CORRUPTED], times[fate <= CORRUPTED])
        for i in np.flatnonzero(fate[fate <= CORRUPTED] == CORRUPTED):
            frames[i] = corrupt_frame(frames[i], self._rng)
        twice = np.flatnonzero(self._rng.random(len(frames)) < self.duplicate)
        for i in twice:
            frames[i] = frames[i] * 2
        self.duplicated.extend(seq[fate <= CORRUPTED][twice].tolist())
        data = b"".join(frames)
        self.clock.sent(self.port, len(data))  # booked first: in flight until the reader took it
        written = self.link.write(data, self._stop, full=self.clock.nudge)
        self.clock.sent(self.port, written - len(data))  # what the pty did not take is gone
        self.clock.nudge()  # the reader has bytes to take
        ends = np.cumsum([len(f) for f in frames])
        sent = np.flatnonzero(fate <= CORRUPTED)
        fate[sent[ends > written]] = OVERFLOW if self.plugged else UNPLUGGED
        self._log.append((seq, fate))

    def _encode(self, seq: np.ndarray, times: np.ndarray) -> list:
        """The wire bytes of frames `seq` sampled at `times`, one list item per frame."""
        if len(seq) == 0:
            return []
        counts = np.asarray(self.source(times))
        m = len(self.profile.imu.channels)
        if counts.shape != (len(times), m) or not np.issubdtype(counts.dtype, np.integer):
            raise ValueError("twin source must return integer counts of shape "
                             f"({len(times)}, {m}); got {counts.dtype} {counts.shape}")
        fmt = self.profile.serial.frame
        if self.profile.serial.protocol == "ascii":
            return encode_lines(fmt, times, counts,
                                self.profile.imu.channels).splitlines(keepends=True)
        if self._origin is None:  # restarted: this frame is the device's number 0
            self._origin = int(seq[0])
            self.restarts.append(self._origin)
        wire = seq - self._origin
        zero = self.time_of(self._origin) if self.restarts else 0.0  # the device clock's 0
        imu = self.profile.imu
        ticks = (np.round((times - zero) / fmt.time_tick).astype(np.int64)
                 if np.isfinite(fmt.time_tick) else wire)
        data = encode_frames(fmt, wire, ticks, counts, imu.channels, imu.scale)
        size = len(data) // len(times)
        return [data[i : i + size] for i in range(0, len(data), size)]
