"""MAVLink IMU driver: a flight controller's IMU messages -> timestamped `SampleBlock`s.

    with MavlinkImu("udpin:127.0.0.1:14550", "acc3_mavlink") as imu:   # or "/dev/ttyACM0"
        block = imu.read_block(timeout=0.5)                             # SampleBlock or None

An `ImuDriver` (drivers/__init__.py). The frames are parsed by pymavlink's generated `common`
dialect (`MAVLink.parse_buffer`, MAVLink 2 and 1 frames; robust parsing: a frame failing its CRC
comes back as BAD_DATA and is counted, not raised); what the IMU messages mean is
drivers/wire/mavlink.py. The device profile (TOML) has `[imu]` (channels, SI units, counts per SI
unit, rate) and `[mavlink]` (the message family and instance, the sender's system and component id,
the field of each channel, the serial baud rate, whether to request the stream): docs/devices.md.

The link is a serial port (pyserial: a device path or URL, opened exclusively) or UDP: the address
`udpin:HOST:PORT` listens on HOST:PORT (the flight controller sends there, as to a ground station;
replies go to the last sender). `open()` asks for the IMU message at the profile's rate
(COMMAND_LONG MAV_CMD_SET_MESSAGE_INTERVAL, once a second while waiting) and waits up to
`[mavlink] wait_s` wall seconds for the first one; if none comes it raises `MavlinkError` naming the
messages that did come (only HEARTBEAT: the stream is not enabled; the message with another
instance or from another system: the profile's ids are wrong; nothing: the port or baud rate).

Sequence numbers: the MAVLink packet sequence (8 bits, per sender, over all its messages) tells
where messages were lost (`MavlinkStats.lost_messages`); a sample's `seq` counts the IMU messages,
stepping by the samples missing where the stream lost messages or the device time jumped by more
than 1.5 periods (`round(dt * rate_hz)`, so `rate_hz` must be the rate the device really sends).
A time stamp going backwards is a device reboot: a new segment (`seq` does not increase). An IMU
message repeated with the same packet sequence and bytes is a duplicate, dropped.
"""

import contextlib
import ipaddress
import math
import select
import socket
import time
from collections import Counter
from dataclasses import dataclass

import numpy as np
import serial
from pymavlink.dialects.v20 import common as mavlink

from drivers import LinkStats
from drivers.clock import WallClock, reply_timeout
from drivers.errors import DeviceLostError, MavlinkError, ProfileError, SerialPortError
from drivers.profile import ImuSection, Section, load_profile
from drivers.samples import SampleBlock
from drivers.wire.mavlink import DEFAULT_SCALE, QUANTITY, ImuMessage

GCS_IDS = (255, mavlink.MAV_COMP_ID_MISSIONPLANNER)
"""The station's own MAVLink system and component id (a ground station's, by convention)."""

REQUEST_EVERY = 1.0
"""Wall seconds between stream requests while `open()` waits for the first IMU message."""


@dataclass(frozen=True)
class MavlinkSection:
    """`[mavlink]`: which messages carry the samples.

    message       : "HIGHRES_IMU", "SCALED_IMU" or "RAW_IMU" (drivers/wire/mavlink.py)
    instance      : which IMU: SCALED_IMU 0, 1, 2 = SCALED_IMU, SCALED_IMU2, SCALED_IMU3; the
                    others: the message's `id` field
    system_id     : MAVLink system id of the flight controller (1..255)
    component_id  : its component id (1 = the autopilot)
    fields        : the message field of each [imu] channel, in channel order (xacc ... zmag)
    baudrate      : serial link speed (ignored on UDP)
    request_stream: ask for the message at [imu] rate_hz with MAV_CMD_SET_MESSAGE_INTERVAL
    wait_s        : wall seconds `open()` waits for the first IMU message (on a stepped clock
                    at least `drivers.clock.reply_timeout`: a loaded host's twin answers late)
    """

    message: ImuMessage
    system_id: int
    component_id: int
    baudrate: int
    request_stream: bool
    wait_s: float

    @classmethod
    def parse(cls, s: Section) -> "MavlinkSection":
        family = s.get("message", str, choices=("HIGHRES_IMU", "SCALED_IMU", "RAW_IMU"))
        instance = s.get("instance", int, default=0)
        top = 2 if family == "SCALED_IMU" else 255
        if not 0 <= instance <= top:
            raise s.error("instance", f"must be 0..{top} for {family}")
        fields = s.get_list("fields", str)
        unknown = sorted(set(fields) - set(QUANTITY))
        if unknown or not fields or len(set(fields)) != len(fields):
            raise s.error("fields", f"must be distinct fields of {', '.join(QUANTITY)}; got "
                                    f"{list(fields)}")
        ids = {k: s.get(k, int, default=1) for k in ("system_id", "component_id")}
        if not (1 <= ids["system_id"] <= 255 and 0 <= ids["component_id"] <= 255):
            raise s.error("system_id", "system_id must be 1..255 and component_id 0..255")
        baudrate = s.get("baudrate", int, default=921600)
        wait_s = s.get("wait_s", float, default=3.0)
        if baudrate <= 0 or not (math.isfinite(wait_s) and wait_s > 0):
            raise s.error("wait_s", "baudrate and wait_s must be positive")
        section = cls(ImuMessage(family, instance, fields), ids["system_id"], ids["component_id"],
                      baudrate, s.get("request_stream", bool, default=True), wait_s)
        s.finish()
        return section


@dataclass(frozen=True)
class MavlinkProfile:
    """A MAVLink IMU profile: `[imu]` and `[mavlink]`. In `[imu]`, `units` default to the
    fields' (m/s^2, rad/s, T) and `scale` to the message's fixed one (SCALED_IMU) or to
    `drivers.wire.mavlink.DEFAULT_SCALE` (HIGHRES_IMU); RAW_IMU needs the sensor's own."""

    source: str
    imu: ImuSection
    mavlink: MavlinkSection

    @classmethod
    def load(cls, path_or_name) -> "MavlinkProfile":
        """Read and check a MAVLink IMU profile (file path or bundled name)."""
        profile = load_profile(path_or_name)
        section = profile.section("mavlink", MavlinkSection.parse)
        message = section.message
        table = dict(profile.tables.get("imu") or {})
        where = f"{profile.source}: [imu]"
        channels = table.get("channels")
        if isinstance(channels, list) and len(channels) != len(message.fields):
            raise ProfileError(f"{where} has {len(channels)} channels and [mavlink] fields "
                               f"{len(message.fields)}: give one field per channel")
        units = [QUANTITY[f] for f in message.fields]
        table.setdefault("units", units)
        if message.family != "RAW_IMU":
            table.setdefault("scale", [message.fixed_scale(u) or DEFAULT_SCALE[u] for u in units])
        imu = ImuSection.parse(Section(profile.source, "imu", table))
        if list(imu.units) != units:
            raise ProfileError(f"{where} units {list(imu.units)} differ from the fields' "
                               f"{units} ({', '.join(message.fields)}); omit `units`")
        for unit, scale in zip(units, imu.scale, strict=True):
            fixed = message.fixed_scale(unit)
            if fixed is not None and not math.isclose(scale, fixed, rel_tol=1e-9):
                raise ProfileError(f"{where} scale: {message.family} fixes {fixed!r} counts per "
                                   f"{unit} (one count per milli-unit); omit `scale`")
        return cls(profile.source, imu, section)


@dataclass
class MavlinkStats(LinkStats):
    """Counters of a MAVLink link (LinkStats' samples, gaps, dropped, duplicates, restarts, and):

    bytes          : bytes received
    messages       : MAVLink messages decoded (any sender, any type)
    crc_failures   : frames whose CRC did not match (skipped)
    bad_bytes      : bytes that started no frame, or frames pymavlink refused otherwise (skipped)
    lost_messages  : packet sequence numbers missing from the flight controller's stream (its
                     messages of any type lost on the way)
    other_messages : the flight controller's messages that are not the IMU message (HEARTBEAT,
                     COMMAND_ACK, other instances...)
    invalid        : IMU messages with a value that is not finite or beyond the counts' range
                     (HIGHRES_IMU floats), not returned
    """

    bytes: int = 0
    messages: int = 0
    crc_failures: int = 0
    bad_bytes: int = 0
    lost_messages: int = 0
    other_messages: int = 0
    invalid: int = 0


class MavlinkDecoder:
    """Bytes in, samples out: pymavlink's parser and the rules of the module docstring. No I/O.

    `seen` counts the messages decoded by (type, system id, component id, instance) for the
    errors; `acks` holds the result of each COMMAND_ACK for MAV_CMD_SET_MESSAGE_INTERVAL.
    """

    def __init__(self, section: MavlinkSection, scale, rate_hz: float):
        self.section, self.message = section, section.message
        self.scale = np.asarray(scale, float)
        self.rate_hz = float(rate_hz)
        self.stats = MavlinkStats()
        self.seen = Counter()
        self.acks = []
        self._last = None  # (seq, device time) of the last sample
        self.reset()

    def reset(self) -> None:
        """A new connection: forget the parser's buffer and the packet sequence."""
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        self._packet = None  # last packet sequence number of the flight controller
        self._lost = False  # messages lost since the last sample
        self._last_buf = None  # bytes of the last IMU message (duplicates)

    def decode(self, data: bytes, host_time: float) -> SampleBlock:
        """The samples completed by `data` (possibly none)."""
        self.stats.bytes += len(data)
        rows, seqs, times = [], [], []
        for msg in self._parser.parse_buffer(data) or ():
            sample = self._take(msg)
            if sample is not None:
                rows.append(sample[0])
                seqs.append(sample[1])
                times.append(sample[2])
        m = len(self.message.fields)
        return SampleBlock(np.array(rows, np.int64).reshape(-1, m), np.array(seqs, np.int64),
                           np.array(times, float), np.full(len(rows), float(host_time)))

    def _take(self, msg):
        """(counts, seq, device time) if `msg` is a new sample, else None (counted)."""
        if msg.get_type() == "BAD_DATA":
            if "CRC" in msg.reason:
                self.stats.crc_failures += 1
            else:
                self.stats.bad_bytes += len(msg.data)
            return None
        self.stats.messages += 1
        family = self.message.is_family(msg)
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        self.seen[(msg.get_type(), *source, self.message.instance_of(msg) if family else None)] += 1
        if source != (self.section.system_id, self.section.component_id):
            return None
        if msg.get_type() == "COMMAND_ACK" and msg.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            self.acks.append(msg.result)
        step = None if self._packet is None else (msg.get_seq() - self._packet) % 256
        is_sample = family and self.message.instance_of(msg) == self.message.instance
        if step == 0 and is_sample and msg.get_msgbuf() == self._last_buf:
            self.stats.duplicates += 1
            return None
        if step is not None and step > 1:
            self.stats.lost_messages += step - 1
            self._lost = True
        self._packet = msg.get_seq()
        if not is_sample:
            self.stats.other_messages += 1
            return None
        self._last_buf = msg.get_msgbuf()
        counts = self.message.counts(msg, self.scale)
        if counts is None:
            self.stats.invalid += 1
            return None
        return counts, *self._number(msg)

    def _number(self, msg) -> tuple:
        """(seq, device time) of an IMU message (the numbering of the module docstring)."""
        t = self.message.time_of(msg)
        if self._last is None:
            seq = 0
        else:
            last_seq, last_t = self._last
            periods = (t - last_t) * self.rate_hz
            if periods < -0.5:  # the clock went back: the device rebooted
                seq = last_seq
                self.stats.restarts += 1
            else:
                step = max(1, round(periods)) if self._lost or periods > 1.5 else 1
                seq = last_seq + step
                if step > 1:
                    self.stats.gaps += 1
                    self.stats.dropped += step - 1
        self._last, self._lost = (seq, t), False
        self.stats.samples += 1
        return seq, t


def udp_address(address: str) -> tuple | None:
    """(host, port) of a `udpin:HOST:PORT` address, None for a serial port; MavlinkError for a
    malformed UDP address or another MAVLink URL scheme."""
    scheme, sep, rest = address.partition(":")
    if not sep or scheme.lower() not in ("udpin", "udp", "udpout", "tcp", "tcpin"):
        return None
    host, _, port = rest.rpartition(":")
    try:
        ipaddress.ip_address(host)
        number = int(port)
    except ValueError:
        number = 0
    if scheme.lower() != "udpin" or not 1 <= number <= 65535:
        raise MavlinkError(address, f"MAVLink address {address!r}: give udpin:HOST:PORT (HOST an "
                                    "IP address the station listens on, e.g. udpin:127.0.0.1:14550,"
                                    " the flight controller sending there) or a serial port")
    return host, number


class _SerialLink:
    """A serial port (pyserial), opened exclusively."""

    def __init__(self, port: str, baudrate: int, read_timeout: float):
        self.port, self.baudrate, self.read_timeout = port, baudrate, read_timeout
        self._serial = None

    def open(self) -> None:
        try:
            self._serial = serial.serial_for_url(
                self.port, baudrate=self.baudrate, timeout=self.read_timeout, write_timeout=1.0,
                exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise SerialPortError(
                self.port, f"cannot open serial port {self.port}: {exc}. Check that the flight "
                "controller is plugged in, that the path is right and that no other program (a "
                "ground station) holds the port.") from exc

    def read(self) -> bytes:
        """What the port has now, or the first byte within the read timeout; OSError or
        SerialException when the device is gone."""
        return self._serial.read(self._serial.in_waiting or 1)

    def waiting(self) -> bool:
        """Has the port bytes to read now? OSError or SerialException when the device is
        gone."""
        return self._serial.in_waiting > 0

    def write(self, data: bytes) -> None:
        self._serial.write(data)

    def close(self) -> None:
        if self._serial is not None:
            with contextlib.suppress(serial.SerialException, OSError):  # already gone
                self._serial.close()
            self._serial = None


class _UdpLink:
    """A UDP socket listening on (host, port); writes go to the last sender. Its receive buffer
    is `buffer` bytes (the kernel's default holds a few hundred datagrams: a fraction of a
    second of a fast stream while the host is busy)."""

    buffer = 1 << 22
    drain = 1024  # datagrams taken by one read at most

    def __init__(self, address: str, host_port: tuple, read_timeout: float):
        self.address, self.host_port, self.read_timeout = address, host_port, read_timeout
        self._socket = self._peer = None

    def open(self) -> None:
        family = socket.AF_INET6 if ":" in self.host_port[0] else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            sock.bind(self.host_port)
        except OSError as exc:
            sock.close()
            raise MavlinkError(self.address, f"cannot listen on {self.address}: {exc.strerror}. "
                                             "Is another program (a ground station) using the "
                                             "port? Is the address one of this host's?") from exc
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.buffer)
        sock.setblocking(False)
        self._socket = sock

    def waiting(self) -> bool:
        """Has a datagram come that was not read yet?"""
        return bool(select.select([self._socket], [], [], 0)[0])

    def read(self) -> bytes:
        """The datagrams waiting now (one message each, usually; at most `drain`), or the first
        within the read timeout: b"" if none."""
        if not select.select([self._socket], [], [], self.read_timeout)[0]:
            return b""
        chunks = []
        with contextlib.suppress(BlockingIOError):
            while len(chunks) < self.drain:
                data, self._peer = self._socket.recvfrom(65536)
                chunks.append(data)
        return b"".join(chunks)

    def write(self, data: bytes) -> None:
        if self._peer is not None:  # nobody to answer before the first datagram
            with contextlib.suppress(OSError):  # the sender went away: UDP says nothing
                self._socket.sendto(data, self._peer)

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None


class MavlinkImu:
    """An `ImuDriver` for a flight controller's IMU over MAVLink (see the module docstring).

    address      : serial port path or pyserial URL, or `udpin:HOST:PORT`
    profile      : a MavlinkProfile, a path or a bundled name
    clock        : station clock for host timestamps and read timeouts (WallClock by default)
    read_timeout : wall seconds one low-level read may wait
    """

    profile_type = MavlinkProfile

    def __init__(self, address: str, profile, clock=None, read_timeout: float = 0.01):
        self.address = str(address)
        self.profile = (profile if isinstance(profile, MavlinkProfile)
                        else MavlinkProfile.load(profile))
        self.clock = clock or WallClock()
        section = self.profile.mavlink
        udp = udp_address(self.address)
        self._link = (_UdpLink(self.address, udp, read_timeout) if udp else
                      _SerialLink(self.address, section.baudrate, read_timeout))
        self.decoder = MavlinkDecoder(section, self.profile.imu.scale, self.profile.imu.rate_hz)
        self._gcs = mavlink.MAVLink(self._link, *GCS_IDS)
        self.connections = 0
        self._open = False
        self._pending = None  # the first block, read by open()
        self._lost = None  # DeviceLostError to raise once the last samples are handed out

    @property
    def stats(self) -> MavlinkStats:
        """Link counters, cumulative over reconnects."""
        return self.decoder.stats

    def open(self) -> "MavlinkImu":
        """Open (or reopen after a loss) the link, ask for the IMU stream and wait for its first
        message (MavlinkError naming what came instead)."""
        if self._open:
            return self
        self._link.open()
        self.clock.forget(self.address)  # what came before the port opened is not ours
        self._open = True
        self.decoder.reset()
        self.connections += 1
        try:
            self._pending = self._first_block()
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        self._link.close()
        self._open = False

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    def request_stream(self) -> None:
        """Ask the flight controller for the IMU message at [imu] rate_hz
        (COMMAND_LONG MAV_CMD_SET_MESSAGE_INTERVAL: param1 message id, param2 interval in us)."""
        section = self.profile.mavlink
        self._gcs.send(self._gcs.command_long_encode(
            section.system_id, section.component_id, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
            section.message.msg_id, 1e6 / self.profile.imu.rate_hz, 0, 0, 0, 0, 0))

    def read_block(self, timeout: float = 0.1):
        """The samples completed within `timeout` clock seconds: a SampleBlock as soon as one sample
        is decoded, None if none came. Raises DeviceLostError if a serial device is lost."""
        if self._pending is not None:
            block, self._pending = self._pending, None
            return block
        if not self._open:
            if self._lost is not None:
                error, self._lost = self._lost, None
                raise error
            raise MavlinkError(self.address, f"MAVLink link {self.address} is not open; call "
                                             "open() first")
        deadline = self.clock.now() + timeout
        blocks = []
        while True:
            block = self._read()
            if block is not None and len(block):
                blocks.append(block)
            if not self._open:  # lost: the last samples first, the error at the next call
                if blocks:
                    return SampleBlock.concat(blocks)
                error, self._lost = self._lost, None
                raise error
            flight = self.clock.in_flight(self.address)
            if blocks and (self.clock.realtime or not flight):
                return SampleBlock.concat(blocks)
            if self.clock.now() >= deadline:
                return SampleBlock.concat(blocks) if blocks else None
            if not (self.clock.realtime or flight):
                self.clock.idle()  # lockstep time: wait for the twin's next delivery

    def backlog(self) -> bool:
        """Has the link bytes on their way that were not read yet (never when closed)? What a
        reader on a `drivers.clock.SteppedClock` has to take before time moves on."""
        return self._open and self.clock.in_flight(self.address)

    def _read(self):
        """The samples in what the link has now (None if nothing came); on a lost serial device
        the link is closed and the error kept in `_lost`."""
        try:
            if not (self.clock.realtime or self.clock.in_flight(self.address)
                    or self._link.waiting()):
                return None  # lockstep time: nothing sent, nothing to wait for
            data = self._link.read()
            self.clock.taken(self.address, len(data))
        except (serial.SerialException, OSError) as exc:
            self.close()
            self._lost = DeviceLostError(
                self.address, f"MAVLink device on {self.address} was lost ({exc}). The samples "
                "read so far are kept; reconnect it and call open() to continue.")
            self._lost.__cause__ = exc
            return None
        return self.decoder.decode(data, self.clock.now()) if data else None

    def _first_block(self) -> SampleBlock:
        """The first IMU samples (asking for the stream); MavlinkError after `wait_s`."""
        section = self.profile.mavlink
        deadline = time.monotonic() + max(section.wait_s, reply_timeout(self.clock))
        asked, heard = -math.inf, 0
        while time.monotonic() < deadline:
            # ask again every REQUEST_EVERY s, and at once when the first message comes (on UDP
            # the station can answer only once it has heard from the flight controller)
            again = time.monotonic() - asked >= REQUEST_EVERY or (self.stats.messages and not heard)
            if section.request_stream and again:
                self.request_stream()
                asked, heard = time.monotonic(), self.stats.messages
            block = self._read()
            if not self._open:
                error, self._lost = self._lost, None
                raise error
            if block is not None and len(block):
                return block
            if not (self.clock.realtime or self.clock.in_flight(self.address)):
                time.sleep(0.002)  # lockstep time stands still until the stream starts
        raise MavlinkError(self.address, self._silence())

    def _silence(self) -> str:
        """Why no IMU message came, from what did (the error of `open()`)."""
        section, message = self.profile.mavlink, self.profile.mavlink.message
        want = (f"{message.name} (#{message.msg_id}) instance {message.instance} from system "
                f"{section.system_id} component {section.component_id}")
        head = f"no {want} on {self.address} within {section.wait_s:g} s"
        stats, seen = self.stats, self.decoder.seen
        if not seen:
            garbled = (f"{stats.bytes} bytes came but no valid MAVLink message "
                       f"({stats.crc_failures} CRC failures): check the baud rate "
                       f"([mavlink] baudrate = {section.baudrate}) and that the port speaks "
                       "MAVLink" if stats.bytes else "nothing came: check that the flight "
                       "controller is powered and sends MAVLink on this port")
            return f"{head}; {garbled}"
        listed = ", ".join(f"{name}{'' if inst is None else f' instance {inst}'} x{n} from "
                           f"{sys_id}/{comp}" for (name, sys_id, comp, inst), n in seen.items())
        ours = [k for k in seen if k[3] is not None]
        if ours:
            return (f"{head}; seen: {listed}. Set [mavlink] instance, system_id and "
                    "component_id in the device profile to one of those")
        results = mavlink.enums["MAV_RESULT"]
        ack = (f"; it answered the request with {results[self.decoder.acks[-1]].name}"
               if self.decoder.acks else "")
        return (f"{head}; seen only: {listed}{ack}. Enable the IMU stream: SET_MESSAGE_INTERVAL "
                f"(MAV_CMD_SET_MESSAGE_INTERVAL, 511) for message {message.msg_id} at "
                f"{self.profile.imu.rate_hz:g} Hz ([mavlink] request_stream = true asks for it; "
                "PX4: `mavlink stream -s ... -r ...`, ArduPilot: the SRn_RAW_SENS rate)")
