"""Virtual flight controller: an IMU behind MAVLink, on a pty or UDP on 127.0.0.1.

    with MavlinkTwin("acc3_mavlink", source, clock) as twin:          # twin.port: a pty path
        with MavlinkImu(twin.port, "acc3_mavlink", clock) as imu: ...
    with MavlinkTwin(profile, source, clock, udp_port=14550) as twin:  # sends to 127.0.0.1:14550
        with MavlinkImu("udpin:127.0.0.1:14550", profile, clock) as imu: ...

It speaks as system `[mavlink] system_id`, component `component_id` of the device profile
(`drivers.mavlink_imu.MavlinkProfile`), every message packed by pymavlink's generated `common`
dialect (MAVLink 2, or 1 with `mavlink1`), one packet sequence counter over all its messages:

- HEARTBEAT once a second of clock time (a quadrotor running PX4), from `start()`;
- the profile's IMU message (HIGHRES_IMU, SCALED_IMU/2/3 or RAW_IMU with its instance), sample n
  taken at `time_of(n)` with the counts `source(times)` gives (k, m) for the profile's channels
  (the other fields 0), time stamps on the clock (boot at clock 0). It streams from the first
  COMMAND_LONG MAV_CMD_SET_MESSAGE_INTERVAL for that message (param2: the interval in us; 0: the
  profile's rate; -1: stop), acknowledged with COMMAND_ACK, or from `start()` with `stream=True`;
  a request for another message is answered MAV_RESULT_UNSUPPORTED; with `answer=False` requests
  are ignored (a vehicle whose stream must be enabled in its own configuration).

Samples are paced by the shared clock as in `drivers.twins.serial.SerialTwin` (on a stepped clock
each step, every byte booked on the clock's ledger until the station took it; lockstep time stands
still until the station asks for the IMU stream): if the twin falls
more than `max_lag` clock seconds behind it skips samples; on the pty, `unread_after` (wall
seconds) makes a port nobody reads lose the samples due (`drivers.twins.pty.PtyLink`); on UDP a
message nobody listens for is lost, as on a real network.

Fault knobs (attributes, changeable while streaming):
- `drop`: fraction of IMU messages lost on the way (their packet sequence numbers are missing);
- `corrupt`: fraction of IMU messages with one payload byte changed (the frame fails its CRC);
- `burst(n)`: n random bytes sent between two messages (line noise);
- `unplug()` / `plug()`: the pty closes (the reader gets an error) or the UDP sender goes silent,
  and comes back.
Every IMU message's fate, time and field values are logged (`log()`), so tests know exactly what an
ideal reader gets.
"""

import socket
import threading
import time
from typing import NamedTuple

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from drivers.clock import WallClock
from drivers.mavlink_imu import MavlinkProfile
from drivers.twins.pty import PtyLink
from drivers.twins.streamer import Streamer

# fates of IMU messages in the log
SENT, CORRUPTED, DROPPED, OVERFLOW, UNPLUGGED = range(5)


class TwinLog(NamedTuple):
    """Every IMU message so far: sample number, fate, clock time sampled, (k, m) field values."""

    seq: np.ndarray
    fate: np.ndarray
    time: np.ndarray
    values: np.ndarray


class UdpSender:
    """The flight controller's end of a UDP link: sends to 127.0.0.1:`port` (the station
    listening there, `udpin:`), reads what comes back to its own ephemeral port."""

    def __init__(self, port: int):
        self.target = ("127.0.0.1", int(port))
        self.port = f"udpin:127.0.0.1:{int(port)}"
        self._socket = None
        self.plug()

    def plug(self) -> None:
        if self._socket is None:
            self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._socket.bind(("127.0.0.1", 0))
            self._socket.setblocking(False)

    @property
    def plugged(self) -> bool:
        return self._socket is not None

    def unplug(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    close = unplug

    def unread(self) -> bool:
        return False  # UDP: a datagram nobody reads is lost by the network, not held

    def read(self) -> bytes:
        try:
            return self._socket.recv(65536) if self._socket is not None else b""
        except (BlockingIOError, ConnectionRefusedError):
            return b""

    def send(self, datagrams: list) -> int:
        """Send each message as its own datagram (as MAVLink routers do); how many went out."""
        for i, data in enumerate(datagrams):
            if self._socket is None:
                return i
            try:
                self._socket.sendto(data, self.target)
            except ConnectionRefusedError:  # nobody listens (an ICMP error of an earlier send)
                pass
            except BlockingIOError:
                return i
        return len(datagrams)


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 nobody listens on now (for a twin and its station to share)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


class MavlinkTwin(Streamer):
    """A flight controller with the IMU of `profile` (see the module docstring).

    source   : callable times (k,) in clock seconds -> counts (k, m) integers
    clock    : shared clock (`drivers.clock`: wall, scaled or stepped)
    udp_port : send over UDP to 127.0.0.1:udp_port instead of a pty
    stream   : stream the IMU from `start()` without waiting for a request
    """

    max_batch = 4096  # IMU messages encoded and written at once

    def __init__(self, profile, source, clock=None, udp_port=None, seed=0, drop=0.0,
                 corrupt=0.0, max_lag=1.0, unread_after=None, stream=False, answer=True,
                 mavlink1=False):
        self.profile = (profile if isinstance(profile, MavlinkProfile)
                        else MavlinkProfile.load(profile))
        self.message = self.profile.mavlink.message
        self.scale = np.asarray(self.profile.imu.scale, float)
        self.source, self.clock = source, clock or WallClock()
        self.drop, self.corrupt, self.max_lag = drop, corrupt, max_lag
        self.stream_on_start, self.answer, self.mavlink1 = stream, answer, mavlink1
        self.link = UdpSender(udp_port) if udp_port else PtyLink(unread_after, "ttyACM")
        self.port = self.link.port
        section = self.profile.mavlink
        self._encoder = mavlink.MAVLink(None, section.system_id, section.component_id)
        self._commands = mavlink.MAVLink(None)
        self._commands.robust_parsing = True
        self._fates = np.random.default_rng(seed)  # two draws per IMU message, in order
        self._rng = np.random.default_rng([seed, 1])  # damage and noise
        self._log = []
        self._garbage = b""  # noise to send next (`burst`)
        self._lock = threading.Lock()
        self._next_beat = 0.0  # clock time of the next heartbeat
        self.requests = []  # (message id, interval us) of each SET_MESSAGE_INTERVAL received
        self.streaming = threading.Event()
        self.rate_hz = None
        self._epoch = (0.0, 0)  # (clock time, sample number) the current rate counts from
        self._next = 0  # next sample number
        super().__init__()

    # -- device life -----------------------------------------------------------------------------

    def burst(self, n: int) -> None:
        """Send `n` random bytes before the next message (line noise)."""
        with self._lock:
            self._garbage += self._rng.integers(0, 256, int(n), dtype=np.uint8).tobytes()

    def start(self) -> "MavlinkTwin":
        """Start the heartbeat (and with `stream`, the IMU stream at the profile's rate)."""
        self._next_beat = self.clock.now()
        if self.stream_on_start:
            self._set_rate(self.profile.imu.rate_hz)
        return self._launch("mavlink-twin")

    # -- what was sent ---------------------------------------------------------------------------

    def time_of(self, seq) -> np.ndarray:
        """Clock time IMU sample number `seq` was (or will be) taken at, at the current rate."""
        start, first = self._epoch
        return start + (np.asarray(seq, dtype=np.int64) - first) / self.rate_hz

    def log(self) -> TwinLog:
        """Every IMU message so far (`TwinLog`)."""
        m = len(self.message.fields)
        if not self._log:
            return TwinLog(np.zeros(0, np.int64), np.zeros(0, np.int8), np.zeros(0),
                           np.zeros((0, m)))
        return TwinLog(*(np.concatenate(part) for part in zip(*self._log, strict=True)))

    # -- the flight controller -------------------------------------------------------------------

    def _run(self) -> None:
        """Answer requests and send what is due; then wait: a real-time clock 2 ms, a stepped
        clock its next step (`clock.pace`) once streaming. Before the station asks for the IMU,
        the twin listens without waiting on a stepped clock, so lockstep time stands still until
        the stream starts; meanwhile it sends a heartbeat each wall second (over UDP the station
        can ask only once it has heard the vehicle)."""
        try:
            beat = time.monotonic()
            while not self._stop.is_set():
                self._serve(self.link.read())
                if self._send_due():
                    continue
                if self.clock.realtime:
                    time.sleep(0.002)
                elif self.streaming.is_set():
                    self.clock.pace(self._stop)
                else:  # a heartbeat a wall second, for a station that answers only once heard
                    if time.monotonic() - beat > 1.0:
                        beat = time.monotonic()
                        self._write([self._heartbeat()])
                    time.sleep(0.002)
        except Exception as exc:  # noqa: BLE001 - told at once (Streamer._failed)
            self._failed(exc)

    def _serve(self, data: bytes) -> None:
        """Answer the SET_MESSAGE_INTERVAL commands in `data` addressed to this vehicle."""
        section = self.profile.mavlink
        for msg in self._commands.parse_buffer(data) or ():
            if (msg.get_type() != "COMMAND_LONG"
                    or msg.command != mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
                    or msg.target_system not in (0, section.system_id)
                    or msg.target_component not in (0, section.component_id)):
                continue
            self.requests.append((int(msg.param1), msg.param2))
            if not self.answer:
                continue
            ours = int(msg.param1) == self.message.msg_id
            if ours and msg.param2 < 0:
                self.streaming.clear()
            elif ours:
                self._set_rate(1e6 / msg.param2 if msg.param2 > 0 else self.profile.imu.rate_hz)
            result = mavlink.MAV_RESULT_ACCEPTED if ours else mavlink.MAV_RESULT_UNSUPPORTED
            self._write([self._pack(self._encoder.command_ack_encode(
                mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, result, 0, 0, msg.get_srcSystem(),
                msg.get_srcComponent()))])

    def _set_rate(self, rate_hz: float) -> None:
        """Stream at `rate_hz` from now on (the sample numbers go on)."""
        if self.streaming.is_set() and rate_hz == self.rate_hz:
            return
        self.rate_hz = float(rate_hz)
        self._epoch = (self.clock.now(), self._next)
        self.streaming.set()

    def _send_due(self) -> bool:
        """Send the noise, heartbeats and IMU messages due by now; False if nothing was due."""
        now = self.clock.now()
        with self._lock:
            out, self._garbage = [self._garbage], b""
        while self._next_beat <= now:
            out.append(self._heartbeat())
            self._next_beat += 1.0
        seq = np.zeros(0, np.int64)
        if self.streaming.is_set():
            due = int(np.floor((now - self._epoch[0]) * self.rate_hz)) + self._epoch[1] + 1
            keep = self.max_lag * self.rate_hz
            if due - self._next > keep:  # buffer overflow: skip the oldest
                skipped = np.arange(self._next, due - int(keep))
                self._record(skipped, np.full(len(skipped), OVERFLOW, np.int8))
                self._next = int(skipped[-1]) + 1
            seq = np.arange(self._next, min(due, self._next + self.max_batch))
        if len(seq):
            self._next = int(seq[-1]) + 1
            out.extend(self._imu(seq))
        if not any(out):
            return False
        lost = np.arange(len(out)) >= self._write(out)
        if len(seq) and lost.any():  # the IMU messages the link did not take
            fate = self._log[-1][1]
            gone = lost[-len(seq):] & (fate <= CORRUPTED)
            fate[gone] = UNPLUGGED if not self.plugged else OVERFLOW
        return True

    def _heartbeat(self) -> bytes:
        """One HEARTBEAT, packed: a quadrotor running PX4, in standby."""
        return self._pack(self._encoder.heartbeat_encode(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0,
            mavlink.MAV_STATE_STANDBY))

    def _imu(self, seq: np.ndarray) -> list:
        """The IMU messages of samples `seq` (dropped ones empty), logged with their fates."""
        times = self.time_of(seq)
        counts = np.asarray(self.source(times))
        m = len(self.message.fields)
        if counts.shape != (len(seq), m) or not np.issubdtype(counts.dtype, np.integer):
            raise ValueError("twin source must return integer counts of shape "
                             f"({len(seq)}, {m}); got {counts.dtype} {counts.shape}")
        values = self.message.wire_values(counts, self.scale)
        fate = np.full(len(seq), SENT, np.int8)
        draws = self._fates.random((len(seq), 2))  # the same fates however the stream is cut
        fate[draws[:, 0] < self.corrupt] = CORRUPTED
        fate[draws[:, 1] < self.drop] = DROPPED
        frames = []
        for t, row, f in zip(times, values, fate, strict=True):
            frame = self._pack(self.message.encode(self._encoder, t, row))
            frames.append(self._damage(frame) if f == CORRUPTED else b"" if f else frame)
        self._record(seq, fate, times, values)
        return frames

    def _damage(self, frame: bytes) -> bytes:
        """`frame` with one payload byte changed: its CRC fails, its framing holds."""
        header = 6 if frame[0] == mavlink.PROTOCOL_MARKER_V1 else 10
        data = bytearray(frame)
        data[int(self._rng.integers(header, len(data) - 2))] ^= int(self._rng.integers(1, 256))
        return bytes(data)

    def _pack(self, msg) -> bytes:
        """`msg` packed with the next packet sequence number."""
        data = msg.pack(self._encoder, force_mavlink1=self.mavlink1)
        self._encoder.seq = (self._encoder.seq + 1) % 256
        return bytes(data)

    def _record(self, seq, fate, times=None, values=None) -> None:
        m = len(self.message.fields)
        times = self.time_of(seq) if times is None else times
        values = np.full((len(seq), m), np.nan) if values is None else values
        self._log.append((seq, fate, times, np.asarray(values, float)))

    def _write(self, frames: list) -> int:
        """Write `frames` (b"" for none); how many of them, from the first, the link took. The
        bytes are booked on the clock's ledger first (in flight until the station took them:
        `drivers.clock`), what the link did not take is unbooked, and the reader nudged."""
        ends = np.cumsum([len(f) for f in frames])
        self.clock.sent(self.port, int(ends[-1]))
        if isinstance(self.link, UdpSender):
            sent = self.link.send([f for f in frames if f])
            took = int(np.searchsorted(np.cumsum([bool(f) for f in frames]), sent, "right"))
            written = int(ends[took - 1]) if took else 0
        else:
            written = self.link.write(b"".join(frames), self._stop, full=self.clock.nudge)
            took = int(np.searchsorted(ends, written, "right"))
        self.clock.sent(self.port, written - int(ends[-1]))
        self.clock.nudge()
        return took
