"""Rotary table driver over Modbus TCP (pymodbus synchronous client).

The table is a set of holding registers described by the device profile's `[table]` section
(`TableRegisterMap`): a status bit field (ready, moving, at rate, fault), a run/stop command, the
rate setpoint, the measured rate and the cumulative angle, the last three as signed 32-bit fixed
point numbers (register integer = SI value * scale) with a configurable word order. A two-axis
table adds an optional position axis (the inner axis the unit is mounted on, docs/devices.md): a
position setpoint and the measured position (int32 fixed point, counts per rad) and an
`in_position` status bit; a map without them is a one-axis table, exactly as before. The position
axis may also have a rate mode (optional, all or none; it needs the position axis): a
`position_mode` register (uint16: `command_values.position_spin` runs the axis at
`position_rate_setpoint`, `command_values.position_hold` brings it to rest and holds it where it
stops, or moves it to a new `position_setpoint`), the rate setpoint and the measured rate (int32
fixed point at the rate scale) and the status bits `position_at_rate` and `position_moving`; the
`position` register then reads the cumulative angle. The layout is generic, after the per-axis
objects of the CiA 402 drive profile (IEC 61800-7-201): a mode register as "modes of operation"
(0x6060: profile position / profile velocity), the rate setpoint as "target velocity" (0x60FF),
the measured rate as "velocity actual value" (0x606C), `position_at_rate` as the statusword's
"target reached" in velocity mode; no rate-table vendor's command set is copied.
A table with
a motorised mounting fixture (a robot that re-mounts the unit in the positions of the protocol's
plan) adds a `mount` register (uint16: the position asked for, 1-based; 0 none) and a `mounted`
status bit (the fixture holds the unit in the position asked for).

`RotaryTable(host, port, register_map)` offers `set_rate`, `start`, `stop`, `state()`, on a
two-axis table `set_position` (waits until the table reports in position, or `TableTimeout`), with
a rate mode `spin_position` (runs the position axis at a rate and waits until it is there, or
`TableTimeout` with both axes stopped) and,
with a fixture, `mount` (waits until the fixture reports the unit mounted, or `TableTimeout`). Every
failure of a transaction becomes a `TableError` whose message names the table (`rotary table at
host:port`), what happened and what to do: `TableBusy` (code 6), `TableTimeout` (no reply),
`TableLinkError` (connection refused, reset or broken: the client reconnects on the next try),
`TableReplyError` (fewer registers than asked, a garbled reply), `TableFault` (code 4, device
failure), `TableError` for the rest (e.g. code 2: the register map does not match the table). A busy
answer is retried a bounded number of times (the controller did nothing); a timeout, a lost
connection or a bad reply only where repeating is safe: reads, the setpoint and stop, never a
start (it may have been executed). `stop` stops every axis: the rate axis and, with a rate
mode, the position axis (back to position mode, held where it comes to rest). After any failure
the driver tries to stop the table and notes on the error whether it could
(`error.table_stopped`); as a context manager it stops the table on exit, whatever happened.

A table may have a communication watchdog (optional `[table.watchdog]`, `drivers.heartbeat`): the
controller stops the table by itself when the host's heartbeat counter has not changed for the
watchdog's period, and sets the status bit `tripped_bit` (`TableReading.watchdog_tripped`).
`heartbeat(on_error)` writes that counter from a thread while a session holds the table. The
client is shared by that thread and the caller's: every transaction holds the driver's lock
(pymodbus' synchronous clients are not thread-safe).
"""

import contextlib
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Self

from pymodbus.client import ModbusTcpClient

from drivers.clock import WallClock, reply_timeout
from drivers.errors import (
    TableBusy,
    TableError,
    TableFault,
    TableLinkError,
    TableReplyError,
    TableTimeout,
)
from drivers.heartbeat import Heartbeat, Watchdog
from drivers.modbus_request import Failures, link_words, read_registers, request
from drivers.profile import ProfileError, Section, load_profile

log = logging.getLogger(__name__)

INT32 = ModbusTcpClient.DATATYPE.INT32
STATUS_BITS = ("ready", "moving", "at_rate", "fault")
WORD_REGISTERS = ("status", "command")  # one 16-bit register each
FIXED_REGISTERS = ("rate_setpoint", "rate", "angle")  # int32 fixed point, two registers each
POSITION_REGISTERS = ("position_setpoint", "position")  # optional position axis, int32 fixed point
POSITION_BIT = "in_position"  # status bit of the optional position axis
RATE_MODE_REGISTERS = ("position_mode", "position_rate_setpoint", "position_rate")
RATE_MODE_FIXED = ("position_rate_setpoint", "position_rate")  # int32 fixed point at rate_scale
RATE_MODE_BITS = ("position_at_rate", "position_moving")  # status bits of the rate mode
FIXTURE_REGISTER = "mount"  # optional mounting fixture: the position asked for (uint16, 1-based)
FIXTURE_BIT = "mounted"  # its status bit: the unit is held in the position asked for
STOP_RETRY_PAUSE = 0.05  # s between two emergency stop attempts
FAILURES = Failures(TableError, TableTimeout, TableLinkError, TableReplyError, TableBusy,
                    TableFault)


def not_stopped(error: BaseException, stop_error: BaseException) -> None:
    """Say on `error` that the table could not be stopped after it: `table_stopped` False and a
    note telling the operator to stop it by hand."""
    error.table_stopped = False
    error.add_note(f"stop command could not be sent ({stop_error}) - stop the table by hand")


@dataclass(frozen=True)
class TableRegisterMap:
    """Holding-register layout of a rotary table (addresses 0-based, as on the wire).

    registers   : name -> address for `status`, `command` (16 bit) and `rate_setpoint`, `rate`,
                  `angle` (int32 fixed point, two registers)
    status_bits : `ready`, `moving`, `at_rate`, `fault` -> bit number in the status register
    run, stop   : values written to the command register
    rate_scale  : register counts per rad/s; angle_scale: counts per rad
    word_order  : "big" (high word at the lower address) or "little"
    position axis (optional, all or none): registers `position_setpoint`, `position` (int32 fixed
                  point at angle_scale counts per rad) and status bit `in_position`
    its rate mode (optional, all or none, with the position axis only): registers
                  `position_mode` (uint16), `position_rate_setpoint`, `position_rate` (int32 fixed
                  point at rate_scale) and status bits `position_at_rate`, `position_moving`;
                  position_spin, position_hold: the values written to `position_mode`
    fixture (optional, both or none): register `mount` (uint16) and status bit `mounted`
    watchdog    : the controller's communication watchdog (`drivers.heartbeat.Watchdog`), or None
    """

    registers: dict
    status_bits: dict
    rate_scale: float
    angle_scale: float
    device_id: int = 1
    run: int = 1
    stop: int = 0
    word_order: str = "big"
    position_spin: int = 1
    position_hold: int = 0
    watchdog: Watchdog | None = None
    span: tuple = field(init=False)  # (first address, count) of one read covering every register
    # but the watchdog's heartbeat (written only)

    def __post_init__(self):
        missing = [n for n in WORD_REGISTERS + FIXED_REGISTERS if n not in self.registers]
        missing += [f"status_bits.{n}" for n in STATUS_BITS if n not in self.status_bits]
        axis = [n in self.registers for n in POSITION_REGISTERS]
        axis += [POSITION_BIT in self.status_bits]
        fixture = [FIXTURE_REGISTER in self.registers, FIXTURE_BIT in self.status_bits]
        rate_mode = [n in self.registers for n in RATE_MODE_REGISTERS]
        rate_mode += [n in self.status_bits for n in RATE_MODE_BITS]
        for names, present in ((POSITION_REGISTERS + (POSITION_BIT,), axis),
                               ((FIXTURE_REGISTER, FIXTURE_BIT), fixture),
                               (RATE_MODE_REGISTERS + RATE_MODE_BITS, rate_mode)):
            if any(present) and not all(present):  # an optional part is all there or absent
                missing += [n for n, on in zip(names, present, strict=True) if not on]
        if any(rate_mode) and not any(axis):
            missing += [n for n, on in zip(POSITION_REGISTERS + (POSITION_BIT,), axis,
                                           strict=True) if not on]  # a rate mode of what?
        if missing:
            raise ProfileError(f"table register map lacks {missing}; see docs/devices.md")
        used = sorted(a for n in self.quantities for a in self.addresses(n))
        if self.watchdog is not None:
            self._check_watchdog(used)
        if len(set(used)) != len(used) or used[0] < 0 or used[-1] > 0xFFFF:
            raise ProfileError(f"table registers overlap or leave 0..65535: {self.registers}")
        if used[-1] - used[0] + 1 > 125:
            raise ProfileError("table registers must fit in one read of 125 registers")
        if self.word_order not in ("big", "little"):
            raise ProfileError(f"word_order must be 'big' or 'little', got {self.word_order!r}")
        if not (self.rate_scale > 0 and self.angle_scale > 0):
            raise ProfileError("table scales (counts per rad/s, counts per rad) must be positive")
        if self.rate_mode and self.position_spin == self.position_hold:
            raise ProfileError("command_values position_spin and position_hold must differ")
        if not all(0 <= b < 16 for b in self.status_bits.values()):
            raise ProfileError(f"status bits must be numbers 0..15, got {self.status_bits}")
        object.__setattr__(self, "span", (used[0], used[-1] - used[0] + 1))

    def _check_watchdog(self, used: list) -> None:
        """Refuse a watchdog whose register or tripped bit another quantity already has."""
        w = self.watchdog
        if w.register in used:
            owner = next(n for n in self.quantities if w.register in self.addresses(n))
            raise ProfileError(f"watchdog register {w.register} is also the {owner} "
                               "register; give the heartbeat its own address")
        if w.tripped_bit in self.status_bits.values():
            owner = next(n for n, b in self.status_bits.items() if b == w.tripped_bit)
            raise ProfileError(f"watchdog tripped_bit {w.tripped_bit} is also status bit "
                               f"{owner}; give it its own bit")

    @property
    def two_axis(self) -> bool:
        """Does the table have a position axis?"""
        return "position" in self.registers

    @property
    def rate_mode(self) -> bool:
        """Can the position axis run at a rate (a two-axis session's spin about it)?"""
        return "position_mode" in self.registers

    @property
    def fixture(self) -> bool:
        """Does the table have a motorised mounting fixture?"""
        return FIXTURE_REGISTER in self.registers

    @property
    def quantities(self) -> tuple:
        """Names of the registers this map lays out."""
        position = POSITION_REGISTERS if self.two_axis else ()
        position += RATE_MODE_REGISTERS if self.rate_mode else ()
        return (WORD_REGISTERS + FIXED_REGISTERS + position
                + ((FIXTURE_REGISTER,) if self.fixture else ()))

    @classmethod
    def parse(cls, s: Section) -> "TableRegisterMap":
        """Build from the `[table]` section of a device profile (see drivers.profile)."""
        s.get("name", str, default="rotary table")
        registers, bits, scale = s.sub("registers"), s.sub("status_bits"), s.sub("scale")
        commands = s.sub("command_values") if s.has("command_values") else None
        optional = tuple(n for n in POSITION_REGISTERS + RATE_MODE_REGISTERS + (FIXTURE_REGISTER,)
                         if registers.has(n))
        optional_bits = tuple(n for n in (POSITION_BIT, FIXTURE_BIT) + RATE_MODE_BITS
                              if bits.has(n))
        try:
            table = cls(
                registers={n: registers.get(n, int)
                           for n in WORD_REGISTERS + FIXED_REGISTERS + optional},
                status_bits={n: bits.get(n, int) for n in STATUS_BITS + optional_bits},
                rate_scale=scale.get("rate", float), angle_scale=scale.get("angle", float),
                device_id=s.get("device_id", int, default=1),
                run=commands.get("run", int, default=1) if commands else 1,
                stop=commands.get("stop", int, default=0) if commands else 0,
                position_spin=commands.get("position_spin", int, default=1) if commands else 1,
                position_hold=commands.get("position_hold", int, default=0) if commands else 0,
                word_order=s.get("word_order", str, default="big", choices=("big", "little")),
                watchdog=(Watchdog.parse(s.sub("watchdog"), "table") if s.has("watchdog")
                          else None))
        except ProfileError as exc:
            if str(exc).startswith(s.source):
                raise
            raise ProfileError(f"{s.source}: [table] {exc}") from None
        except ValueError as exc:
            raise ProfileError(f"{s.source}: [table] {exc}") from None
        for section in (s, registers, bits, scale) + ((commands,) if commands else ()):
            section.finish()
        return table

    @classmethod
    def load(cls, path_or_name) -> "TableRegisterMap":
        """Read the `[table]` section of a device profile (path or bundled name)."""
        return load_profile(path_or_name).section("table", cls.parse)

    def addresses(self, name: str) -> range:
        """Register addresses a named quantity occupies."""
        width = 2 if name in FIXED_REGISTERS + POSITION_REGISTERS + RATE_MODE_FIXED else 1
        return range(self.registers[name], self.registers[name] + width)

    def encode(self, value: float, scale: float) -> list:
        """SI value -> two registers of a signed 32-bit fixed-point number."""
        counts = round(value * scale)
        if not -(2**31) <= counts < 2**31:
            raise ValueError(f"{value!r} does not fit the table's 32-bit fixed point at scale "
                             f"{scale}; command a smaller value")
        return ModbusTcpClient.convert_to_registers(counts, INT32, word_order=self.word_order)

    def decode(self, words, scale: float) -> float:
        """Two registers of a signed 32-bit fixed-point number -> SI value."""
        return ModbusTcpClient.convert_from_registers(list(words), INT32,
                                                      word_order=self.word_order) / scale


@dataclass(frozen=True)
class TableReading:
    """What the table reports, read at host `time` (clock seconds): the middle of the request and
    its reply, which the table's state belongs to within +- `round_trip` / 2 (a busy host
    lengthens the round trip); rad/s and rad (cumulative, wrapping at 2**31 counts)."""

    time: float
    rate: float
    angle: float
    rate_setpoint: float
    running: bool
    ready: bool
    moving: bool
    at_rate: bool
    fault: bool
    position: float | None = None  # rad, the position axis (None: a one-axis table)
    position_setpoint: float | None = None
    in_position: bool | None = None
    position_rate: float | None = None  # rad/s, the position axis' rate mode (None: none)
    position_rate_setpoint: float | None = None
    position_spinning: bool | None = None  # in rate mode (position_mode = position_spin)
    position_at_rate: bool | None = None
    position_moving: bool | None = None
    mount: int | None = None  # the fixture's position asked for, 1-based (None: no fixture)
    mounted: bool | None = None
    watchdog_tripped: bool | None = None  # the watchdog stopped the table (None: no watchdog)
    round_trip: float = 0.0  # clock s from the request to its reply

    @property
    def resting(self) -> bool:
        """Every axis stands still: the rate axis and, with a rate mode, the position axis."""
        return not (self.moving or self.position_moving)


class RotaryTable:
    """Synchronous rotary-table client; one Modbus transaction per call, bounded retries.

    timeout       : wall seconds to wait for each reply (default `drivers.clock.reply_timeout`)
    retries       : extra tries after a timeout or a busy answer (busy ones `busy_backoff` s apart)
    stop_patience : seconds the driver keeps trying to stop the table after a failure
    clock         : stamps `TableReading.time` (share the recorder's clock)
    """

    def __init__(self, host: str, port: int, register_map: TableRegisterMap, timeout=None,
                 retries=2, busy_backoff=0.05, stop_patience=2.0, clock=None):
        self.host, self.port, self.map = host, port, register_map
        self.clock = clock or WallClock()
        timeout = reply_timeout(self.clock) if timeout is None else timeout
        self.timeout, self.retries, self.busy_backoff = timeout, int(retries), busy_backoff
        self.stop_patience = stop_patience
        self._client = ModbusTcpClient(host, port=port, timeout=timeout, retries=0)
        self._lock = threading.Lock()  # one transaction at a time (the heartbeat's thread too)

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.stop()
            if exc is not None:
                exc.table_stopped = True
        except TableError as stop_error:
            if exc is None:
                raise
            if getattr(exc, "table_stopped", None) is None:  # not said yet
                not_stopped(exc, stop_error)
        finally:
            self.close()

    def connect(self) -> None:
        """Open the TCP connection, or raise TableError naming the address."""
        if not self._client.connect():
            raise TableLinkError(f"{self.where}: cannot connect; check its power, cable and IP "
                                 "address")

    def close(self) -> None:
        self._client.close()

    def heartbeat(self, on_error):
        """A context manager writing the watchdog's heartbeat while entered
        (`drivers.heartbeat.Heartbeat`; its failures told to `on_error`); nothing for a table
        without a watchdog."""
        w = self.map.watchdog
        if w is None:
            return contextlib.nullcontext()
        return Heartbeat(
            lambda: self._request("read the watchdog heartbeat",
                                  lambda: self._read(w.register, 1)).registers[0],
            lambda count: self._request("write the watchdog heartbeat", lambda: (
                self._client.write_register(w.register, count, device_id=self.map.device_id))),
            w, self.clock, on_error, "rotary table")

    def set_rate(self, rate_rad_s: float) -> None:
        """Write the rate setpoint (rad/s, signed)."""
        if not math.isfinite(rate_rad_s):
            raise ValueError(f"rate setpoint must be a finite number of rad/s, got {rate_rad_s!r}")
        words = self.map.encode(rate_rad_s, self.map.rate_scale)
        self._operate("set rate", lambda: self._client.write_registers(
            self.map.registers["rate_setpoint"], words, device_id=self.map.device_id))

    def set_position(self, angle_rad: float, timeout: float = 60.0, poll: float = 0.05) -> \
            TableReading:
        """Move the position axis to `angle_rad` and wait (clock seconds, at most `timeout`) until
        the table reports in position there; returns that reading. A table without a position
        axis is an error; one that does not get there in time raises `TableTimeout` and is
        stopped."""
        if not self.map.two_axis:
            raise TableError(f"{self.where}: its register map has no position axis; use a "
                             "two-axis profile (e.g. table_two_axis) or mount the unit by hand")
        if not math.isfinite(angle_rad):
            raise ValueError(f"position setpoint must be a finite number of rad, got {angle_rad!r}")
        words = self.map.encode(angle_rad, self.map.angle_scale)
        self._operate("set position", lambda: self._client.write_registers(
            self.map.registers["position_setpoint"], words, device_id=self.map.device_id))
        return self._wait_until(
            lambda r: r.in_position and abs(r.position_setpoint - angle_rad)
            <= 1 / self.map.angle_scale, timeout, poll,
            lambda r: f"position axis not in position at {angle_rad:.4f} rad within {timeout} s "
                      f"(at {r.position:.4f} rad); check that nothing blocks it and the axis is "
                      "enabled")

    def spin_position(self, rate_rad_s: float, timeout: float = 60.0, poll: float = 0.05) -> \
            TableReading:
        """Run the position axis at `rate_rad_s` (rate mode) and wait (clock seconds, at most
        `timeout`) until the table reports it at rate; returns that reading. A table without the
        rate mode is an error; one that does not reach the rate in time raises `TableTimeout` and
        is stopped (both axes). `stop` ends the spin."""
        if not self.map.rate_mode:
            raise TableError(f"{self.where}: its register map has no rate mode of the position "
                             "axis; use a two-axis profile with one (e.g. table_two_axis)")
        if not math.isfinite(rate_rad_s):
            raise ValueError(f"position rate must be a finite number of rad/s, got "
                             f"{rate_rad_s!r}")
        words = self.map.encode(rate_rad_s, self.map.rate_scale)
        self._operate("set position rate", lambda: self._client.write_registers(
            self.map.registers["position_rate_setpoint"], words, device_id=self.map.device_id))
        self._operate("spin position axis", lambda: self._write_mode(self.map.position_spin),
                      repeat=False)
        return self._wait_until(
            lambda r: r.position_spinning and r.position_at_rate
            and abs(r.position_rate_setpoint - rate_rad_s) <= 1 / self.map.rate_scale,
            timeout, poll,
            lambda r: f"position axis not at {rate_rad_s:g} rad/s within {timeout} s (at "
                      f"{r.position_rate:.4f} rad/s); check that nothing blocks it and the axis "
                      "is enabled")

    def mount(self, position: int, timeout: float = 120.0, poll: float = 0.05) -> TableReading:
        """Ask the mounting fixture for `position` (1-based, as the plan numbers them) and wait
        (clock seconds, at most `timeout`) until it reports the unit mounted there; returns that
        reading. A table without a fixture is an error; a fixture that does not get there in
        time raises `TableTimeout` (the table is stopped)."""
        if not self.map.fixture:
            raise TableError(f"{self.where}: its register map has no mounting fixture; use a "
                             "profile with one (e.g. table_fixture) or mount the unit by hand")
        if not 1 <= position <= 0xFFFF:
            raise ValueError(f"fixture position must be 1..65535, got {position!r}")
        self._operate("mount", lambda: self._client.write_register(
            self.map.registers[FIXTURE_REGISTER], position, device_id=self.map.device_id))
        return self._wait_until(
            lambda r: r.mounted and r.mount == position, timeout, poll,
            lambda r: f"fixture did not report position {position} mounted within {timeout} s "
                      f"(asked: {r.mount}, mounted: {r.mounted}); check that nothing blocks it "
                      "and it is enabled")

    def _wait_until(self, done, timeout: float, poll: float, words) -> TableReading:
        """Poll `state()` until `done(reading)`; after `timeout` clock seconds stop the table and
        raise `TableTimeout` with `words(reading)`."""
        deadline = self.clock.now() + timeout
        while True:
            reading = self.state()
            if done(reading):
                return reading
            if self.clock.now() >= deadline:
                error = TableTimeout(f"{self.where}: {words(reading)}, then resume the session")
                self._emergency_stop(error)
                raise error
            self.clock.sleep(poll)

    def start(self) -> None:
        """Command the table to run towards the setpoint."""
        self._operate("start", lambda: self._write_command(self.map.run), repeat=False)

    def stop(self) -> None:
        """Command every axis to decelerate to rest: the rate axis and, with a rate mode, the
        position axis (position mode, held where it stops). Both commands are sent even if the
        first fails; the first failure is raised."""
        failure = None
        stops = [("stop", lambda: self._write_command(self.map.stop))]
        if self.map.rate_mode:
            stops.append(("stop position axis", lambda: self._write_mode(self.map.position_hold)))
        for what, call in stops:
            try:
                self._request(what, call)
            except TableError as error:
                failure = failure or error
        if failure is not None:
            raise failure

    def state(self) -> TableReading:
        """Read every register in one transaction."""
        first, count = self.map.span
        asked = self.clock.now()
        regs = self._operate("read state", lambda: self._read(first, count)).registers
        answered = self.clock.now()

        def words(name):
            return [regs[a - first] for a in self.map.addresses(name)]

        status = regs[self.map.registers["status"] - first]
        bits = {n: bool(status >> b & 1) for n, b in self.map.status_bits.items()}
        axis = {}
        if self.map.two_axis:
            axis = {"position": self.map.decode(words("position"), self.map.angle_scale),
                    "position_setpoint": self.map.decode(words("position_setpoint"),
                                                         self.map.angle_scale),
                    "in_position": bits[POSITION_BIT]}
        if self.map.rate_mode:
            axis |= {"position_rate": self.map.decode(words("position_rate"), self.map.rate_scale),
                     "position_rate_setpoint": self.map.decode(words("position_rate_setpoint"),
                                                               self.map.rate_scale),
                     "position_spinning": regs[self.map.registers["position_mode"] - first]
                     == self.map.position_spin,
                     **{n: bits[n] for n in RATE_MODE_BITS}}
        if self.map.fixture:
            axis |= {"mount": regs[self.map.registers[FIXTURE_REGISTER] - first],
                     "mounted": bits[FIXTURE_BIT]}
        if self.map.watchdog is not None:
            axis["watchdog_tripped"] = bool(status >> self.map.watchdog.tripped_bit & 1)
        return TableReading(
            time=(asked + answered) / 2, round_trip=answered - asked,
            rate=self.map.decode(words("rate"), self.map.rate_scale),
            angle=self.map.decode(words("angle"), self.map.angle_scale),
            rate_setpoint=self.map.decode(words("rate_setpoint"), self.map.rate_scale),
            running=regs[self.map.registers["command"] - first] == self.map.run,
            **{n: bits[n] for n in STATUS_BITS}, **axis)

    def _read(self, first: int, count: int):
        """One read of `count` registers; a reply with fewer is refused (TableReplyError)."""
        return read_registers(self._client, first, count, self.map.device_id, self.where,
                              TableReplyError)

    @property
    def where(self) -> str:
        """The table in words, for messages: "rotary table at host:port"."""
        return f"rotary table at {self.host}:{self.port}"

    def _write_command(self, value: int):
        return self._client.write_register(self.map.registers["command"], value,
                                           device_id=self.map.device_id)

    def _write_mode(self, value: int):
        return self._client.write_register(self.map.registers["position_mode"], value,
                                           device_id=self.map.device_id)

    def _operate(self, what: str, call, repeat: bool = True):
        """`_request`, and on failure try to stop the table before raising."""
        try:
            return self._request(what, call, repeat)
        except TableError as error:
            log.warning("%s", error)
            self._emergency_stop(error)
            raise

    def _emergency_stop(self, error: TableError) -> None:
        """Keep commanding stop for up to `stop_patience` seconds (a stalled controller may still
        be working through the requests that timed out); say on `error` whether it succeeded
        (`table_stopped`; a note the command line prints when it did not)."""
        deadline = time.monotonic() + self.stop_patience
        while True:
            try:
                self.stop()
                error.table_stopped = True
                return
            except TableError as stop_error:
                if time.monotonic() >= deadline:
                    not_stopped(error, stop_error)
                    return
            time.sleep(STOP_RETRY_PAUSE)

    def _request(self, what: str, call, repeat: bool = True):
        """One transaction (`drivers.modbus_request.request`): busy answers are retried `retries`
        times; timeouts, lost connections and bad replies too if `repeat` (the request is safe
        to send again), reconnecting first; under the driver's lock."""
        with self._lock:
            return request(call, what, self.where, FAILURES, client=self._client,
                           device_id=self.map.device_id, retries=self.retries,
                           timeout=self.timeout, link_words=link_words, repeat=repeat,
                           busy_backoff=self.busy_backoff)
