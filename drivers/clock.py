"""Clocks shared by the recorder and the virtual devices.

`WallClock` is the real monotonic time. `ScaledClock` runs `speed` times faster than the wall, so a
10-minute protocol can be driven through the real drivers in seconds; every virtual device and the
recorder of one bench share one instance.
"""

import threading
import time


class WallClock:
    """Host monotonic time in seconds."""

    speed = 1.0

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class ScaledClock(WallClock):
    """Simulated time that advances `speed` times faster than the wall clock, starting at
    `start`."""

    def __init__(self, speed: float = 1.0, start: float = 0.0):
        if not speed > 0:
            raise ValueError(f"clock speed must be positive, got {speed!r}")
        self.speed = float(speed)
        self._start = float(start)
        self._wall0 = time.monotonic()
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._start + (time.monotonic() - self._wall0) * self.speed

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds / self.speed)
