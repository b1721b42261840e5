"""Thermal chamber driver over Modbus TCP or Modbus RTU (pymodbus synchronous clients).

The chamber's controller is a set of holding registers described by the device profile's
`[chamber]` section (`ChamberRegisterMap`): a status bit field (running, alarm, door open, at
setpoint), a run/stop command, the setpoint, the measured air temperature and the ramp rate. The
three values are either signed 16-bit integers scaled by a fixed number of counts per degC (per
K/min for the ramp: 10 counts = 0.1 degC resolution, as most controllers' "one implied decimal")
or IEEE 754 32-bit floats in two registers in the profile's word order. The wire speaks degC; the
API speaks kelvin (SI inside), the ramp in K/min (0: as fast as the chamber can).

`ThermalChamber(register_map, host=..., port=...)` or `ThermalChamber(register_map,
serial_port=...)` (RTU with the profile's `[chamber.serial]` line settings) offers `set_setpoint`,
`run`, `stop`, `state()`, `check()` (state, raising on an alarm or an open door) and `safe()`.
Every failure of a transaction becomes a `ChamberError` whose message names the chamber ("thermal
chamber at host:port" or "on /dev/ttyUSB0"), what happened and what to do: `ChamberTimeout`,
`ChamberLinkError`, `ChamberReplyError` (short or garbled reply, a value that is no number),
`ChamberAlarm`, `ChamberDoorOpen`, `ChamberRangeError` (a setpoint or ramp outside the profile's
limits: refused before anything is sent), `ChamberError` for a Modbus exception. Every request
is an absolute register write or a read, so every one is retried after a timeout, a lost link or
a bad reply (`drivers.modbus_request`): writing the same setpoint or command twice does nothing
more than writing it once.

A chamber may have a communication watchdog (optional `[chamber.watchdog]`, `drivers.heartbeat`):
its controller goes to the watchdog's safe setpoint (action "safe") or stops (action "off") by
itself when the host's heartbeat counter has not changed for the watchdog's period, and sets the
status bit `tripped_bit` (`ChamberReading.watchdog_tripped`). `heartbeat(on_error)` writes that
counter from a thread while a campaign holds the chamber; every transaction holds the driver's
lock (the heartbeat's thread, the campaign's chamber watch and the main thread share the client).
"""

import contextlib
import math
import threading
from dataclasses import dataclass, field
from typing import Self

from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from drivers.clock import WallClock, reply_timeout
from drivers.errors import (
    ChamberAlarm,
    ChamberDoorOpen,
    ChamberError,
    ChamberLinkError,
    ChamberRangeError,
    ChamberReplyError,
    ChamberTimeout,
)
from drivers.heartbeat import Heartbeat, Watchdog
from drivers.modbus_request import Failures, link_words, read_registers, request
from drivers.profile import ProfileError, Section, load_profile

ZERO_CELSIUS = 273.15  # K
STATUS_BITS = ("running", "alarm", "door_open", "at_setpoint")
WORD_REGISTERS = ("status", "command")  # one 16-bit register each
VALUE_REGISTERS = ("setpoint", "temperature", "ramp")  # int16 scaled or float32
VALUE_TYPES = {"int16": (ModbusTcpClient.DATATYPE.INT16, 1),
               "float32": (ModbusTcpClient.DATATYPE.FLOAT32, 2)}  # pymodbus type, registers
FLOAT32_MAX = 3.4028234663852886e38
FAILURES = Failures(base=ChamberError, timeout=ChamberTimeout, link=ChamberLinkError,
                    reply=ChamberReplyError)


@dataclass(frozen=True)
class ChamberRegisterMap:
    """Holding-register layout of a thermal chamber controller (addresses 0-based, as on the wire).

    registers    : name -> address for `status`, `command` (16 bit) and `setpoint`, `temperature`
                   (measured air), `ramp` (values of `value_type`)
    status_bits  : `running`, `alarm`, `door_open`, `at_setpoint` -> bit number in `status`
    value_type   : "int16" (signed, `scale` counts per degC / per K/min) or "float32" (IEEE 754)
    word_order   : of a float32: "big" (high word at the lower address) or "little"
    scale        : (temperature, ramp) counts per degC and per K/min (int16; 1 for float32)
    setpoint_range : (min, max) setpoint the chamber may be given, K
    ramp_max     : largest ramp rate it may be given, K/min
    run, stop    : values written to the command register
    baudrate, parity, stopbits : Modbus RTU line settings (8 data bits)
    watchdog     : the controller's communication watchdog (`drivers.heartbeat.Watchdog`), or None
    """

    registers: dict
    status_bits: dict
    value_type: str
    setpoint_range: tuple
    ramp_max: float
    scale: tuple = (1.0, 1.0)
    word_order: str = "big"
    device_id: int = 1
    run: int = 1
    stop: int = 0
    baudrate: int = 19200
    parity: str = "N"
    stopbits: int = 1
    watchdog: Watchdog | None = None
    span: tuple = field(init=False)  # (first address, count) of one read covering every register
    # but the watchdog's heartbeat (written only)

    def __post_init__(self):
        missing = [n for n in WORD_REGISTERS + VALUE_REGISTERS if n not in self.registers]
        missing += [f"status_bits.{n}" for n in STATUS_BITS if n not in self.status_bits]
        if missing:
            raise ProfileError(f"chamber register map lacks {missing}; see docs/devices.md")
        if self.value_type not in VALUE_TYPES:
            raise ProfileError(f"chamber value_type must be one of {list(VALUE_TYPES)}, got "
                               f"{self.value_type!r}")
        owner = {}
        for name in WORD_REGISTERS + VALUE_REGISTERS:
            for address in self.addresses(name):
                if address in owner:
                    raise ProfileError(f"chamber registers {owner[address]} and {name} overlap at "
                                       f"address {address}; give each its own "
                                       f"{self.width(name)} register(s)")
                owner[address] = name
        used = sorted(owner)
        if used[0] < 0 or used[-1] > 0xFFFF or used[-1] - used[0] + 1 > 125:
            raise ProfileError("chamber registers must lie in 0..65535 and fit in one read of 125 "
                               f"registers, got {self.registers}")
        if self.word_order not in ("big", "little"):
            raise ProfileError(f"word_order must be 'big' or 'little', got {self.word_order!r}")
        if not all(math.isfinite(s) and s > 0 for s in self.scale):
            raise ProfileError(f"chamber scale (counts per degC, per K/min) must be positive, got "
                               f"{self.scale}")
        bits = list(self.status_bits.values())
        if not all(0 <= b < 16 for b in bits) or len(set(bits)) != len(bits):
            raise ProfileError(f"status bits must be distinct numbers 0..15, got "
                               f"{self.status_bits}")
        low, high = self.setpoint_range
        if not (math.isfinite(low) and math.isfinite(high) and 0 < low < high):
            raise ProfileError(f"chamber setpoint limits must be 0 < min < max kelvin, got "
                               f"{self.setpoint_range}")
        if not (math.isfinite(self.ramp_max) and self.ramp_max > 0):
            raise ProfileError(f"chamber ramp_max must be a positive K/min, got {self.ramp_max}")
        try:  # every value the limits allow must fit its register
            for name, value in (("setpoint", low - ZERO_CELSIUS), ("setpoint", high - ZERO_CELSIUS),
                                ("ramp", self.ramp_max)):
                self.encode(name, value)
        except ValueError as exc:
            raise ProfileError(f"chamber limits do not fit the registers: {exc}; lower the limits "
                               "or the scale") from None
        if self.watchdog is not None:
            self._check_watchdog(owner)
        object.__setattr__(self, "span", (used[0], used[-1] - used[0] + 1))

    def _check_watchdog(self, owner: dict) -> None:
        """Refuse a watchdog whose register or tripped bit another quantity has, or whose safe
        setpoint is outside the setpoint limits."""
        w = self.watchdog
        if w.register in owner:
            raise ProfileError(f"watchdog register {w.register} is also the "
                               f"{owner[w.register]} register; give the heartbeat its own "
                               "address")
        if w.tripped_bit in self.status_bits.values():
            name = next(n for n, b in self.status_bits.items() if b == w.tripped_bit)
            raise ProfileError(f"watchdog tripped_bit {w.tripped_bit} is also status "
                               f"bit {name}; give it its own bit")
        low, high = self.setpoint_range
        if w.safe_setpoint is not None and not low <= w.safe_setpoint <= high:
            raise ProfileError(f"watchdog safe_setpoint {w.safe_setpoint!r} K is "
                               f"outside the setpoint limits {low:.2f}..{high:.2f} K")

    @classmethod
    def parse(cls, s: Section) -> "ChamberRegisterMap":
        """Build from the `[chamber]` section of a device profile (see drivers.profile)."""
        s.get("name", str, default="thermal chamber")
        value_type = s.get("value_type", str, choices=tuple(VALUE_TYPES))
        registers, bits, limits = s.sub("registers"), s.sub("status_bits"), s.sub("limits")
        sections = [s, registers, bits, limits]
        scale = (1.0, 1.0)
        if value_type == "int16" or s.has("scale"):
            sub = s.sub("scale")
            scale = (sub.get("temperature", float), sub.get("ramp", float))
            sections.append(sub)
        commands, serial = ({}, {})
        if s.has("command_values"):
            sub = s.sub("command_values")
            commands = {"run": sub.get("run", int), "stop": sub.get("stop", int)}
            sections.append(sub)
        if s.has("serial"):
            sub = s.sub("serial")
            serial = {"baudrate": sub.get("baudrate", int, default=19200),
                      "parity": sub.get("parity", str, default="N", choices=("N", "E", "O")),
                      "stopbits": sub.get("stopbits", int, default=1, choices=(1, 2))}
            if serial["baudrate"] <= 0:
                raise sub.error("baudrate", "must be positive")
            sections.append(sub)
        watchdog = Watchdog.parse(s.sub("watchdog"), "chamber") if s.has("watchdog") else None
        fields = dict(
            registers={n: registers.get(n, int) for n in WORD_REGISTERS + VALUE_REGISTERS},
            status_bits={n: bits.get(n, int) for n in STATUS_BITS},
            value_type=value_type,
            setpoint_range=(limits.get("setpoint_min", float), limits.get("setpoint_max", float)),
            ramp_max=limits.get("ramp_max", float), scale=scale,
            word_order=s.get("word_order", str, default="big", choices=("big", "little")),
            device_id=s.get("device_id", int, default=1), watchdog=watchdog, **commands,
            **serial)
        try:
            chamber = cls(**fields)
        except ProfileError as exc:
            raise ProfileError(f"{s.source}: [chamber] {exc}") from None
        for section in sections:
            section.finish()
        return chamber

    @classmethod
    def load(cls, path_or_name) -> "ChamberRegisterMap":
        """Read the `[chamber]` section of a device profile (path or bundled name)."""
        return load_profile(path_or_name).section("chamber", cls.parse)

    def width(self, name: str) -> int:
        """Registers a named quantity occupies."""
        return VALUE_TYPES[self.value_type][1] if name in VALUE_REGISTERS else 1

    def addresses(self, name: str) -> range:
        """Register addresses a named quantity occupies."""
        return range(self.registers[name], self.registers[name] + self.width(name))

    def _scale(self, name: str) -> float:
        return self.scale[1] if name == "ramp" else self.scale[0]

    def encode(self, name: str, value: float) -> list:
        """A wire value (degC, or K/min for the ramp) -> the registers of `name`."""
        kind = VALUE_TYPES[self.value_type][0]
        if self.value_type == "int16":
            counts = round(value * self._scale(name))
            if not -(2**15) <= counts < 2**15:
                raise ValueError(f"{value!r} does not fit the chamber's 16-bit {name} register "
                                 f"at {self._scale(name)} counts per unit")
            return ModbusTcpClient.convert_to_registers(counts, kind)
        if not abs(value) <= FLOAT32_MAX:
            raise ValueError(f"{value!r} does not fit the chamber's 32-bit float {name} register")
        return ModbusTcpClient.convert_to_registers(float(value), kind,
                                                    word_order=self.word_order)

    def decode(self, name: str, words) -> float:
        """The registers of `name` -> its wire value (degC, or K/min for the ramp)."""
        kind = VALUE_TYPES[self.value_type][0]
        value = ModbusTcpClient.convert_from_registers(list(words), kind,
                                                       word_order=self.word_order)
        return value / self._scale(name) if self.value_type == "int16" else float(value)


@dataclass(frozen=True)
class ChamberReading:
    """What the chamber reports, read at host `time` (clock seconds): air temperature and setpoint
    in K, ramp in K/min, and the status bits."""

    time: float
    temperature: float
    setpoint: float
    ramp: float
    running: bool
    alarm: bool
    door_open: bool
    at_setpoint: bool
    watchdog_tripped: bool | None = None  # the watchdog acted (None: the chamber has none)


def serial_link_words(exc: OSError) -> str:
    """What a serial port that cannot be opened or was lost means, in words an operator can act
    on (pyserial raises SerialException, an OSError, with its own text)."""
    text = str(exc).lower()
    if "could not open" in text or "no such file" in text:
        return ("cannot open the serial port (is the adapter plugged in, the path right, the port "
                "free?)")
    return f"serial link lost ({exc}); check the adapter and the cable"


class ThermalChamber:
    """Synchronous thermal chamber client; one Modbus transaction per call, bounded retries.

    host, port   : Modbus TCP address; or serial_port: Modbus RTU on that port (profile's line
                   settings)
    timeout      : wall seconds to wait for each reply (default `drivers.clock.reply_timeout`)
    retries      : extra tries after a timeout, a lost link, a bad reply or a busy answer
    safe_kelvin  : if given, leaving the `with` block on an exception calls `safe(safe_kelvin)`
                   and says on the exception whether it worked (`chamber_safe`)
    clock        : stamps `ChamberReading.time` (share the recorder's clock)
    """

    def __init__(self, register_map: ChamberRegisterMap, host: str | None = None, port: int = 502,
                 serial_port: str | None = None, timeout: float | None = None, retries: int = 2,
                 safe_kelvin: float | None = None, clock=None):
        if (host is None) == (serial_port is None):
            raise ValueError("give the chamber's host (Modbus TCP) or its serial_port (Modbus "
                             "RTU), not both")
        self.clock = clock or WallClock()
        timeout = reply_timeout(self.clock) if timeout is None else timeout
        self.map, self.timeout, self.retries = register_map, timeout, int(retries)
        self.safe_kelvin = safe_kelvin
        if safe_kelvin is not None:
            self._check_setpoint(safe_kelvin)
        if host is not None:
            self.where = f"thermal chamber at {host}:{port}"
            self._words = link_words
            self._client = ModbusTcpClient(host, port=port, timeout=timeout, retries=0)
        else:
            self.where = f"thermal chamber on {serial_port}"
            self._words = serial_link_words
            m = register_map
            self._client = ModbusSerialClient(serial_port, framer=FramerType.RTU,
                                              baudrate=m.baudrate, bytesize=8, parity=m.parity,
                                              stopbits=m.stopbits, timeout=timeout, retries=0)
        self._lock = threading.Lock()  # one transaction at a time (heartbeat, watch, caller)

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc is not None and self.safe_kelvin is not None:
                try:
                    self.safe(self.safe_kelvin)
                    exc.chamber_safe = True
                except ChamberError as safe_error:
                    exc.chamber_safe = False
                    exc.add_note(f"the chamber could not be brought to its safe setpoint "
                                 f"{self.safe_kelvin:.2f} K ({safe_error}); "
                                 f"{self._unattended()}")
        finally:
            self.close()

    def _unattended(self) -> str:
        """What becomes of a chamber the station can no longer reach, and what to do."""
        w = self.map.watchdog
        if w is None:
            return "set it by hand"
        does = (f"goes to {w.safe_setpoint:.2f} K" if w.action == "safe"
                else "stops conditioning")
        return (f"its watchdog {does} by itself {w.period:g} s after the last heartbeat: check "
                f"on its panel that it did, or set it by hand")

    def connect(self) -> None:
        """Open the link, or raise ChamberLinkError naming the address."""
        if not self._client.connect():
            raise ChamberLinkError(f"{self.where}: cannot connect; check its power, cable and "
                                   "address (IP and port, or serial port)")

    def close(self) -> None:
        self._client.close()

    def heartbeat(self, on_error):
        """A context manager writing the watchdog's heartbeat while entered
        (`drivers.heartbeat.Heartbeat`; its failures told to `on_error`); nothing for a chamber
        without a watchdog."""
        w = self.map.watchdog
        if w is None:
            return contextlib.nullcontext()
        return Heartbeat(
            lambda: self._request("read the watchdog heartbeat", lambda: read_registers(
                self._client, w.register, 1, self.map.device_id, self.where, ChamberReplyError)
            ).registers[0],
            lambda count: self._request("write the watchdog heartbeat", lambda: (
                self._client.write_register(w.register, count, device_id=self.map.device_id))),
            w, self.clock, on_error, "thermal chamber")

    def set_setpoint(self, kelvin: float, ramp: float | None = None) -> None:
        """Write the ramp rate (K/min, 0 = as fast as possible; None leaves it) and then the
        setpoint (K), so that the new setpoint is approached at the new rate. Values outside the
        profile's limits raise ChamberRangeError before anything is sent."""
        self._check_setpoint(kelvin)
        if ramp is not None:
            if not (math.isfinite(ramp) and 0 <= ramp <= self.map.ramp_max):
                raise ChamberRangeError(f"{self.where}: ramp {ramp!r} K/min is outside the "
                                        f"profile's 0..{self.map.ramp_max} K/min; nothing was "
                                        "sent")
            self._write_value("ramp", ramp)
        self._write_value("setpoint", kelvin - ZERO_CELSIUS)

    def run(self) -> None:
        """Start conditioning towards the setpoint; refused (ChamberAlarm, ChamberDoorOpen) while
        the chamber reports an alarm or an open door."""
        self.check()
        self._write_command(self.map.run, "run")

    def stop(self) -> None:
        """Stop conditioning (the air then drifts towards the room)."""
        self._write_command(self.map.stop, "stop")

    def safe(self, kelvin: float, hold: bool = True) -> None:
        """Leave the chamber safe: setpoint `kelvin` (e.g. room temperature), reached at the ramp
        rate already set, and with `hold` (default) the chamber kept running so it brings the
        unit there and holds it; without, stopped (the air drifts to the room). Alarm and door
        bits are not checked: this is what to do when something went wrong."""
        self.set_setpoint(kelvin)
        if hold:
            self._write_command(self.map.run, "run")
        else:
            self.stop()

    def state(self) -> ChamberReading:
        """Read every register in one transaction."""
        first, count = self.map.span
        now = self.clock.now()
        regs = self._request("read state", lambda: read_registers(
            self._client, first, count, self.map.device_id, self.where, ChamberReplyError)
        ).registers

        def value(name):
            v = self.map.decode(name, [regs[a - first] for a in self.map.addresses(name)])
            if not math.isfinite(v):
                raise ChamberReplyError(f"{self.where}: its {name} register holds {v!r}, no "
                                        "number; check value_type and word_order in the profile")
            return v

        status = regs[self.map.registers["status"] - first]
        bits = {n: bool(status >> b & 1) for n, b in self.map.status_bits.items()}
        if self.map.watchdog is not None:
            bits["watchdog_tripped"] = bool(status >> self.map.watchdog.tripped_bit & 1)
        return ChamberReading(time=now, temperature=value("temperature") + ZERO_CELSIUS,
                              setpoint=value("setpoint") + ZERO_CELSIUS, ramp=value("ramp"),
                              **bits)

    def check(self) -> ChamberReading:
        """`state()`, raising ChamberAlarm or ChamberDoorOpen when the chamber reports either."""
        reading = self.state()
        air = f"air at {reading.temperature - ZERO_CELSIUS:.1f} degC"
        if reading.alarm:
            raise ChamberAlarm(f"{self.where}: reports an alarm ({air}); read the alarm on its "
                               "display, clear its cause and acknowledge it, then resume")
        if reading.door_open:
            raise ChamberDoorOpen(f"{self.where}: reports its door open ({air}); close the door, "
                                  "then resume")
        return reading

    def _check_setpoint(self, kelvin: float) -> None:
        low, high = self.map.setpoint_range
        if not (math.isfinite(kelvin) and low <= kelvin <= high):
            raise ChamberRangeError(f"chamber setpoint {kelvin!r} K is outside the profile's "
                                    f"{low:.2f}..{high:.2f} K; nothing was sent")

    def _write_value(self, name: str, wire_value: float) -> None:
        words = self.map.encode(name, wire_value)
        self._request(f"set {name}", lambda: self._client.write_registers(
            self.map.registers[name], words, device_id=self.map.device_id))

    def _write_command(self, value: int, what: str) -> None:
        self._request(what, lambda: self._client.write_register(
            self.map.registers["command"], value, device_id=self.map.device_id))

    def _request(self, what: str, call):
        """One transaction (`drivers.modbus_request.request`) under the driver's lock."""
        with self._lock:
            return request(call, what, self.where, FAILURES, client=self._client,
                           device_id=self.map.device_id, retries=self.retries,
                           timeout=self.timeout, link_words=self._words)
