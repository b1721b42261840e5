"""Serial IMU driver: a port path or pyserial URL in, timestamped SampleBlocks out.

    with SerialImu("/dev/ttyUSB0", "imu12_serial") as imu:
        block = imu.read_block(timeout=0.5)   # SampleBlock or None

The wire format (binary frames or ASCII lines) comes from the device profile; parsing is in
drivers/wire/frames.py. Reads take what the port has (`read(in_waiting or 1)`) with a short timeout, so a
block is returned as soon as a sample is complete. A lost device (unplug) raises DeviceLostError
naming the port; every sample decoded before it has already been returned, and `open()` reconnects.
For a recorder, `start(callback)` runs the reads in a background thread.
"""

import threading
import time

import serial

from drivers.wire.frames import AsciiLineParser, BinaryFrameParser
from drivers.profile import SerialImuProfile
from drivers.clock import WallClock
from drivers.errors import DeviceLostError, SerialPortError


class SerialImu:
    """A serial IMU described by a device profile (a SerialImuProfile, a path or a bundled name).

    port         : device path ("/dev/ttyUSB0") or pyserial URL
    clock        : station clock for host timestamps and read timeouts (WallClock by default)
    read_timeout : wall seconds one low-level read may wait for a first byte
    """

    def __init__(self, port: str, profile, clock=None, read_timeout: float = 0.01):
        self.port = str(port)
        self.profile = profile if isinstance(profile, SerialImuProfile) else SerialImuProfile.load(profile)
        self.clock = clock or WallClock()
        self.read_timeout = read_timeout
        parser = BinaryFrameParser if self.profile.serial.protocol == "binary" else AsciiLineParser
        self.parser = parser(self.profile.serial.frame, self.profile.imu.channels)
        self.connections = 0
        self.error = None
        self._serial = None
        self._lost = None  # DeviceLostError to raise once the last samples are handed out
        self._thread = None
        self._stop = threading.Event()

    @property
    def stats(self):
        """Link counters (drivers.wire.frames.LinkStats), cumulative over reconnects."""
        return self.parser.stats

    @property
    def is_open(self) -> bool:
        return self._serial is not None

    def open(self) -> "SerialImu":
        """Open (or reopen after a loss) the port, exclusively."""
        if self._serial is not None:
            return self
        try:
            self._serial = serial.serial_for_url(
                self.port, baudrate=self.profile.serial.baudrate, timeout=self.read_timeout,
                write_timeout=1.0, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise SerialPortError(
                self.port, f"cannot open serial port {self.port}: {exc}. Check that the device is "
                "plugged in, that the path is right and that no other program holds the port.") from exc
        self.parser.reset()
        self.connections += 1
        return self

    def close(self) -> None:
        """Stop the background reader if any and close the port."""
        self.stop()
        self._close_port()

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    def read_block(self, timeout: float = 0.1):
        """The samples completed within `timeout` clock seconds: a SampleBlock as soon as one sample
        is decoded, None if none came. Raises DeviceLostError if the device is lost."""
        if self._serial is None and self._lost is None:
            raise SerialPortError(self.port, f"serial port {self.port} is not open; call open() first")
        if self._lost is not None:
            error, self._lost = self._lost, None
            raise error
        deadline = self.clock.now() + timeout
        while True:
            data = self._read()
            if data is None:  # lost: hand out the last decodable frames first
                block = self.parser.feed(b"", self.clock.now(), final=True)
                if len(block):
                    return block
                error, self._lost = self._lost, None
                raise error
            if data:
                block = self.parser.feed(data, self.clock.now())
                if len(block):
                    return block
            if self.clock.now() >= deadline:
                return None

    def _read(self):
        """What the port has now, or the first byte within `read_timeout`; None if the device was
        lost (the error is kept in `_lost`)."""
        try:
            return self._serial.read(self._serial.in_waiting or 1)
        except (serial.SerialException, OSError) as exc:
            self._close_port()
            self._lost = DeviceLostError(
                self.port, f"serial IMU on {self.port} was lost ({exc}). The samples read so far are "
                "kept; reconnect the device and call open() to continue.")
            self._lost.__cause__ = exc
            return None

    def _close_port(self) -> None:
        if self._serial is not None:
            try:
                self._serial.close()
            except (serial.SerialException, OSError):
                pass  # the device is already gone
            self._serial = None

    # -- background reading ----------------------------------------------------------------------

    def start(self, callback, on_error=None, interval: float = 0.005) -> None:
        """Read in a background thread, calling `callback(block)` for every SampleBlock.

        The thread waits `interval` wall seconds between reads so that each block holds several
        samples. If the device is lost or the callback raises, the thread ends, keeps the exception
        in `error` and calls `on_error(exc)`.
        """
        self.open()
        self.error = None
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, args=(callback, on_error, interval),
                                        name=f"serial-imu {self.port}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """End the background reader (the port stays open)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()
            self._thread = None

    def _run(self, callback, on_error, interval) -> None:
        try:
            while not self._stop.is_set():
                block = self.read_block(timeout=0.0)
                if block is not None:
                    callback(block)
                time.sleep(interval)
        except Exception as exc:  # handed to the owner: a reader thread must not die silently
            self.error = exc
            if on_error is not None:
                on_error(exc)
