"""The recorder: IMU samples, table states and protocol events into one session file.

A reader thread pulls `SampleBlock`s from an IMU driver (anything with `read_block(timeout)`, e.g.
`drivers.serial_imu.SerialImu` opened, or `drivers.can_imu.CanImu` started) and appends them to a
`station.session.SessionWriter`. The protocol, in its own thread, records table states and events
through the same recorder; one lock serialises every access to the writer, which is not
thread-safe.

The reader never dies silently: a lost device or a writer failure ends the thread and is kept in
`error`; `check()` re-raises it in the protocol's thread, and also raises when no sample has
arrived for too long (a silent device).
"""

import threading
import time


class RecordingError(RuntimeError):
    """The IMU stream stopped: the device went silent or the reader failed."""


class Recorder:
    """Records `imu` into `writer`'s stream `stream` until `stop()`; a context manager.

    clock    : the session's clock (the writer's, shared with the devices)
    interval : wall seconds between two reads, so that each block holds several samples
    """

    def __init__(self, writer, imu, stream: str = "imu", clock=None, interval: float = 0.005):
        self.writer = writer
        self.imu = imu
        self.stream = stream
        self.clock = clock or writer.clock
        self.interval = interval
        self.samples = 0
        self.error = None
        self._last_arrival = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = None

    def start(self) -> "Recorder":
        """Start the reader thread."""
        self._last_arrival = self.clock.now()
        self._stop.clear()
        self._thread = threading.Thread(target=self._read, name="recorder", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """End the reader thread (the devices and the writer stay open)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def __enter__(self) -> "Recorder":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def event(self, kind: str, position: int | None = None, detail: dict | None = None) -> None:
        """Record a protocol event now (see `station.session.EVENT_KINDS`)."""
        with self._lock:
            self.writer.event(kind, position, detail)

    def table(self, reading) -> None:
        """Keep one table state (`drivers.rotary_table.TableReading`)."""
        with self._lock:
            self.writer.append_table(reading)

    def check(self, stale: float) -> None:
        """Raise RecordingError if the reader failed or no sample came for `stale` clock seconds."""
        if self.error is not None:
            raise RecordingError(f"recording of the IMU stopped: {self.error}") from self.error
        silent = self.clock.now() - self._last_arrival
        if silent > stale:
            raise RecordingError(f"no IMU sample for {silent:.1f} s (limit {stale} s); check the "
                                 "IMU's power and cable, then record the session again")

    def _read(self) -> None:
        try:
            while not self._stop.is_set():
                block = self.imu.read_block(timeout=0.0)
                if block is not None and len(block):
                    with self._lock:
                        self.writer.append(self.stream, block)
                    self.samples += len(block)
                    self._last_arrival = self.clock.now()
                time.sleep(self.interval)
        except Exception as exc:  # noqa: BLE001 - handed to the protocol by check()
            self.error = exc
