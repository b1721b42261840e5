"""The recorder: IMU samples, table states and protocol events into one session file.

A reader thread pulls `SampleBlock`s from an opened IMU driver (a `drivers.ImuDriver`: serial or
CAN, see `drivers.open_imu`) and appends them to a `station.session.SessionWriter`. The
protocol, in its own thread, records table states and events through the same recorder; one lock
serialises every access to the writer, which is not thread-safe.

The reader never dies silently: a lost device or a writer failure ends the thread and is kept in
`error`; `check()` re-raises it in the protocol's thread, and also raises when no sample has
arrived for too long (a silent device).

Samples arrive late when the host is busy (a CAN notifier can lag by a second of wall time):
`drain(t)` waits until every sample taken up to clock time t has arrived, so that a protocol can
make sure a window is complete before it moves the table.

A lost device (`reconnect()` after the cable is back) or a resumed session starts a new segment of
the stream: the sequence numbers may jump or restart, so sample times are worked out per segment
(`station.reduce.timeline.sample_times`, the breaks being the times of the `resume` and
`session_resumed` events).
"""

import logging
import threading
import time
from typing import Self

import numpy as np

from drivers.clock import WallClock
from station.acquire import interrupts
from station.errors import RecordingError
from station.reduce.timeline import arrival_offset

log = logging.getLogger(__name__)


class Recorder:
    """Records `imu` into `writer`'s stream `stream` until `stop()`; a context manager.

    clock    : the session's clock (default: the writer's, shared with the devices, or WallClock)
    interval : wall seconds the reader waits once it has caught up (the driver has no sample, or
               fewer than half what one interval brings), so that each block holds several
               samples; while larger blocks come (a backlog) it reads on at once. A port hands
               over at most its buffer a read (a pty 4 KB, 70 frames of 58 bytes): a reader that
               waited after every block fell behind a fast stream on a busy host (3 units at 100
               Hz on a 40x clock) and never drained the backlog, so no sample of the segment
               arrived promptly and every instant `arrival_offset` gave it came out late by it;
               one that never waits spins on single samples and starves the other threads.
    drain_timeout : wall seconds `drain` waits for the samples in flight (a real-time clock's)
    busy_grace    : wall seconds of silence always tolerated on a real-time clock: a busy host (an
                    HDF5 flush, other processes) can hold the reader that long, which is many
                    seconds of a fast clock; lockstep time does not move while the host is busy
    lock          : the lock of every access to the writer (default its own; `PlateRecorder`
                    shares one between the recorders of one writer)
    """

    def __init__(self, writer, imu, stream: str = "imu", clock=None, interval: float = 0.003,
                 drain_timeout: float = 30.0, busy_grace: float = 2.0, lock=None):
        self.writer = writer
        self.imu = imu
        self.stream = stream
        self.clock = clock or writer.clock or WallClock()
        self.interval = interval
        self.drain_timeout = drain_timeout
        self.busy_grace = busy_grace
        self.rate_hz = writer.specs[stream].rate_hz
        self.samples = 0
        self.error = None
        self._last_arrival = None  # (clock, wall) time of the last block
        self._offset = np.inf  # arrival_offset of the samples so far
        self._last_seq = None
        self._lock = lock or threading.Lock()
        self._stop = threading.Event()
        self._thread = None

    def start(self) -> "Recorder":
        """Start the reader thread. On a stepped clock (`drivers.clock.SteppedClock`) the calling
        thread (the protocol's) and the reader take part in lockstep time, and time waits while
        the driver holds data not read yet (its `backlog()`, where it has one)."""
        self._last_arrival = (self.clock.now(), time.monotonic())
        self._stop.clear()
        self._thread = threading.Thread(target=self._read, name="recorder", daemon=True)
        self.clock.enlist()
        self.clock.enlist(self._thread)
        if hasattr(self.imu, "backlog"):
            self.clock.watch(self.imu.backlog)
        self._thread.start()
        return self

    def stop(self) -> None:
        """End the reader thread now (the devices and the writer stay open); the calling thread
        leaves lockstep time."""
        self._stop.set()
        self.clock.nudge()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if hasattr(self.imu, "backlog"):
            self.clock.unwatch(self.imu.backlog)
        self.clock.leave()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def reconnect(self) -> None:
        """Reopen a lost IMU (`ImuDriver.open()`, whatever the link) and read on, as a new segment
        of the stream; record the `resume` event before calling it. Raises the driver's
        ConnectionError while the device is still missing (then call it again later)."""
        self.stop()
        self.imu.open()
        log.info("IMU reopened after %r; a new segment of stream %s", self.error, self.stream)
        self.error = None
        self._offset, self._last_seq = np.inf, None
        self.start()

    def sampled_until(self) -> float:
        """Sampling instant (clock s) of the newest sample received; -inf before the first."""
        if self._last_seq is None:
            return -np.inf
        return self._last_seq / self.rate_hz + self._offset

    def drain(self, until: float, stale: float) -> None:
        """Wait until the samples taken up to clock time `until` have arrived; RecordingError
        when none comes for `stale` clock seconds or after `drain_timeout` wall seconds."""
        deadline = time.monotonic() + self.drain_timeout
        while self.sampled_until() < until:
            self.check(stale)
            if self.clock.realtime and time.monotonic() > deadline:
                speed = getattr(self.clock, "speed", 1.0)
                advice = (f"; the virtual bench runs {speed:g}x faster than the wall clock: "
                          f"give --speed {max(1.0, speed / 4):g} (or close other programs)"
                          if speed > 1 else "; close other programs or lower the sample rate")
                raise RecordingError(
                    f"the IMU samples lag {until - self.sampled_until():.1f} s behind after "
                    f"waiting {self.drain_timeout} s: the host is too busy for this link's "
                    f"rate{advice}")
            self.clock.idle(self.interval)

    def event(self, kind: str, position: int | None = None, detail: dict | None = None,
              time: float | None = None) -> float:
        """Record a protocol event (see `station.session.EVENT_KINDS`) at clock `time`
        (default now, stamped before waiting for the writer, which a block may be holding; a
        window's bound: the instant of the table reading it was cut at); returns the time
        stored."""
        time = self.clock.now() if time is None else float(time)
        with self._lock:
            self.writer.event(kind, position, detail, time=time)
        return time

    def table(self, reading) -> None:
        """Keep one table state (`drivers.rotary_table.TableReading`)."""
        with self._lock:
            self.writer.append_table(reading)

    def check(self, stale: float) -> None:
        """Raise RecordingError if the reader failed or no sample came for `stale` clock seconds
        (and at least `busy_grace` wall seconds); raise a Ctrl-C that was dropped
        (`station.acquire.interrupts`)."""
        interrupts.raise_dropped()
        if self.error is not None:
            raise RecordingError(f"recording of the IMU stopped: {self.error}") from self.error
        clock, wall = self._last_arrival
        silent = self.clock.now() - clock
        busy = self.clock.realtime and time.monotonic() - wall <= self.busy_grace
        if silent > stale and not busy:
            raise RecordingError(f"no IMU sample for {silent:.1f} s (limit {stale} s); check the "
                                 "IMU's power and cable, then record the session again")

    def _follow(self, block) -> None:
        """Update what `sampled_until` knows from a new block; a device that restarted its
        numbering (the seq does not increase: `drivers.samples.restart_seq`) starts afresh."""
        seq = block.seq
        before = seq[0] - 1 if self._last_seq is None else self._last_seq
        restarts = np.flatnonzero(np.diff(seq, prepend=before) <= 0)
        if restarts.size:
            self._offset, seq = np.inf, seq[restarts[-1]:]
        self._offset = min(self._offset, arrival_offset(seq, block.host_time[-len(seq):],
                                                        self.rate_hz))
        self._last_seq = int(seq[-1])

    def _read(self) -> None:
        """The reader thread: blocks as they come, a pause of `interval` once caught up (see
        `interval`; on a stepped clock it reads until the driver has nothing, then idles until
        the twin sends more)."""
        caught_up = (0.5 * self.rate_hz * self.clock.speed * self.interval
                     if self.clock.realtime else 1)
        try:
            while not self._stop.is_set():
                block = self.imu.read_block(timeout=0.0)
                if block is not None and len(block):
                    self._last_arrival = (self.clock.now(), time.monotonic())
                    with self._lock:
                        self.writer.append(self.stream, block)
                    self.samples += len(block)
                    self._follow(block)
                    self.clock.nudge()  # a protocol draining the stream looks again
                    if len(block) >= caught_up:
                        continue
                self.clock.idle(self.interval, self._stop)
        except Exception as exc:  # noqa: BLE001 - handed to the protocol by check()
            self.error = exc


class PlateRecorder:
    """Several units on one table into one writer: a `Recorder` per unit (its own reader thread
    and stream) sharing one lock on the writer, seen by a protocol as one Recorder.

    imus  : {stream: opened IMU driver}, the first the unit whose stream carries `stream`
    names : {stream: the unit in words, e.g. "unit SN7 (stream imu2)"}

    Every guard applies per unit: `check` and `drain` raise the first unit's RecordingError that
    fails, its message starting with the unit's name and its cause kept (a lost link is a
    ConnectionError, which the protocol recovers from); the error carries the name as `unit`.
    `sampled_until` is the least advanced unit's; `reconnect` reopens the units that failed.
    Events and table states are recorded once, through the first unit's recorder.
    """

    def __init__(self, writer, imus: dict, names: dict, clock=None, **options):
        lock = threading.Lock()
        self.units = {stream: Recorder(writer, imu, stream, clock, lock=lock, **options)
                      for stream, imu in imus.items()}
        self.names = names
        self._first = next(iter(self.units.values()))
        self.writer, self.stream, self.clock = writer, self._first.stream, self._first.clock

    def start(self) -> "PlateRecorder":
        """Start every unit's reader thread."""
        for recorder in self.units.values():
            recorder.start()
        return self

    def stop(self) -> None:
        """End every unit's reader thread (the devices and the writer stay open)."""
        for recorder in self.units.values():
            recorder.stop()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def error(self):
        """The failure of the first unit whose reader failed, None while all read."""
        return next((r.error for r in self.units.values() if r.error is not None), None)

    @property
    def samples(self) -> int:
        """Samples recorded, every unit's."""
        return sum(r.samples for r in self.units.values())

    def event(self, kind: str, position: int | None = None, detail: dict | None = None,
              time: float | None = None) -> float:
        """`Recorder.event`: once for the session."""
        return self._first.event(kind, position, detail, time)

    def table(self, reading) -> None:
        """`Recorder.table`: once for the session."""
        self._first.table(reading)

    def sampled_until(self) -> float:
        """Sampling instant of the newest sample every unit has delivered."""
        return min(r.sampled_until() for r in self.units.values())

    def check(self, stale: float) -> None:
        """`Recorder.check` of every unit, the failing one named."""
        for stream, recorder in self.units.items():
            self._named(stream, recorder.check, stale)

    def drain(self, until: float, stale: float) -> None:
        """`Recorder.drain` of every unit, the failing one named."""
        for stream, recorder in self.units.items():
            self._named(stream, recorder.drain, until, stale)

    def reconnect(self) -> None:
        """Reopen every unit whose reader failed (`Recorder.reconnect`); the driver's
        ConnectionError, with the unit's name in a note, while one is still missing."""
        for stream, recorder in self.units.items():
            if recorder.error is not None:
                try:
                    recorder.reconnect()
                except ConnectionError as exc:
                    exc.add_note(f"{self.names[stream]} is missing")
                    raise

    def _named(self, stream: str, call, *args) -> None:
        """`call(*args)`; its RecordingError again with the unit's name first."""
        try:
            call(*args)
        except RecordingError as exc:
            named = RecordingError(f"{self.names[stream]}: {exc}")
            named.unit = self.names[stream]
            raise named from exc.__cause__
