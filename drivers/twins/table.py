"""Virtual rotary table: a pymodbus TCP server on 127.0.0.1 whose registers follow the physics of
`station.sim.table.TablePhysics`.

The server runs in a background thread with its own asyncio loop, listens on an ephemeral port
(`TableTwin.port`) and stops on `close()` or by itself after `lifetime` seconds. Registers are not
pushed into a datastore (pymodbus 3.16 ignores updates of a running server's context): the
`SimDevice` action hook refreshes them from `table.state()` on every read and turns every write into
`set_rate` / `start` / `stop` calls, answering Modbus exceptions like a real controller would.

Fault knobs (`inject`), each applied to the next `count` requests:
  "busy"      -> exception 6 (device busy)
  "exception" -> the given exception `code` (e.g. 4 device failure, 2 illegal address)
  "slow"      -> the reply comes `delay` seconds late (the whole controller stalls, like a real one)
  "drop"      -> no reply at all
  "reset"     -> no reply: every connection is reset (TCP RST), as when the controller's network
                 stack restarts; the driver must reconnect
  "short"     -> a read is answered with one register fewer than asked (a well-formed frame);
                 a write's reply loses its last two bytes

`die()` is the controller process dying: every connection is reset and the port closed, so that
later connections are refused; the table's physics goes on (a table left turning keeps turning).

Every write the controller accepts is kept in `writes` as (time.monotonic(), address, values) and,
when `write_log` names a file, appended to it as one line `<monotonic s> <address> <values...>`
(CLOCK_MONOTONIC is shared by every process of the machine, so another process can measure when
its command arrived).

With `position` (a `station.sim.table.PositionAxis`) and a register map with a position axis, the
twin is a two-axis table: it serves the axis' angle, setpoint and `in_position` bit and turns
writes of the position setpoint into `position.set_position`; with a map that has the position
axis' rate mode it also serves `position_mode`, the axis' rate and rate setpoint and the
`position_at_rate`/`position_moving` bits, and turns writes of the rate setpoint into
`position.set_rate` and of `position_mode` into `position.spin` / `position.hold`. With `fixture` (a
`station.sim.table.MountingFixture`) and a map with a fixture, it serves the `mount` register and
the `mounted` bit and turns writes of `mount` into `fixture.request`.

`silent` (an attribute): while True no request is answered, however many come (a link that is
down: the cable pulled, the controller's network port dead); the physics go on.

With a register map that has a watchdog (`[table.watchdog]`), the controller serves it
(`watchdog`, a `drivers.twins.watchdog.TwinWatchdog` on the table's clock): once the host has
written the heartbeat register, the table stops by itself (every axis, as a stop command) when
that register stays unchanged for the watchdog's period (a killed, hung or cut-off station); the
status register's `tripped_bit` says so until the next run command. Heartbeat writes are not
commands: they are not kept in `writes` nor in the write log.
"""

import asyncio
import collections
import socket
import struct
import time
from pathlib import Path
from typing import Self

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import SimDevice

from drivers.rotary_table import (
    FIXTURE_BIT,
    FIXTURE_REGISTER,
    POSITION_BIT,
    RATE_MODE_BITS,
    TableRegisterMap,
)
from drivers.twins.modbus_server import ServerThread
from drivers.twins.watchdog import TwinWatchdog, register_blocks

KINDS = ("busy", "exception", "slow", "drop", "reset", "short")
WRITE_SINGLE = 6  # Modbus function code "write single register"
READ_HOLDING = 3  # Modbus function code "read holding registers"
MBAP = 7  # bytes of the Modbus TCP header: transaction, protocol, length, unit id


class TableTwin:
    """Serve `table` (a `station.sim.table.TablePhysics`) with the layout of `register_map`."""

    def __init__(self, table, register_map: TableRegisterMap, lifetime: float = 60.0,
                 write_log: str | Path | None = None, position=None, fixture=None):
        if (position is not None) != register_map.two_axis:
            raise ValueError("a two-axis register map needs a position axis, and only it")
        if (fixture is not None) != register_map.fixture:
            raise ValueError("a register map with a fixture needs a fixture, and only it")
        self.table = table
        self.position = position
        self.fixture = fixture
        self.map = register_map
        self.lifetime = lifetime
        self.write_log = write_log
        self.port = None
        self.requests = 0
        self.writes = []
        self._server = None
        self._cut = False  # the next reply is sent short
        self.silent = False
        self._faults = collections.deque()
        self.error = self.on_error = None  # drivers.twins.failure
        self._thread = ServerThread("table twin", lifetime, self)
        self.watchdog = None if register_map.watchdog is None else TwinWatchdog(
            register_map.watchdog, table.clock, self._watchdog_stop, "rotary table twin")

    def start(self) -> "TableTwin":
        """Start serving (and watching the heartbeat); returns once the port is known."""
        self._thread.start(self._open)
        if self.watchdog is not None:
            self.watchdog.start()
        return self

    def close(self) -> None:
        """Stop the server and its thread (idempotent)."""
        self._thread.close()
        if self.watchdog is not None:
            self.watchdog.close()

    def die(self) -> None:
        """The controller process dies: reset every connection, close the port (see the module
        doc); the physics goes on."""
        self._thread.close(first=self._reset_connections)
        if self.watchdog is not None:
            self.watchdog.close()

    def _watchdog_stop(self) -> None:
        """The watchdog's action: stop every axis, as a stop command does."""
        self.table.stop()
        if self.map.rate_mode:
            self.position.hold()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def inject(self, kind: str, count: int = 1, code: int | None = None,
               delay: float | None = None) -> None:
        """Make the next `count` requests fail in the way `kind` says (see the module doc)."""
        if kind not in KINDS:
            raise ValueError(f"unknown fault {kind!r}; choose one of {KINDS}")
        if kind == "exception" and code not in set(ExcCodes):
            raise ValueError(f"fault 'exception' needs a Modbus exception code, got {code!r}")
        if kind == "slow" and not (delay and delay > 0):
            raise ValueError("fault 'slow' needs a positive delay in seconds")
        self._faults.extend([(kind, code, delay)] * count)

    async def _open(self):
        """The server, listening on an ephemeral port of 127.0.0.1 (`port`)."""
        action = self._thread.guarded(self._action)  # an error there fails the twin
        device = SimDevice(id=self.map.device_id, action=action, simdata=register_blocks(
            self.map.span, self.map.watchdog))
        server = ModbusTcpServer(device, address=("127.0.0.1", 0), trace_packet=self._trace)
        self._server = server
        await server.serve_forever(background=True)
        self.port = server.transport.sockets[0].getsockname()[1]
        return server

    async def _action(self, func_code, start, address, count, registers, values):
        """pymodbus hook called before each access: faults, then physics."""
        if self.silent:
            raise asyncio.CancelledError  # the link is down: no reply
        if func_code == WRITE_SINGLE and not values:  # pymodbus reads back after a single write:
            # part of the same request, no second fault
            self._refresh(start, registers, address, count)
            return None
        self.requests += 1
        if self._faults:
            kind, code, delay = self._faults.popleft()
            if kind == "busy":
                return ExcCodes.DEVICE_BUSY
            if kind == "exception":
                return ExcCodes(code)
            if kind == "drop":
                raise asyncio.CancelledError  # the request task ends without a reply
            if kind == "reset":
                self._reset_connections()
                raise asyncio.CancelledError
            if kind == "short":
                self._cut = True
                return self._serve_request(func_code, start, address, count, registers, values)
            time.sleep(delay)  # noqa: ASYNC251 - "slow": the whole controller stalls
        return self._serve_request(func_code, start, address, count, registers, values)

    def _serve_request(self, func_code, start, address, count, registers,
                       values) -> ExcCodes | None:
        """Apply a write to the physics (and nudge the clock: a fixture waiting for a command on
        a lockstep clock looks at once), or refresh the register image for a read."""
        if values:
            try:
                return self._write(address, values)
            finally:
                self.table.clock.nudge()
        self._refresh(start, registers, address, count)
        return None

    def _reset_connections(self) -> None:
        """Reset every client connection (SO_LINGER 0, then close: the peer gets a TCP RST)."""
        for connection in list(self._server.active_connections.values()):
            transport = connection.transport
            if transport is None:
                continue
            sock = transport.get_extra_info("socket")
            if sock is not None:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            transport.abort()

    def _trace(self, sending: bool, packet: bytes) -> bytes:
        """pymodbus' packet hook: cut the reply a "short" fault asked for (the MBAP length field
        follows the cut, so the frame stays well-formed)."""
        if not (sending and self._cut) or len(packet) < MBAP + 3:
            return packet
        self._cut = False
        body = bytearray(packet[:-2])
        if body[MBAP] == READ_HOLDING:
            body[MBAP + 1] -= 2  # the byte count: one register fewer
        struct.pack_into(">H", body, 4, len(body) - 6)  # length: unit id and PDU
        return bytes(body)

    def _log_write(self, address: int, values: list) -> None:
        """Keep an accepted write with its instant (see the module doc)."""
        now = time.monotonic()
        self.writes.append((now, address, list(values)))
        if self.write_log is not None:
            with open(self.write_log, "a", encoding="ascii") as log:
                log.write(f"{now:.6f} {address} {' '.join(map(str, values))}\n")

    def _refresh(self, start: int, registers: list, address: int, count: int) -> None:
        """Write the table's present state into the register image (in place) for an access to
        `count` registers at `address`; the heartbeat register alone from the watchdog
        (`TwinWatchdog.fill`)."""
        if self.watchdog is not None and self.watchdog.fill(address, count, start, registers):
            return
        s, m = self.table.state(), self.map
        bits = {"ready": not s.fault, "moving": s.moving, "at_rate": s.at_rate, "fault": s.fault}
        image = {m.registers["status"]: sum(1 << m.status_bits[n] for n, on in bits.items() if on),
                 m.registers["command"]: m.run if s.running else m.stop}
        angle_counts = (round(s.angle * m.angle_scale) + 2**31) % 2**32 - 2**31  # int32 wrap
        fixed = {"rate_setpoint": m.encode(s.rate_setpoint, m.rate_scale),
                 "rate": m.encode(s.rate, m.rate_scale),
                 "angle": m.encode(angle_counts / m.angle_scale, m.angle_scale)}
        if self.position is not None:
            p = self.position.state()
            image[m.registers["status"]] |= p.in_position << m.status_bits[POSITION_BIT]
            fixed |= {"position": m.encode(p.angle, m.angle_scale),
                      "position_setpoint": m.encode(p.setpoint, m.angle_scale)}
            if m.rate_mode:
                for name, on in zip(RATE_MODE_BITS, (p.at_rate, p.moving), strict=True):
                    image[m.registers["status"]] |= on << m.status_bits[name]
                image[m.registers["position_mode"]] = (m.position_spin if p.spinning
                                                       else m.position_hold)
                fixed |= {"position_rate": m.encode(p.rate, m.rate_scale),
                          "position_rate_setpoint": m.encode(p.rate_setpoint, m.rate_scale)}
        if self.fixture is not None:
            asked, held = self.fixture.state()
            image[m.registers["status"]] |= held << m.status_bits[FIXTURE_BIT]
            image[m.registers[FIXTURE_REGISTER]] = asked
        if self.watchdog is not None:
            image[m.registers["status"]] |= self.watchdog.tripped << m.watchdog.tripped_bit
            image[m.watchdog.register] = self.watchdog.value or 0
        for name in fixed:
            image.update(zip(m.addresses(name), fixed[name], strict=True))
        for address, value in image.items():
            if 0 <= address - start < len(registers):  # the block asked (span or heartbeat)
                registers[address - start] = value

    def _write(self, address: int, values: list) -> ExcCodes | None:
        """Apply a write of `values` at `address` to the physics, as the controller would."""
        m = self.map
        written = dict(zip(range(address, address + len(values)), values, strict=True))
        setpoint = list(m.addresses("rate_setpoint"))
        target = list(m.addresses("position_setpoint")) if self.position is not None else []
        mount = {m.registers[FIXTURE_REGISTER]} if self.fixture is not None else set()
        spin = list(m.addresses("position_rate_setpoint")) if m.rate_mode else []
        mode = {m.registers["position_mode"]} if m.rate_mode else set()
        beat = {m.watchdog.register} if self.watchdog is not None else set()
        if not set(written) <= (set(setpoint) | set(target) | mount | set(spin) | mode | beat
                                | {m.registers["command"]}):
            return ExcCodes.ILLEGAL_ADDRESS  # read-only or unmapped register
        for address in beat & set(written):
            self.watchdog.fed(written[address])
        if set(written) <= beat:
            return None  # a heartbeat alone: no command
        if any(0 < sum(a in written for a in pair) < 2 for pair in (target, setpoint, spin)):
            return ExcCodes.ILLEGAL_ADDRESS  # half of a 32-bit value
        position_mode = next((written[a] for a in mode & set(written)), None)
        if position_mode not in (None, m.position_spin, m.position_hold):
            return ExcCodes.ILLEGAL_VALUE
        for address in mount & set(written):
            self.fixture.request(written[address])
        try:
            if target and target[0] in written:
                self.position.set_position(m.decode([written[a] for a in target], m.angle_scale))
            if spin and spin[0] in written:
                self.position.set_rate(m.decode([written[a] for a in spin], m.rate_scale))
            if setpoint[0] in written:
                self.table.set_rate(m.decode([written[a] for a in setpoint], m.rate_scale))
        except ValueError:  # out of range, or positioning the axis in rate mode
            return ExcCodes.ILLEGAL_VALUE
        command = written.get(m.registers["command"])
        if command not in (None, m.run, m.stop):
            return ExcCodes.ILLEGAL_VALUE
        self._log_write(address, values)
        if position_mode == m.position_spin:
            self.position.spin()
        elif position_mode == m.position_hold:
            self.position.hold()
        if command == m.run:
            if self.watchdog is not None:
                self.watchdog.rearm()
            if not self.table.start():
                return ExcCodes.DEVICE_FAILURE
        elif command == m.stop:
            self.table.stop()
        return None
