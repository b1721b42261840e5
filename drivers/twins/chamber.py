"""Virtual thermal chamber: a pymodbus server whose registers follow `ChamberPhysics`.

`ChamberTwin(physics, register_map, link="tcp")` serves Modbus TCP on 127.0.0.1 at an ephemeral
`port`; `link="rtu"` serves Modbus RTU on one end of a null-modem pair of ptys
(`drivers.twins.nullmodem`) and the driver opens `serial_port`, the other end. It stops on
`close()` or by itself after `lifetime` seconds (`drivers.twins.modbus_server`). As the table twin
does, the `SimDevice` action hook refreshes the register image from `physics.state()` on every read
and turns every write into `set_setpoint` / `set_ramp` / `run` / `stop`, answering Modbus
exceptions as a controller would: 2 (illegal address) for a write to a read-only register or to
half of a float, 3 (illegal value) for a setpoint or ramp the controller cannot take or an unknown
command.

`unit_temperature(t)` is the physics' (the unit inside the chamber), for an IMU twin to read on the
shared clock.

Fault knobs:
  physics.alarm, physics.door_open -> the status bits (alarm also stops conditioning)
  silent (attribute)               -> while True no request is answered (cable pulled)
  inject("short", count)           -> the next `count` reads are answered with one register fewer
                                      than asked (a well-formed frame: right length, right CRC)
  inject("exception", count, code) -> the next `count` requests get Modbus exception `code`
  inject("garbled", count)         -> TCP only: the next `count` read replies claim more data than
                                      they hold (byte count 255), a frame pymodbus cannot decode
                                      (over RTU such a frame fails its CRC and is dropped: `silent`)

With a register map that has a watchdog (`[chamber.watchdog]`), the controller serves it
(`watchdog`, a `drivers.twins.watchdog.TwinWatchdog` on the physics' clock): once the host has
written the heartbeat register, the chamber goes to the watchdog's safe setpoint and runs there
(action "safe") or stops (action "off") by itself when that register stays unchanged for the
watchdog's period (a killed, hung or cut-off station; a `silent` link hears no heartbeat
either); the status register's `tripped_bit` says so until the next run command.
"""

import asyncio
import collections
import math
from typing import Self

from pymodbus import FramerType
from pymodbus.constants import ExcCodes
from pymodbus.pdu.register_message import ReadHoldingRegistersResponse
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import SimDevice

from drivers.thermal_chamber import ZERO_CELSIUS, ChamberRegisterMap
from drivers.twins.modbus_server import ServerThread
from drivers.twins.nullmodem import NullModem
from drivers.twins.watchdog import TwinWatchdog, register_blocks

KINDS = ("short", "exception", "garbled")
WRITE_SINGLE = 6  # Modbus function code "write single register"
READ_HOLDING = 3  # Modbus function code "read holding registers"
MBAP = 7  # bytes of the Modbus TCP header: transaction, protocol, length, unit id


class ChamberTwin:
    """Serve `physics` (a `drivers.twins.thermal.ChamberPhysics`) with the layout of
    `register_map`, over "tcp" or "rtu" (see the module docstring)."""

    def __init__(self, physics, register_map: ChamberRegisterMap, link: str = "tcp",
                 lifetime: float = 60.0):
        if link not in ("tcp", "rtu"):
            raise ValueError(f"link must be 'tcp' or 'rtu', got {link!r}")
        self.physics, self.map, self.link = physics, register_map, link
        self.port = self.serial_port = None
        self.silent = False
        self.requests = 0
        self._faults = collections.deque()
        self._modem = None
        self.error = self.on_error = None  # drivers.twins.failure
        self._thread = ServerThread("ChamberTwin", lifetime, self)
        self.watchdog = None if register_map.watchdog is None else TwinWatchdog(
            register_map.watchdog, physics.clock, self._watchdog_act, "thermal chamber twin")

    def start(self) -> "ChamberTwin":
        """Start serving (and watching the heartbeat); returns once the server listens."""
        if self.link == "rtu":
            self._modem = NullModem(("ttyChamberDriver", "ttyChamberTwin"))
            self.serial_port = self._modem.a
        try:
            self._thread.start(self._open)
        except BaseException:
            self.close()
            raise
        if self.link == "tcp":
            self.port = self.bound[1]
        if self.watchdog is not None:
            self.watchdog.start()
        return self

    def close(self) -> None:
        """Stop the server and remove the serial ports (idempotent)."""
        self._thread.close()
        if self.watchdog is not None:
            self.watchdog.close()
        if self._modem is not None:
            self._modem.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def bound(self) -> tuple:
        """The (host, port) the TCP server listens on (None over RTU)."""
        if self.link != "tcp":
            return None
        return self._thread.server.transport.sockets[0].getsockname()[:2]

    def _watchdog_act(self) -> None:
        """The watchdog's action: the safe setpoint, held ("safe"), or conditioning stopped."""
        if self.map.watchdog.action == "safe":
            self.physics.set_setpoint(self.map.watchdog.safe_setpoint)
            self.physics.run()
        else:
            self.physics.stop()

    def unit_temperature(self, t: float | None = None) -> float:
        """The unit's temperature at clock time `t` (default now), K."""
        return self.physics.unit_temperature(t)

    def inject(self, kind: str, count: int = 1, code: int | None = None) -> None:
        """Make the next `count` requests fail in the way `kind` says (see the module doc)."""
        if kind not in KINDS:
            raise ValueError(f"unknown fault {kind!r}; choose one of {KINDS}")
        if kind == "exception" and code not in set(ExcCodes):
            raise ValueError(f"fault 'exception' needs a Modbus exception code, got {code!r}")
        if kind == "garbled" and self.link != "tcp":
            raise ValueError("fault 'garbled' is for Modbus TCP: over RTU a garbled frame fails "
                             "its CRC and is dropped; use `silent`")
        self._faults.extend([(kind, code)] * count)

    async def _open(self):
        """Create and start the pymodbus server for the link."""
        action = self._thread.guarded(self._action)  # an error there fails the twin
        device = SimDevice(id=self.map.device_id, action=action, simdata=register_blocks(
            self.map.span, self.map.watchdog))
        if self.link == "tcp":
            server = ModbusTcpServer(device, address=("127.0.0.1", 0), trace_pdu=self._trace,
                                     trace_packet=self._garble)
        else:
            m = self.map
            server = ModbusSerialServer(device, framer=FramerType.RTU, port=self._modem.b,
                                        baudrate=m.baudrate, parity=m.parity,
                                        stopbits=m.stopbits, trace_pdu=self._trace)
        await server.serve_forever(background=True)
        return server

    async def _action(self, func_code, start, address, count, registers, values):
        """pymodbus hook called before each access: silence, faults, then physics."""
        if self.silent:
            raise asyncio.CancelledError  # the link is down: no reply
        if func_code == WRITE_SINGLE and not values:  # pymodbus reads back after a single write
            self._refresh(start, registers, address, count)
            return None
        self.requests += 1
        if self._faults and self._faults[0][0] == "exception":
            return ExcCodes(self._faults.popleft()[1])
        if values:
            return self._write(address, values)
        self._refresh(start, registers, address, count)
        return None

    def _trace(self, sending: bool, pdu):
        """pymodbus' PDU hook: a read reply loses its last register when a "short" fault is due
        (the framer then builds a well-formed frame around it)."""
        if (sending and self._faults and self._faults[0][0] == "short"
                and isinstance(pdu, ReadHoldingRegistersResponse) and pdu.registers):
            self._faults.popleft()
            pdu.registers = pdu.registers[:-1]
        return pdu

    def _garble(self, sending: bool, packet: bytes) -> bytes:
        """pymodbus' packet hook (TCP): a read reply's byte count set to 255 when a "garbled"
        fault is due."""
        if (sending and self._faults and self._faults[0][0] == "garbled"
                and len(packet) > MBAP + 1 and packet[MBAP] == READ_HOLDING):
            self._faults.popleft()
            return packet[:MBAP + 1] + b"\xff" + packet[MBAP + 2:]
        return packet

    def _refresh(self, start: int, registers: list, address: int, count: int) -> None:
        """Write the chamber's present state into the register image (in place) for an access
        to `count` registers at `address`; the heartbeat register alone from the watchdog
        (`TwinWatchdog.fill`)."""
        if self.watchdog is not None and self.watchdog.fill(address, count, start, registers):
            return
        s, m = self.physics.state(), self.map
        bits = {"running": s.running, "alarm": s.alarm, "door_open": s.door_open,
                "at_setpoint": s.at_setpoint}
        image = {m.registers["status"]: sum(1 << m.status_bits[n] for n, on in bits.items() if on),
                 m.registers["command"]: m.run if s.running else m.stop}
        if self.watchdog is not None:
            image[m.registers["status"]] |= self.watchdog.tripped << m.watchdog.tripped_bit
            image[m.watchdog.register] = self.watchdog.value or 0
        for name, value in (("setpoint", s.setpoint - ZERO_CELSIUS),
                            ("temperature", s.air - ZERO_CELSIUS), ("ramp", s.ramp)):
            image.update(zip(m.addresses(name), m.encode(name, value), strict=True))
        for address, value in image.items():
            if 0 <= address - start < len(registers):
                registers[address - start] = value

    def _write(self, address: int, values: list) -> ExcCodes | None:
        """Apply a write of `values` at `address` to the physics, as the controller would."""
        m, p = self.map, self.physics
        written = dict(zip(range(address, address + len(values)), values, strict=True))
        settable = {a for n in ("setpoint", "ramp") for a in m.addresses(n)}
        beat = {m.watchdog.register} if self.watchdog is not None else set()
        if not set(written) <= settable | beat | {m.registers["command"]}:
            return ExcCodes.ILLEGAL_ADDRESS  # read-only or unmapped register
        for address in beat & set(written):
            self.watchdog.fed(written[address])
        new = {}
        for name in ("ramp", "setpoint"):
            addresses = list(m.addresses(name))
            if any(a in written for a in addresses):
                if not all(a in written for a in addresses):
                    return ExcCodes.ILLEGAL_ADDRESS  # half of a float
                new[name] = m.decode(name, [written[a] for a in addresses])
        low, high = m.setpoint_range
        if "setpoint" in new and not (math.isfinite(new["setpoint"])
                                      and low <= new["setpoint"] + ZERO_CELSIUS <= high):
            return ExcCodes.ILLEGAL_VALUE
        if "ramp" in new and not (math.isfinite(new["ramp"]) and 0 <= new["ramp"] <= m.ramp_max):
            return ExcCodes.ILLEGAL_VALUE
        command = written.get(m.registers["command"])
        if command not in (None, m.run, m.stop):
            return ExcCodes.ILLEGAL_VALUE
        if "ramp" in new:
            p.set_ramp(new["ramp"])
        if "setpoint" in new:
            p.set_setpoint(new["setpoint"] + ZERO_CELSIUS)
        if command == m.run:
            if self.watchdog is not None:
                self.watchdog.rearm()
            p.run()
        elif command == m.stop:
            p.stop()
        return None
