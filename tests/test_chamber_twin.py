"""The virtual thermal chamber: its physics against the closed-form solutions of its equations
(drivers/twins/thermal.py), and its server's answers to a plain pymodbus client."""

import math
import time
from pathlib import Path

import numpy as np
import pytest
from pymodbus.client import ModbusTcpClient

from drivers.clock import ScaledClock
from drivers.thermal_chamber import ChamberRegisterMap
from drivers.twins.chamber import ChamberTwin
from drivers.twins.thermal import ChamberPhysics

ROOM = 296.15
INT16 = ChamberRegisterMap.load("chamber_modbus")
FLOAT32 = ChamberRegisterMap.load("chamber_float_rtu")

pytestmark = pytest.mark.usefixtures("quiet_pymodbus")


class SetClock:
    """A clock the test sets by hand (the physics only asks it for the time)."""

    def __init__(self):
        self.t = 0.0

    def now(self) -> float:
        return self.t


def physics(**settings) -> tuple:
    clock = SetClock()
    return clock, ChamberPhysics(clock, **dict(room=ROOM, tau_air=20.0, heat_rate=6.0,
                                               cool_rate=2.0, tau_unit=120.0) | settings)


def air_at(clock, p, t: float) -> float:
    clock.t = t
    return p.state().air


@pytest.mark.parametrize("target, rate", [(ROOM + 30.0, 6.0), (ROOM - 15.0, 2.0)],
                         ids=["heating", "cooling"])
def test_air_is_rate_limited_then_exponential(target, rate):
    """On the limit h the air moves h*t; once the gap is h*tau it decays as exp(-t/tau)."""
    clock, p = physics()
    p.set_setpoint(target)
    p.run()
    h, tau, sign = rate / 60.0, 20.0, math.copysign(1.0, target - ROOM)
    assert air_at(clock, p, 60.0) == pytest.approx(ROOM + sign * h * 60.0, abs=1e-9)
    t_knee = abs(target - ROOM) / h - tau  # gap h*tau reached
    for s in (10.0, 40.0):
        gap = target - air_at(clock, p, t_knee + s)
        assert gap == pytest.approx(sign * h * tau * math.exp(-s / tau), rel=2e-3)


def test_heating_and_cooling_limits_differ():
    clock, p = physics()
    p.set_setpoint(ROOM + 50.0)
    p.run()
    heated = air_at(clock, p, 100.0) - ROOM
    p.set_setpoint(ROOM - 50.0)
    at_150 = air_at(clock, p, 150.0)  # past the turn-around
    cooled = air_at(clock, p, 200.0) - at_150
    assert heated == pytest.approx(6.0 / 60 * 100.0)
    assert cooled == pytest.approx(-2.0 / 60 * 50.0)


def test_unit_follows_a_ramp_with_its_time_constant():
    """Air ramping at h from the room: U(t) = T0 + h(t - tau_u(1 - exp(-t/tau_u)))."""
    clock, p = physics(tau_air=5.0)
    p.set_setpoint(ROOM + 60.0)
    p.run()
    h, tau_u = 6.0 / 60, 120.0
    for t in (60.0, 120.0, 240.0):  # the air is on its limit until 600 - 5 s
        clock.t = t
        assert p.unit_temperature() == pytest.approx(
            ROOM + h * (t - tau_u * (1 - math.exp(-t / tau_u))), abs=1e-4)
    assert p.unit_temperature(120.0) == pytest.approx(ROOM + h * tau_u / math.e, abs=1e-3)


def test_stopped_air_and_unit_relax_to_the_room():
    """Stopped, the air decays to the room with tau_room; the unit follows it."""
    clock, p = physics(tau_air=1.0, heat_rate=600.0, tau_room=100.0, tau_unit=1.0)
    p.set_setpoint(ROOM + 10.0)
    p.run()
    hot = air_at(clock, p, 30.0)
    assert hot == pytest.approx(ROOM + 10.0, abs=1e-6)
    p.stop()
    assert air_at(clock, p, 130.0) - ROOM == pytest.approx(10.0 * math.exp(-1), rel=1e-3)
    assert p.unit_temperature() > air_at(clock, p, 130.0)  # it lags the cooling air


def test_alarm_stops_conditioning_and_a_new_run_is_refused():
    clock, p = physics()
    p.set_setpoint(ROOM + 20.0)
    p.run()
    p.alarm = True
    state = p.state()
    assert (state.running, state.alarm) == (False, True)
    p.run()
    assert not p.state().running  # refused in alarm
    p.alarm = False
    assert not p.state().running  # stays stopped once the alarm is cleared
    p.run()
    assert p.state().running


def test_unit_temperature_of_the_past_is_interpolated():
    """Linear interpolation between steps dt errs by at most dt^2/8 max|U''|, and on the air's
    ramp h, |U''| = h/tau_u exp(-t/tau_u) <= h/tau_u."""
    clock, p = physics()
    p.set_setpoint(ROOM + 30.0)
    p.run()
    early = p.unit_temperature(50.0)
    clock.t = 400.0
    p.state()
    assert p.unit_temperature(50.0) == pytest.approx(early, abs=p.step**2 / 8 * 0.1 / 120)
    assert p.unit_temperature(-1.0) == ROOM  # before the start: where the unit sat


def test_a_late_question_gets_the_value_an_early_one_got():
    """A busy host makes the IMU twin ask for its sample times late: asked after the physics ran
    100 000 steps further (the old history kept 20 000), every instant gets, to the last bit, the
    value a physics asked in order, a sample block at a time, got (the commands alike)."""
    times = np.arange(0.0, 600.0, 0.01)

    def chamber(ask_on_time: bool):
        clock, p = physics()
        p.set_setpoint(ROOM + 30.0)
        p.run()
        got, sent = [], 0
        for now in np.arange(0.0, 600.0, 0.37):  # the chamber's polls and the twin's blocks
            clock.t = now
            if now >= 250.0 and p.setpoint > ROOM:
                p.set_setpoint(ROOM - 10.0)
            p.state()
            due = np.searchsorted(times, now, side="right")
            if ask_on_time and due > sent:
                got.append(p.unit_temperature(times[sent:due]))
                sent = due
        return clock, p, np.concatenate(got or [[]])

    _, on_time, got = chamber(ask_on_time=True)
    clock, late, _ = chamber(ask_on_time=False)
    clock.t = 20000.0
    late.state()
    asked = times[: len(got)]
    np.testing.assert_array_equal(late.unit_temperature(asked), got)
    assert [late.unit_temperature(t) for t in asked[::997]] == list(got[::997])


def plain_client(twin) -> ModbusTcpClient:
    client = ModbusTcpClient("127.0.0.1", port=twin.port, timeout=5.0)  # a busy host may be slow
    assert client.connect()
    return client


def test_twin_refuses_what_a_controller_would():
    with ChamberTwin(ChamberPhysics(ScaledClock(10.0)), FLOAT32, lifetime=10.0) as twin:
        client = plain_client(twin)
        try:
            def write(address, values):
                return client.write_registers(address, values, device_id=7)

            assert write(104, [0, 0]).exception_code == 2  # the measured temperature
            assert write(100, [0]).exception_code == 2  # half of the setpoint's float
            assert write(111, [9]).exception_code == 3  # no such command
            hot = FLOAT32.encode("setpoint", 400.0)  # degC, above the limit
            assert write(100, hot).exception_code == 3
            assert not write(100, FLOAT32.encode("setpoint", 40.0)).isError()
            assert twin.physics.setpoint == pytest.approx(313.15)
        finally:
            client.close()


def _answers(port: int) -> bool:
    """Whether a Modbus TCP server accepts a connection on the loopback `port`."""
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=0.2)
    try:
        return client.connect()
    finally:
        client.close()


def test_twin_listens_on_loopback_only_and_stops_by_itself():
    twin = ChamberTwin(ChamberPhysics(ScaledClock(10.0)), INT16, lifetime=0.5).start()
    try:
        assert twin.bound == ("127.0.0.1", twin.port)
        deadline = time.monotonic() + 60  # its lifetime (0.5 s) however late a busy host runs it
        while _answers(twin.port):
            assert time.monotonic() < deadline, "the twin outlived its lifetime by a minute"
            time.sleep(0.1)
    finally:
        twin.close()


def test_rtu_twin_removes_its_ports():
    with ChamberTwin(ChamberPhysics(ScaledClock(10.0)), INT16, link="rtu", lifetime=10.0) as twin:
        port = twin.serial_port
        with open(port, "rb"):  # a pty end a driver can open
            pass
    assert not Path(port).exists()
