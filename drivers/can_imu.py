"""CAN IMU driver: DBC-described frames -> timestamped `SampleBlock`s (python-can, cantools).

One sample of m channels travels as one or more CAN frames that all carry the same sample counter
(an n-bit integer that wraps). The DBC file describes the frames and their signals; the device
profile (TOML: `[imu]` and `[can]` sections) says which frames make one sample, which signal is the
counter and which signal feeds which channel. The raw integer value of a signal is the channel's
count; the profile's `scale` (counts per SI unit) converts counts to SI units.

Live: `CanImu(bus, profile)` is an `ImuDriver` (drivers/__init__.py); `bus` is the `can.Bus`
keyword arguments (interface, channel, bitrate...): the driver opens the bus itself, so that it
can open it again after a loss. It runs one `can.Notifier` on the bus with one listener that never
lets an exception escape (an escaping exception would kill the notifier thread), decodes frames as
they arrive and, when asked, writes every raw frame to a `can.Logger` file (`.blf` or `.log`; one
file from `open()` to `close()`, across reconnections). `replay(log_path, profile)` decodes such a
file to the same samples.

A bus that raises (an unplugged adapter) loses the link: `read_block` hands out the samples decoded
before, then raises `CanBusError`; `open()` opens a new bus on the same address.

Frames that the profile does not know, short frames, and samples whose frames are incomplete (a lost
frame of a multi-frame sample) are counted in `CanStats`, never emitted half-filled.
"""

import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Self

import can
import cantools
import numpy as np

from drivers import LinkStats
from drivers.clock import WallClock
from drivers.errors import CanBusError
from drivers.profile import ImuSection, Profile, ProfileError, Section, load_profile
from drivers.samples import SampleBlock, restart_seq

DEFAULT_MAX_GAP = 4
"""Largest counter step taken as samples lost (3 samples, 1.5 ms at 2 kHz): CAN retransmits
damaged frames, so a longer loss is rare, while a device reset sets the counter back to 0 from
anywhere; a step beyond is read as a restart (a gap of unknown length) rather than a jump of
hundreds of samples that would shift every later sample's time."""

LOST_BUS_PAUSE = 0.1
"""Wall seconds the listener rests after each error of a lost bus (it raises at once on every
read until the driver notices the loss and stops the notifier)."""


@dataclass(frozen=True)
class CanSection:
    """`[can]`: how samples travel as frames.

    dbc     : DBC file describing the frames (path relative to the profile file)
    frames  : names of the DBC messages that make one sample, in the order the device sends them
    counter : name of the sample-counter signal present in every one of those frames
    signals : `[can.signals]`, channel name -> "MESSAGE.SIGNAL"
    id_offset : added to every DBC frame id on the wire (default 0): the unit's node offset, so
              that several units of one model share a bus, each configured to its own ids
    max_gap : largest counter step taken as samples lost on the bus (default DEFAULT_MAX_GAP,
              at most an eighth of the counter's range); a larger step, or one back, is the
              device restarting its counter (`SampleAssembler`)
    """

    dbc: Path
    frames: tuple
    counter: str
    signals: dict
    id_offset: int = 0
    max_gap: int = 0  # 0: DEFAULT_MAX_GAP

    @classmethod
    def parse(cls, s: Section) -> "CanSection":
        dbc = Path(s.source).parent / s.get("dbc", str)
        frames = s.get_list("frames", str)
        counter = s.get("counter", str)
        sub = s.sub("signals")
        signals = {channel: sub.get(channel, str) for channel in list(sub.table)}
        id_offset = s.get("id_offset", int, default=0)
        max_gap = s.get("max_gap", int, default=0)
        if max_gap < 0:
            raise s.error("max_gap", "must be a whole number of samples >= 1")
        s.finish()
        return cls(dbc, frames, counter, signals, id_offset, max_gap)


@dataclass(frozen=True)
class CanProfile:
    """A CAN IMU profile: `[imu]` (channels, units, scale, rate) and `[can]`."""

    source: str
    imu: ImuSection
    can: CanSection

    @classmethod
    def from_profile(cls, profile: Profile) -> "CanProfile":
        imu = profile.section("imu", ImuSection.parse)
        can_section = profile.section("can", CanSection.parse)
        if set(can_section.signals) != set(imu.channels):
            raise ProfileError(f"{profile.source}: [can.signals] must map exactly the channels "
                               f"{list(imu.channels)}; it maps {sorted(can_section.signals)}")
        return cls(profile.source, imu, can_section)

    @classmethod
    def load(cls, path_or_name) -> "CanProfile":
        """Read a CAN IMU profile (file path or bundled name, e.g. "imu12_can")."""
        return cls.from_profile(load_profile(path_or_name))


@dataclass(frozen=True)
class _Slot:
    """One frame of a sample: its position in the sample, its DBC message, its channel columns,
    its id on the wire (the DBC's plus the profile's id_offset)."""

    index: int
    message: object
    columns: tuple  # (signal name, column) pairs
    frame_id: int


class FrameLayout:
    """The DBC messages of a profile, checked against each other, ready to encode and decode.

    slots           : one `_Slot` per frame of a sample, in sending order
    by_id           : (frame id, extended?) -> slot
    counter         : name of the counter signal; counter_modulus: 2**its width
    channels        : channel names; lo, hi: (m,) raw range of each channel's signal
    """

    def __init__(self, profile: CanProfile):
        can_section, dbc = profile.can, profile.can.dbc
        try:
            db = cantools.database.load_file(dbc)
        except FileNotFoundError:
            raise ProfileError(f"DBC file {dbc} not found; fix [can] dbc in {profile.source} "
                               "(it is relative to the profile file)") from None
        except Exception as exc:  # noqa: BLE001 - cantools raises many types
            raise ProfileError(f"DBC file {dbc} cannot be parsed: {exc}") from None
        self.channels, self.counter = profile.imu.channels, can_section.counter
        messages = [_message(db, name, dbc) for name in can_section.frames]
        columns = {name: [] for name in can_section.frames}
        ranges = []
        for col, channel in enumerate(self.channels):
            msg_name, _, sig_name = can_section.signals[channel].partition(".")
            if msg_name not in columns:
                raise ProfileError(f"channel {channel!r} maps to {can_section.signals[channel]!r}, "
                                   f"but {msg_name!r} is not one of [can] frames")
            ranges.append(_raw_range(_signal(db.get_message_by_name(msg_name), sig_name, dbc)))
            columns[msg_name].append((sig_name, col))
        widths = {_signal(m, self.counter, dbc).length for m in messages}
        if len(widths) != 1:
            raise ProfileError(f"counter {self.counter!r} must have one width in all frames")
        self.counter_modulus = 1 << widths.pop()
        self.max_gap = can_section.max_gap or min(DEFAULT_MAX_GAP, self.counter_modulus // 8)
        if not 1 <= self.max_gap <= self.counter_modulus // 8:
            raise ProfileError(f"{profile.source}: [can] max_gap {self.max_gap} must be 1.."
                               f"{self.counter_modulus // 8} (an eighth of the counter's range)")
        self.lo, self.hi = (np.array(r, dtype=np.int64) for r in zip(*ranges, strict=True))
        self.slots = tuple(_Slot(i, m, tuple(columns[m.name]),
                                 _wire_id(m, can_section.id_offset, profile.source))
                           for i, m in enumerate(messages))
        self.by_id = {(s.frame_id, s.message.is_extended_frame): s for s in self.slots}


def _wire_id(message, offset: int, source: str) -> int:
    """The id of `message` on the wire: its DBC id plus the unit's id_offset, within the range
    of its frame format (11 bits standard, 29 extended)."""
    bits = 29 if message.is_extended_frame else 11
    wire = message.frame_id + offset
    if not 0 <= wire < 1 << bits:
        raise ProfileError(f"{source}: [can] id_offset {offset} puts frame {message.name} "
                           f"(id {message.frame_id:#x}) at {wire:#x}, outside the {bits}-bit ids "
                           "of its frame format; choose the offset the unit is configured to")
    return wire


def _raw_range(sig) -> tuple:
    """Smallest and largest raw integer a DBC signal can carry."""
    if sig.is_signed:
        return -(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1
    return 0, (1 << sig.length) - 1


def _message(db, name: str, dbc: Path):
    try:
        return db.get_message_by_name(name)
    except KeyError:
        raise ProfileError(f"frame {name!r} of [can] frames is not in {dbc}") from None


def _signal(message, name: str, dbc: Path):
    try:
        sig = message.get_signal_by_name(name)
    except KeyError:
        raise ProfileError(f"signal {name!r} is not in frame {message.name!r} of {dbc}") from None
    if sig.is_float:
        raise ProfileError(f"signal {message.name}.{name} is a float; counts must be integers")
    return sig


@dataclass
class CanStats(LinkStats):
    """Counters of what the decoder saw (LinkStats' samples, gaps, dropped, duplicates, restarts,
    and the frames). Every frame lands in exactly one of `used` (including a repeated sample's),
    `unknown`, `short` (fewer data bytes than the DBC says) and `orphaned` (part of an incomplete
    sample). `dropped` counts the samples missing between
    consecutive counters, whether all their frames were lost or only some (`incomplete`)."""

    frames: int = 0
    used: int = 0
    unknown: int = 0
    short: int = 0
    orphaned: int = 0
    incomplete: int = 0  # samples dropped because one of their frames never arrived
    errors: int = 0  # exceptions caught in the listener (decoder, logger, bus), see `last_error`
    last_error: str = ""


class SampleAssembler:
    """Pure decoder: feed frames in bus order, take complete samples. No threads, no I/O.

    A sample is complete when every frame of the profile has arrived with the same counter value;
    frames are collected until the counter changes. The counter is unwrapped into `seq`: a step
    forward of at most the layout's `max_gap` is a gap (samples lost on the bus), and so is a
    longer step forward that the host time since the last sample explains at `rate_hz` (within
    a quarter of it: an outage of the adapter, the device counting on); any other step (back, to
    0 after a reset, or far forward) is the device restarting its counter: a new segment
    (`restart_seq`, counted in `restarts`), a gap of unknown length, never a jump.
    """

    def __init__(self, layout: FrameLayout, rate_hz: float | None = None):
        self.layout = layout
        self.rate_hz = rate_hz
        self.stats = CanStats()
        m = len(layout.channels)
        self._row = np.zeros(m, dtype=np.int64)
        self._have = []  # slots filled for the pending counter
        self._counter = None
        self._last = None  # (counter, seq, counts) of the last emitted sample
        self._last_host = None  # its host time
        self._counts, self._seq, self._host = [], [], []

    def feed(self, msg: can.Message, host_time: float) -> None:
        """Account for one received frame; completes a sample when its last frame arrives."""
        self.stats.frames += 1
        slot = None
        if not (msg.is_error_frame or msg.is_remote_frame):
            slot = self.layout.by_id.get((msg.arbitration_id, msg.is_extended_id))
        if slot is None:
            self.stats.unknown += 1
            return
        data = bytes(msg.data)
        if len(data) < slot.message.length:
            self.stats.short += 1
            return
        values = slot.message.decode(data[:slot.message.length], decode_choices=False,
                                     scaling=False)
        counter = values[self.layout.counter]
        if counter != self._counter or slot.index in self._have:
            self._drop_pending()
            self._counter = counter
        self._have.append(slot.index)
        for name, col in slot.columns:
            self._row[col] = values[name]
        if len(self._have) == len(self.layout.slots):
            self._emit(host_time)

    def _drop_pending(self) -> None:
        if self._have:
            self.stats.incomplete += 1
            self.stats.orphaned += len(self._have)
        self._have = []

    def _emit(self, host_time: float) -> None:
        """Hand out the completed sample, unless it repeats the last one (same counter, same
        counts: a duplicate, counted). A forward step of at most `max_gap` is a gap; the same
        counter with other counts, or any other step, is a device that restarted its numbering
        (`restart_seq`: a new segment). Without a device time a restart that lands within
        `max_gap` after the last counter cannot be told from a gap."""
        counter = self._counter
        if self._last is None:
            seq = counter
        else:
            last_counter, last_seq, last_row = self._last
            step = (counter - last_counter) % self.layout.counter_modulus
            if step == 0 and np.array_equal(self._row, last_row):
                self.stats.duplicates += 1
                self.stats.used += len(self._have)
                self._have, self._counter = [], None
                return
            if step == 0 or not (step <= self.layout.max_gap or self._explained(step, host_time)):
                self.stats.restarts += 1
                seq = restart_seq(counter, last_seq, self.layout.counter_modulus)
            else:
                seq = last_seq + step
                self.stats.gaps += step > 1
                self.stats.dropped += step - 1
        self._last = (counter, seq, self._row.copy())
        self._last_host = host_time
        self._counts.append(self._row.copy())
        self._seq.append(seq)
        self._host.append(host_time)
        self.stats.samples += 1
        self.stats.used += len(self._have)
        self._have, self._counter = [], None

    def _explained(self, step: int, host_time: float) -> bool:
        """Does the host time since the last sample explain a counter `step` forward (within a
        quarter of the samples due at `rate_hz`, and less than half the counter's range)?"""
        if self.rate_hz is None or self._last_host is None:
            return False
        due = (host_time - self._last_host) * self.rate_hz
        return step < self.layout.counter_modulus // 2 and abs(step - due) <= 0.25 * due

    def ready(self) -> bool:
        """True when completed samples wait to be taken."""
        return bool(self._seq)

    def finish(self) -> None:
        """End of stream: a sample still waiting for frames is incomplete."""
        self._drop_pending()
        self._counter = None

    def take(self) -> SampleBlock | None:
        """The samples completed since the last call, or None."""
        if not self._seq:
            return None
        k = len(self._seq)
        block = SampleBlock(counts=np.array(self._counts, dtype=np.int64).reshape(k, -1),
                            seq=np.array(self._seq, dtype=np.int64),
                            device_time=np.full(k, np.nan),
                            host_time=np.array(self._host, dtype=np.float64),
                            channels=self.layout.channels)
        self._counts, self._seq, self._host = [], [], []
        return block


class _Receiver(can.Listener):
    """The one listener on the bus: decodes and logs each frame; contains every exception."""

    def __init__(self, assembler: SampleAssembler, clock, logger: can.Listener | None):
        self.assembler = assembler
        self.clock = clock
        self.logger = logger
        self.lock = threading.Lock()
        self.data_ready = threading.Condition(self.lock)
        self.lost = None  # the bus' exception once the link is lost
        self.received = 0  # frames handed to this listener by the present bus

    def on_message_received(self, msg: can.Message) -> None:
        now = self.clock.now()
        with self.lock:
            try:
                self.assembler.feed(msg, now)
            except Exception as exc:  # noqa: BLE001 - a decoder bug must not kill the notifier
                self._count(exc)
            self.received += 1
            if self.assembler.ready():
                self.data_ready.notify_all()
        self.clock.nudge()  # a reader waiting on a stepped clock looks again
        if self.logger is not None:
            try:
                self.logger.on_message_received(msg)
            except Exception as exc:  # noqa: BLE001 - e.g. disk full: keep decoding
                with self.lock:
                    self._count(exc)

    def on_error(self, exc: Exception) -> None:
        """Called by the Notifier when the bus itself raised: the link is lost (counted once; the
        dead bus raises again on every read until the driver stops the notifier)."""
        with self.lock:
            if self.lost is None:
                self.lost = exc
                self._count(exc)
                self.data_ready.notify_all()
                return
        time.sleep(LOST_BUS_PAUSE)

    def _count(self, exc: Exception) -> None:
        self.assembler.stats.errors += 1
        self.assembler.stats.last_error = f"{type(exc).__name__}: {exc}"

    def stop(self) -> None:
        """Called by `CanImu.close` (a lost bus' notifier is stopped without it, the log goes on):
        close the log (a failure to flush is counted)."""
        if self.logger is not None:
            try:
                self.logger.stop()
            except Exception as exc:  # noqa: BLE001 - a failed flush must not stop the close
                with self.lock:
                    self._count(exc)


class CanImu:
    """An `ImuDriver` for a live CAN IMU; `bus` holds the `can.Bus` keyword arguments.

    `log_path` (".blf" or ".log") records every raw frame with `can.Logger` for `replay`.
    """

    profile_type = CanProfile

    def __init__(self, bus: dict, profile, clock=None, log_path=None):
        self.bus_config = dict(bus)
        self.channel = f"{self.bus_config.get('interface', 'can')}:{self.bus_config.get('channel')}"
        self.profile = profile if isinstance(profile, CanProfile) else CanProfile.load(profile)
        self.log_path = Path(log_path) if log_path is not None else None
        self.connections = 0
        self.bus = None
        self._assembler = SampleAssembler(FrameLayout(self.profile), self.profile.imu.rate_hz)
        self._clock = clock or WallClock()
        self._receiver = None  # from open() to close(): it holds the raw log
        self._notifier = None

    @property
    def stats(self) -> CanStats:
        """Link counters, cumulative over reconnects."""
        return self._assembler.stats

    def open(self) -> "CanImu":
        """Open the bus and start decoding (and the raw log); after a loss, a new bus on the same
        address (the log goes on). A no-op while the bus is open."""
        if self.bus is not None:
            return self
        try:
            bus = can.Bus(**self.bus_config)
        except (can.CanError, OSError, ValueError) as exc:
            raise CanBusError(self.channel, f"cannot open CAN bus {self.channel}: {exc}. Check the "
                              "adapter, the interface name and the channel.") from exc
        if self._receiver is None:
            logger = can.Logger(self.log_path) if self.log_path is not None else None
            self._receiver = _Receiver(self._assembler, self._clock, logger)
        self._receiver.lost, self._receiver.received = None, 0
        self.bus = bus
        self._notifier = can.Notifier(bus, [self._receiver], timeout=0.1)
        self.connections += 1
        return self

    def read_block(self, timeout: float = 0.1) -> SampleBlock | None:
        """Samples completed since the last call; waits up to `timeout` clock seconds for the
        first. Raises CanBusError once the bus is lost and its last samples are out."""
        if self.bus is None:
            raise CanBusError(self.channel,
                              f"CAN bus {self.channel} is not open; call open() first")
        deadline = self._clock.now() + timeout
        while True:
            with self._receiver.lock:
                if not self._assembler.ready() and self._receiver.lost is None \
                        and self._clock.realtime:
                    self._receiver.data_ready.wait(timeout / self._clock.speed)
                block, lost = self._assembler.take(), self._receiver.lost
            if block is not None or lost is not None or self._clock.realtime \
                    or self._clock.now() >= deadline:
                break
            self._clock.idle()  # lockstep time: wait for the twin's next delivery
        if block is None and lost is not None:
            self._disconnect()
            raise CanBusError(self.channel, f"CAN IMU on {self.channel} was lost ({lost}). The "
                              "samples read so far are kept; reconnect the adapter and call open() "
                              "to continue.") from lost
        return block

    def backlog(self) -> int:
        """Frames the bus has received that are not decoded yet, where the interface tells
        (python-can's virtual bus, whose queue counts every frame put in it; otherwise 0), plus
        the decoded samples not read yet: what a reader on a `drivers.clock.SteppedClock` has to
        take before time moves on."""
        bus, receiver = self.bus, self._receiver
        if bus is None or receiver is None:
            return 0
        queue = getattr(bus, "queue", None)
        queued = queue.unfinished_tasks - receiver.received if queue is not None else 0
        return queued + int(self._assembler.ready())

    def close(self) -> None:
        """Stop decoding, shut the bus down and close the log; a sample still missing frames counts
        as incomplete."""
        self._disconnect()
        if self._receiver is not None:
            self._receiver.stop()
            self._receiver = None

    def _disconnect(self) -> None:
        """Stop the notifier (the receiver and its log stay) and shut the bus down."""
        if self.bus is None:
            return
        self._notifier.remove_listener(self._receiver)
        self._notifier.stop()
        self.bus.shutdown()
        self.bus, self._notifier = None, None
        with self._receiver.lock:
            self._assembler.finish()

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()


def replay(log_path, profile: CanProfile) -> tuple:
    """Decode a raw CAN log (.blf, .log, ...) to (SampleBlock or None, CanStats).

    `host_time` of a replayed sample is the logged timestamp of its last frame.
    """
    assembler = SampleAssembler(FrameLayout(profile), profile.imu.rate_hz)
    with can.LogReader(log_path) as reader:
        for msg in reader:
            assembler.feed(msg, msg.timestamp)
    assembler.finish()
    return assembler.take(), assembler.stats
