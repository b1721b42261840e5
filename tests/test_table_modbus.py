"""Rotary-table driver against its Modbus twin (a real pymodbus server on 127.0.0.1)."""

import dataclasses
import os
import socket
import threading
import time

import pymodbus
import pytest
from pymodbus.client import ModbusTcpClient
from signal_places import ends, interrupted_at

import drivers
from drivers.clock import ScaledClock
from drivers.rotary_table import (
    RotaryTable,
    TableBusy,
    TableError,
    TableFault,
    TableLinkError,
    TableRegisterMap,
    TableReplyError,
    TableTimeout,
)
from drivers.twins.table import TableTwin
from station.sim.table import TablePhysics

MAP = TableRegisterMap.load("table_modbus")
TIMEOUT, RETRIES = 0.5, 1  # long enough for a busy host; the slow fault waits 2.5x
PATIENT = 5.0  # plain clients of tests that are not about timeouts


pytestmark = pytest.mark.usefixtures("quiet_pymodbus")


@pytest.fixture
def bench():
    """(physics, twin, clock): a table physics at 20x speed served on an ephemeral port."""
    clock = ScaledClock(speed=20.0)
    physics = TablePhysics(clock, max_accel=4.0, settle_time=0.5)
    with TableTwin(physics, MAP, lifetime=30.0) as twin:
        yield physics, twin, clock


def driver(twin, clock, register_map=MAP) -> RotaryTable:
    return RotaryTable("127.0.0.1", twin.port, register_map, timeout=TIMEOUT, retries=RETRIES,
                       clock=clock)


def wait_for(predicate, table: RotaryTable, timeout: float = 5.0):
    """Poll `table.state()` until `predicate(reading)`; returns that reading."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        reading = table.state()
        if predicate(reading):
            return reading
        time.sleep(0.005)
    raise AssertionError(f"table never reached the awaited state; last: {reading}")


def test_set_start_steady_stop_cycle(bench):
    physics, twin, clock = bench
    with driver(twin, clock) as table:
        rest = table.state()
        assert (rest.ready, rest.moving, rest.running, rest.fault) == (True, False, False, False)
        table.set_rate(-2.5)
        table.start()
        steady = wait_for(lambda r: r.at_rate, table)
        assert steady.rate == pytest.approx(-2.5, abs=1e-5)  # fixed point: 1e-5 rad/s per count
        assert (steady.rate_setpoint, steady.running, steady.moving) == (-2.5, True, True)
        before = physics.state().angle
        reading = table.state()
        after = physics.state().angle
        assert after - 1e-4 <= reading.angle <= before + 1e-4  # angle decreases: negative rate
        table.stop()
        rest = wait_for(lambda r: not r.moving, table)
        assert (rest.rate, rest.running, rest.at_rate) == (0.0, False, False)
    assert physics.state().rate == 0.0


def test_context_manager_stops_the_table_on_an_exception(bench):
    physics, twin, clock = bench
    with pytest.raises(KeyError), driver(twin, clock) as table:
        table.set_rate(1.0)
        table.start()
        wait_for(lambda r: r.moving, table)
        raise KeyError("operator pressed Ctrl-C")
    assert not physics.state().running


def spinning(twin, clock) -> RotaryTable:
    table = driver(twin, clock)
    table.connect()
    table.set_rate(3.0)
    table.start()
    wait_for(lambda r: r.moving, table)
    return table


@pytest.mark.parametrize("fault, expected, message, setpoint", [
    ({"kind": "busy", "count": RETRIES + 1}, TableBusy, "busy", 3.0),
    # a slow controller still executes the command, only its reply is too late
    ({"kind": "slow", "count": RETRIES + 1, "delay": 2.5 * TIMEOUT}, TableTimeout, "no reply", 1.0),
    ({"kind": "drop", "count": RETRIES + 1}, TableTimeout, "no reply", 3.0),
    ({"kind": "exception", "code": 4}, TableFault, "device failure", 3.0),
    ({"kind": "exception", "code": 2}, TableError, "exception 2 .illegal address", 3.0),
])
def test_each_fault_gives_its_error_and_the_table_is_stopped(bench, fault, expected, message,
                                                             setpoint):
    physics, twin, clock = bench
    table = spinning(twin, clock)
    try:
        twin.inject(**fault)
        with pytest.raises(TableError, match=message) as caught:
            table.set_rate(1.0)
        assert type(caught.value) is expected
        assert not physics.state().running
        assert physics.state().rate_setpoint == setpoint
    finally:
        table.close()


def test_retries_are_bounded_and_a_short_busy_spell_is_absorbed(bench):
    physics, twin, clock = bench
    table = spinning(twin, clock)
    try:
        twin.inject("busy", count=RETRIES)
        table.set_rate(1.0)  # the last try gets through
        assert physics.state().rate_setpoint == 1.0 and physics.state().running
        twin.inject("busy", count=RETRIES + 1)
        requests = twin.requests
        with pytest.raises(TableBusy):
            table.set_rate(2.0)
        assert twin.requests - requests == RETRIES + 1 + 1  # the tries, then one stop
    finally:
        table.close()


def test_start_refused_during_a_fault(bench):
    physics, twin, clock = bench
    physics.fault(True)
    with driver(twin, clock) as table:
        reading = table.state()
        assert (reading.fault, reading.ready) == (True, False)
        table.set_rate(1.0)
        with pytest.raises(TableFault):
            table.start()
    assert not physics.state().running


def test_little_endian_word_order_round_trips_through_the_twin():
    little = dataclasses.replace(MAP, word_order="little")
    clock = ScaledClock(speed=20.0)
    physics = TablePhysics(clock)
    with TableTwin(physics, little) as twin, driver(twin, clock, little) as table:
        table.set_rate(-1.25)
        assert physics.state().rate_setpoint == -1.25
        assert table.state().rate_setpoint == -1.25
        raw = ModbusTcpClient("127.0.0.1", port=twin.port, timeout=PATIENT)
        try:
            words = raw.read_holding_registers(MAP.registers["rate_setpoint"], count=2).registers
        finally:
            raw.close()
    assert words == [(-125000) & 0xFFFF, ((-125000) >> 16) & 0xFFFF]  # low word first


def test_twin_answers_bad_writes_like_a_controller(bench):
    physics, twin, _ = bench
    raw = ModbusTcpClient("127.0.0.1", port=twin.port, timeout=PATIENT, retries=0)
    try:
        assert raw.write_register(MAP.registers["rate"], 5).exception_code == 2  # read-only
        assert raw.write_register(MAP.registers["rate_setpoint"], 5).exception_code == 2  # half
        assert raw.write_register(MAP.registers["command"], 7).exception_code == 3  # no such cmd
        big = MAP.encode(1000.0, MAP.rate_scale)  # beyond the physics' max rate
        assert raw.write_registers(MAP.registers["rate_setpoint"], big).exception_code == 3
        assert raw.read_holding_registers(200, count=1).exception_code == 2
    finally:
        raw.close()
    assert not physics.state().running and physics.state().rate_setpoint == 0.0


def test_unreachable_table_names_its_address():
    clock = ScaledClock()
    with TableTwin(TablePhysics(clock), MAP) as twin:
        port = twin.port
    table = RotaryTable("127.0.0.1", port, MAP, timeout=TIMEOUT)
    with pytest.raises(TableError, match=f"127.0.0.1:{port}"):
        table.connect()


CALLS = {"state": (), "set_rate": (1.0,), "start": (), "stop": ()}
REPEATED = ("state", "set_rate", "stop")  # safe to send again; a start never is


@pytest.mark.parametrize("kind, expected, words", [
    ("reset", TableLinkError, "connection reset by the controller"),
    ("short", TableReplyError, "short reply|garbled reply"),
])
@pytest.mark.parametrize("call", CALLS)
def test_a_lost_connection_or_short_reply_is_a_table_error_naming_the_table(bench, kind,
                                                                            expected, words, call):
    """Every call, on a reset connection or a cut reply: a TableError naming the table and the
    cause (never a raw ConnectionResetError or IndexError), the table stopped afterwards."""
    physics, twin, clock = bench
    table = spinning(twin, clock)
    try:
        twin.inject(kind, count=RETRIES + 1)
        with pytest.raises(expected, match=words) as caught:
            getattr(table, call)(*CALLS[call])
        assert f"rotary table at 127.0.0.1:{twin.port}" in str(caught.value)
        if call != "stop":  # the driver's emergency stop reached the table
            assert caught.value.table_stopped is True
        table.stop()  # the driver reconnects by itself
        assert wait_for(lambda r: not r.moving, table).rate == 0.0
    finally:
        table.close()


@pytest.mark.parametrize("kind", ["reset", "short"])
@pytest.mark.parametrize("call", REPEATED)
def test_one_lost_connection_or_short_reply_is_absorbed_where_repeating_is_safe(bench, kind, call):
    physics, twin, clock = bench
    table = spinning(twin, clock)
    try:
        twin.inject(kind, count=1)
        result = getattr(table, call)(*CALLS[call])
        if call == "state":  # the retry's reading, complete and current
            assert result.rate_setpoint == 3.0 and result.running
        elif call == "set_rate":
            assert physics.state().rate_setpoint == 1.0 and physics.state().running
        else:
            assert not physics.state().running
    finally:
        table.close()


def test_a_start_is_never_sent_twice(bench):
    """A start whose connection was reset may have been executed: not repeated; table stopped."""
    physics, twin, clock = bench
    with driver(twin, clock) as table:
        table.set_rate(1.0)
        twin.inject("reset", count=1)
        requests = twin.requests
        with pytest.raises(TableLinkError, match="during start"):
            table.start()
        assert twin.requests - requests == 2  # the start, then the stop
        assert not physics.state().running


def test_a_controller_that_dies_mid_rotation_leaves_the_table_turning_and_says_so(bench):
    """The controller process dies: the physics keeps turning; the error names the table, says
    the stop could not be sent and tells the operator to stop it by hand; refused reconnections
    are TableLinkErrors too."""
    physics, twin, clock = bench
    table = spinning(twin, clock)
    table.stop_patience = 0.3
    try:
        twin.die()
        with pytest.raises(TableLinkError, match=f"127.0.0.1:{twin.port}") as caught:
            table.state()
        assert caught.value.table_stopped is False
        assert any("stop the table by hand" in n for n in caught.value.__notes__)
        assert physics.state().running and physics.state().rate == pytest.approx(3.0, abs=1e-3)
        with pytest.raises(TableLinkError, match="cannot connect"):
            table.stop()
    finally:
        table.close()


def test_the_twin_logs_the_instant_of_every_accepted_write(bench, tmp_path):
    physics, twin, clock = bench
    log = tmp_path / "writes.log"
    twin.write_log = log
    before = time.monotonic()
    with driver(twin, clock) as table:
        table.set_rate(1.0)
        table.start()
    after = time.monotonic()
    rows = [line.split() for line in log.read_text().splitlines()]
    assert [int(r[1]) for r in rows] == [MAP.registers[n] for n in ("rate_setpoint", "command",
                                                                   "command")]
    assert [int(r[2]) for r in rows[1:]] == [MAP.run, MAP.stop]
    instants = [float(r[0]) for r in rows]
    assert before <= instants[0] <= instants[1] <= instants[2] <= after
    assert [w[0] for w in twin.writes] == pytest.approx(instants, abs=1e-6)


def test_a_ctrl_c_at_any_place_of_a_poll_leaves_the_table_stoppable(bench):
    """The station's main thread polls the turning table when a Ctrl-C or `kill` comes: wherever
    it lands in the poll (the driver, pymodbus, the socket, a lock), the same driver's stop
    command gets through (no stale reply, no lock left taken) and the table stops."""
    physics, twin, clock = bench
    code = tuple(os.path.dirname(m.__file__) for m in (drivers, pymodbus)) + (
        socket.__file__, threading.__file__)
    k, table = 0, driver(twin, clock)
    table.connect()
    try:  # not `with`: its stop would hang the test on a lock left taken
        while True:
            k += 1
            table.set_rate(1.0)
            table.start()
            landed = interrupted_at(k, table.state, code)
            assert ends(table.stop, 30), f"no stop got through after a Ctrl-C at {landed}"
            if landed is None:
                break
            wait_for(lambda r: not r.running, table)
    finally:
        table.close()
    assert k > 100  # the sweep went through pymodbus' request and reply
