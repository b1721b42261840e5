"""Virtual CAN IMU: sends the frames of a device profile on a python-can virtual bus.

The twin opens `can.Bus(interface="virtual", channel=channel)`; a driver on another virtual bus with
the same channel name (in the same process) receives exactly what a real unit would send. Samples
come from `source(times) -> counts (k, m) int` (times in seconds of the shared clock, e.g.
`station.model.unit.SensorUnit.sample`), paced at the profile's rate by the clock, clipped to the
range of each signal like a saturating ADC, and split into the profile's frames with `cantools` (on
a `drivers.clock.SteppedClock`, the samples due at each step, time moving on once the station has
decoded them). Fault knobs: `drop`, the (seq, frame index) pairs that never reach the bus;
`duplicate`, the sequence numbers whose frames are all sent twice (the sample repeated).
"""

import threading
from typing import Self

import can
import numpy as np

from drivers.can_imu import CanProfile, FrameLayout
from drivers.clock import WallClock
from drivers.twins.failure import fail


class CanImuTwin:
    """Streams `samples` samples (or until `stop()`), starting at sequence number `first_seq`.

    `sent_seq` / `sent_counts` record every sample whose frames all went out, so tests can compare
    the driver's output with what was sent. An exception raised while streaming (e.g. by the
    source) ends the stream at once, silent from then on: it is kept in `error` and told to
    `on_error(exc)` if the owner set one (`drivers.twins.failure`).
    """

    def __init__(self, channel: str, profile: CanProfile, source, clock=None, samples=None,
                 first_seq=0, drop=(), duplicate=()):
        self.layout = FrameLayout(profile)
        self.rate_hz = profile.imu.rate_hz
        self.source = source
        self.clock = clock or WallClock()
        self.samples = samples
        self.first_seq = int(first_seq)
        self.drop = set(drop)
        self.duplicate = set(duplicate)
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.sent_seq, self.sent_counts = [], []
        self.error = None
        self.on_error = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"CanImuTwin {channel}", daemon=True)

    def start(self, start_time=None) -> "CanImuTwin":
        """Start streaming; sample 0 is at `start_time` (default: now)."""
        self.start_time = self.clock.now() if start_time is None else float(start_time)
        self.clock.enlist(self._thread, producer=True)
        self._thread.start()
        return self

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until all `samples` are sent; True if the stream has ended."""
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def stop(self) -> None:
        """Stop streaming and release the virtual bus."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        self.bus.shutdown()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _run(self) -> None:
        t0, sent = self.start_time, 0
        total = self.samples if self.samples is not None else float("inf")
        try:
            if not self.clock.realtime:
                self.clock.pace(self._stop)  # lockstep: the first delivery comes after start
            while sent < total and not self._stop.is_set():
                due = min(total, int((self.clock.now() - t0) * self.rate_hz) + 1)
                if due > sent:
                    self._send(t0, np.arange(sent, due))
                    sent = due
                    self.clock.nudge()
                self.clock.pace(self._stop)
        except Exception as exc:  # noqa: BLE001 - told at once (drivers.twins.failure)
            fail(self, exc)

    def _send(self, t0: float, index: np.ndarray) -> None:
        """Sample the source at the due times and put their frames on the bus."""
        counts = np.asarray(self.source(t0 + index / self.rate_hz))
        if counts.shape != (len(index), len(self.layout.channels)) or counts.dtype.kind not in "iu":
            shape = (len(index), len(self.layout.channels))
            raise ValueError(f"source must return integer counts of shape {shape}, "
                             f"got {counts.dtype} {counts.shape}")
        counts = np.clip(counts, self.layout.lo, self.layout.hi).astype(np.int64)
        for seq, row in zip(index + self.first_seq, counts, strict=True):
            if self._send_sample(int(seq), row):
                self.sent_seq.append(int(seq))
                self.sent_counts.append(row)
            if int(seq) in self.duplicate:
                self._send_sample(int(seq), row)

    def _send_sample(self, seq: int, row: np.ndarray) -> bool:
        """Send the frames of one sample; True if none was dropped."""
        counter = {self.layout.counter: seq % self.layout.counter_modulus}
        complete = True
        for slot in self.layout.slots:
            if (seq, slot.index) in self.drop:
                complete = False
                continue
            values = counter | {name: int(row[col]) for name, col in slot.columns}
            data = slot.message.encode(values, scaling=False, padding=True)
            self.bus.send(can.Message(arbitration_id=slot.frame_id, data=data,
                                      is_extended_id=slot.message.is_extended_frame))
        return complete
