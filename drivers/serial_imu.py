"""Serial IMU driver: a port path or pyserial URL in, timestamped SampleBlocks out.

    with SerialImu("/dev/ttyUSB0", "imu12_serial") as imu:
        block = imu.read_block(timeout=0.5)   # SampleBlock or None

An `ImuDriver` (drivers/__init__.py). The wire format (binary frames or ASCII lines) comes from
the device profile; decoding is in drivers/wire/. Reads take what the port has
(`read(in_waiting or 1)`) with a short timeout, so a block is returned as soon as a sample is
complete. A lost device (unplug) raises DeviceLostError naming the port; every sample decoded before
it has already been returned, and `open()` reconnects.
"""

import contextlib

import serial

from drivers.clock import WallClock
from drivers.errors import DeviceLostError, SerialPortError
from drivers.profile import SerialImuProfile
from drivers.samples import SampleBlock
from drivers.wire import SerialStats
from drivers.wire.ascii import AsciiLineParser
from drivers.wire.binary import BinaryFrameParser


class SerialImu:
    """An `ImuDriver` for a serial IMU described by a device profile (a SerialImuProfile, a path
    or a bundled name).

    port         : device path ("/dev/ttyUSB0") or pyserial URL
    clock        : station clock for host timestamps and read timeouts (WallClock by default)
    read_timeout : wall seconds one low-level read may wait for a first byte (on a stepped clock
                   only for bytes the twin has sent: `drivers.clock`)
    """

    profile_type = SerialImuProfile

    def __init__(self, port: str, profile, clock=None, read_timeout: float = 0.01):
        self.port = str(port)
        self.profile = (profile if isinstance(profile, SerialImuProfile)
                        else SerialImuProfile.load(profile))
        self.clock = clock or WallClock()
        self.read_timeout = read_timeout
        imu, serial_section = self.profile.imu, self.profile.serial
        self.parser = (BinaryFrameParser(serial_section.frame, imu.channels, imu.scale)
                       if serial_section.protocol == "binary"
                       else AsciiLineParser(serial_section.frame, imu.channels))
        self.connections = 0
        self._serial = None
        self._lost = None  # DeviceLostError to raise once the last samples are handed out

    @property
    def stats(self) -> SerialStats:
        """Link counters, cumulative over reconnects."""
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
                "plugged in, that the path is right and that no other program holds the "
                "port.") from exc
        self.parser.reset()
        self.clock.forget(self.port)
        self.connections += 1
        return self

    def close(self) -> None:
        """Close the port."""
        self._close_port()

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    def read_block(self, timeout: float = 0.1):
        """The samples completed within `timeout` clock seconds: a SampleBlock as soon as one sample
        is decoded (on a stepped clock: once the bytes the twin has sent are all read, so a block
        is what the twin delivered, whatever the host's timing), None if none came. Raises
        DeviceLostError if the device is lost."""
        if self._serial is None and self._lost is None:
            raise SerialPortError(self.port,
                                  f"serial port {self.port} is not open; call open() first")
        if self._lost is not None:
            error, self._lost = self._lost, None
            raise error
        deadline = self.clock.now() + timeout
        blocks = []
        while True:
            data = self._read()
            if data is None:  # lost: hand out the last decodable frames first
                block = self.parser.decode(b"", self.clock.now(), final=True).block
                if len(block) or blocks:
                    return SampleBlock.concat([b for b in (*blocks, block) if len(b)])
                error, self._lost = self._lost, None
                raise error
            if data:
                block = self.parser.decode(data, self.clock.now()).block
                if len(block):
                    blocks.append(block)
            if blocks and (self.clock.realtime or not self.clock.in_flight(self.port)):
                return SampleBlock.concat(blocks)
            if self.clock.now() >= deadline:
                return SampleBlock.concat(blocks) if blocks else None
            if not (data or self.clock.realtime or self.clock.in_flight(self.port)):
                self.clock.idle()  # lockstep time: wait for the twin's next delivery

    def backlog(self) -> bool:
        """Has the port bytes on their way that were not read yet (never when closed)? What a
        reader on a `drivers.clock.SteppedClock` has to take before time moves on: the bytes the
        twin booked on the clock's ledger (a pty may not show them yet)."""
        return self._serial is not None and self.clock.in_flight(self.port)

    def _read(self):
        """What the port has now, or the first byte within `read_timeout`; None if the device was
        lost (the error is kept in `_lost`)."""
        try:
            waiting = self._serial.in_waiting
            if not (waiting or self.clock.realtime or self.clock.in_flight(self.port)):
                return b""  # lockstep time: nothing sent, nothing to wait for
            data = self._serial.read(waiting or 1)
            self.clock.taken(self.port, len(data))
            return data
        except (serial.SerialException, OSError) as exc:
            self._close_port()
            self._lost = DeviceLostError(
                self.port, f"serial IMU on {self.port} was lost ({exc}). "
                "The samples read so far are kept; reconnect the device and call open() to "
                "continue.")
            self._lost.__cause__ = exc
            return None

    def _close_port(self) -> None:
        if self._serial is not None:
            with contextlib.suppress(serial.SerialException, OSError):  # the device is already gone
                self._serial.close()
            self._serial = None
