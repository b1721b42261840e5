"""Thermal chamber driver against its twin: the real pymodbus clients and servers, over TCP on
127.0.0.1 and over RTU on a null-modem pair of ptys."""

import contextlib
import dataclasses
import math
import struct

import pytest
from pymodbus.client import ModbusTcpClient

from drivers.clock import ScaledClock
from drivers.errors import (
    ChamberAlarm,
    ChamberDoorOpen,
    ChamberError,
    ChamberLinkError,
    ChamberRangeError,
    ChamberReplyError,
    ChamberTimeout,
)
from drivers.thermal_chamber import ChamberRegisterMap, ThermalChamber
from drivers.twins.chamber import ChamberTwin
from drivers.twins.thermal import ChamberPhysics

INT16 = ChamberRegisterMap.load("chamber_modbus")
FLOAT_LITTLE = ChamberRegisterMap.load("chamber_float_rtu")
FLOAT_BIG = dataclasses.replace(FLOAT_LITTLE, word_order="big")
LAYOUTS = {"int16": INT16, "float32-little": FLOAT_LITTLE, "float32-big": FLOAT_BIG}
LINKS = ("tcp", "rtu")
TIMEOUT, RETRIES = 1.0, 1  # no test here waits for a timeout; a busy host may be slow
SPEED = 100.0
ROOM = 296.15  # K

pytestmark = pytest.mark.usefixtures("quiet_pymodbus")


@contextlib.contextmanager
def bench(register_map=INT16, link="tcp", **physics):
    """(physics, twin, chamber): a chamber physics at SPEED x on a twin, and a connected driver."""
    clock = ScaledClock(speed=SPEED)
    settings = dict(room=ROOM, tau_air=10.0, heat_rate=10.0, cool_rate=4.0, tau_unit=60.0) | physics
    p = ChamberPhysics(clock, **settings)
    with ChamberTwin(p, register_map, link=link, lifetime=30.0) as twin, \
            driver(twin, register_map) as chamber:
        yield p, twin, chamber


def driver(twin, register_map, **options) -> ThermalChamber:
    where = (dict(host="127.0.0.1", port=twin.port) if twin.link == "tcp"
             else dict(serial_port=twin.serial_port))
    return ThermalChamber(register_map, timeout=TIMEOUT, retries=RETRIES,
                          clock=twin.physics.clock, **where | options)


def celsius_on_the_wire(register_map, words) -> float:
    """The degC a controller of this layout means by `words`, decoded by hand from the register
    words (not with the map's own decode)."""
    if register_map.value_type == "int16":
        (counts,) = struct.unpack(">h", struct.pack(">H", words[0]))
        return counts / 10.0  # chamber_modbus: 10 counts per degC
    high, low = words if register_map.word_order == "big" else words[::-1]
    return struct.unpack(">f", struct.pack(">HH", high, low))[0]


@pytest.mark.parametrize("link", LINKS)
@pytest.mark.parametrize("layout", LAYOUTS)
def test_setpoint_and_ramp_round_trip_in_kelvin(layout, link):
    register_map = LAYOUTS[layout]
    resolution = 0.05 if layout == "int16" else 1e-5  # K: half a count, or float32 at ~250 K
    with bench(register_map, link) as (physics, twin, chamber):
        at_rest = chamber.state()
        assert at_rest.temperature == pytest.approx(ROOM, abs=resolution)
        assert (at_rest.running, at_rest.alarm, at_rest.door_open) == (False, False, False)
        chamber.set_setpoint(253.15, ramp=2.5)  # -20 degC: a negative value on the wire
        reading = chamber.state()
        assert reading.setpoint == pytest.approx(253.15, abs=resolution)
        assert reading.ramp == pytest.approx(2.5, abs=resolution)
        assert physics.setpoint == pytest.approx(253.15, abs=resolution)
        assert physics.ramp == pytest.approx(2.5, abs=resolution)
        chamber.set_setpoint(333.15, ramp=0)
        chamber.run()
        before = physics.state().air
        reading = chamber.state()
        after = physics.state().air
        assert reading.running and not reading.at_setpoint
        assert before - resolution <= reading.temperature <= after + resolution  # heating


@pytest.mark.parametrize("layout", LAYOUTS)
def test_values_on_the_wire_follow_the_layout(layout):
    """The setpoint's registers, read by a plain pymodbus client, hold the degC value in the
    layout's coding and word order."""
    register_map = LAYOUTS[layout]
    with bench(register_map) as (physics, twin, chamber):
        chamber.set_setpoint(250.65)  # -22.5 degC
        plain = ModbusTcpClient("127.0.0.1", port=twin.port, timeout=TIMEOUT)
        assert plain.connect()
        try:
            words = plain.read_holding_registers(register_map.registers["setpoint"],
                                                 count=register_map.width("setpoint"),
                                                 device_id=register_map.device_id).registers
        finally:
            plain.close()
        assert celsius_on_the_wire(register_map, words) == pytest.approx(-22.5, abs=1e-6)


def poll_until_at_setpoint(chamber, limit: float):
    """Read until the at-setpoint bit; returns (time of the last reading without it, clock time
    after the reading with it): the bit came up in between."""
    clock, last_without = chamber.clock, chamber.clock.now()
    while chamber.clock.now() < limit:
        reading = chamber.state()
        if reading.at_setpoint:
            return last_without, clock.now()
        last_without = reading.time
    raise AssertionError(f"never at setpoint before clock time {limit}")


@pytest.mark.parametrize("target, rate", [(ROOM + 20.0, 10.0), (ROOM - 10.0, 4.0)],
                         ids=["heating", "cooling"])
def test_air_reaches_the_setpoint_at_the_rate_limit(target, rate):
    """Rate-limited first-order air (drivers/twins/thermal.py): at the limit h (K/s) until the
    gap is h*tau, then exponential; within the band b at D/h - tau + tau*ln(h*tau/b)."""
    tau, band = 10.0, 0.5
    with bench(tau_air=tau) as (physics, twin, chamber):
        chamber.set_setpoint(target, ramp=0)
        chamber.run()
        h, gap = rate / 60.0, abs(target - ROOM)
        expected = physics.started + gap / h - tau + tau * math.log(h * tau / band)
        earliest, latest = poll_until_at_setpoint(chamber, expected + 60.0)
        step = 2 * physics.step  # discretisation of the integration
        assert earliest - step <= expected <= latest + step


def test_the_ramp_setting_paces_the_air():
    """Ramp r below the rate limit: the air follows the ramped setpoint, lagging r*tau(1 -
    exp(-t1/tau)) when the ramp ends at t1 = D/r, then within b after tau*ln(lag/b)."""
    tau, band, r, gap = 10.0, 0.5, 4.0, 10.0
    with bench(tau_air=tau) as (physics, twin, chamber):
        chamber.set_setpoint(ROOM + gap, ramp=r)
        chamber.run()
        t1 = gap / (r / 60.0)
        lag = r / 60.0 * tau * (1 - math.exp(-t1 / tau))
        expected = physics.started + t1 + tau * math.log(lag / band)
        earliest, latest = poll_until_at_setpoint(chamber, expected + 60.0)
        assert earliest - 2 * physics.step <= expected <= latest + 2 * physics.step


def test_unit_lags_the_air_by_its_time_constant():
    """Air on the heating limit h from the room: U(tau_unit) = T0 + h*tau_unit/e (the unit
    lags the air's ramp by h*tau_unit(1 - 1/e)), read through the twin on the shared clock."""
    tau_unit, heat = 30.0, 10.0
    with bench(tau_unit=tau_unit, heat_rate=heat) as (physics, twin, chamber):
        chamber.set_setpoint(ROOM + 60.0, ramp=0)  # the gap stays above h*tau_air past tau_unit
        chamber.run()
        t0 = physics.started
        physics.clock.sleep(tau_unit + 1.0 - (physics.clock.now() - t0))
        h = heat / 60.0
        assert twin.unit_temperature(t0 + tau_unit) == pytest.approx(
            ROOM + h * tau_unit / math.e, abs=1e-3)
        assert chamber.state().temperature > twin.unit_temperature()


@pytest.mark.parametrize("link", LINKS)
def test_a_silent_chamber_is_a_timeout_naming_it(link):
    with bench(link=link) as (physics, twin, chamber):
        twin.silent = True
        with pytest.raises(ChamberTimeout, match="no reply to read state") as caught:
            chamber.state()
        where = f"127.0.0.1:{twin.port}" if link == "tcp" else twin.serial_port
        assert where in str(caught.value)
        twin.silent = False
        assert chamber.state().temperature == pytest.approx(ROOM, abs=0.05)  # it recovers


@pytest.mark.parametrize("link", LINKS)
def test_a_short_reply_is_a_reply_error(link):
    with bench(link=link) as (physics, twin, chamber):
        twin.inject("short", count=RETRIES + 1)
        first, count = INT16.span
        with pytest.raises(ChamberReplyError, match=f"short reply, {count - 1} registers of "
                                                    f"the {count}"):
            chamber.state()


def test_a_garbled_reply_is_a_reply_error():
    with bench() as (physics, twin, chamber):
        twin.inject("garbled", count=RETRIES + 1)
        with pytest.raises(ChamberReplyError, match="garbled reply to read state"):
            chamber.state()
        assert chamber.state().temperature == pytest.approx(ROOM, abs=0.05)  # it recovers


def test_a_short_reply_once_is_retried():
    with bench() as (physics, twin, chamber):
        twin.inject("short", count=1)
        assert chamber.state().temperature == pytest.approx(ROOM, abs=0.05)
        assert twin.requests == 2


def test_an_exception_code_is_named():
    with bench() as (physics, twin, chamber):
        twin.inject("exception", code=2)
        with pytest.raises(ChamberError, match=r"exception 2 \(illegal address\)"):
            chamber.set_setpoint(300.0)


def test_alarm_refuses_to_run_and_check_raises():
    with bench() as (physics, twin, chamber):
        physics.alarm = True
        assert chamber.state().alarm
        with pytest.raises(ChamberAlarm, match="reports an alarm"):
            chamber.check()
        with pytest.raises(ChamberAlarm):
            chamber.run()
        assert not physics.running


def test_open_door_refuses_to_run():
    with bench() as (physics, twin, chamber):
        physics.door_open = True
        with pytest.raises(ChamberDoorOpen, match="door open.*close the door"):
            chamber.run()
        assert not physics.running
        physics.door_open = False
        chamber.run()
        assert chamber.check().running


@pytest.mark.parametrize("kelvin, ramp", [(500.0, None), (200.0, None), (math.nan, None),
                                          (300.0, 16.0), (300.0, -1.0)])
def test_out_of_range_values_are_refused_before_sending(kelvin, ramp):
    with bench() as (physics, twin, chamber):
        sent = twin.requests
        with pytest.raises(ChamberRangeError, match="nothing was sent"):
            chamber.set_setpoint(kelvin, ramp)
        assert twin.requests == sent
        assert (physics.setpoint, physics.ramp) == (ROOM, 0.0)


def test_a_refused_connection_is_a_link_error():
    with bench() as (physics, twin, chamber):
        port = twin.port
    with pytest.raises(ChamberLinkError, match=f"127.0.0.1:{port}: cannot connect"), \
            ThermalChamber(INT16, host="127.0.0.1", port=port, timeout=TIMEOUT):
        pass


def test_a_missing_serial_port_is_a_link_error(tmp_path):
    port = str(tmp_path / "ttyNone")
    with pytest.raises(ChamberLinkError, match=f"{port}: cannot connect"), \
            ThermalChamber(INT16, serial_port=port, timeout=TIMEOUT):
        pass


def test_leaving_on_an_error_makes_the_chamber_safe():
    with bench() as (physics, twin, chamber):
        with pytest.raises(KeyError) as caught, \
                driver(twin, INT16, safe_kelvin=ROOM + 2.0) as other:
            other.set_setpoint(330.0)
            other.run()
            raise KeyError("something else failed")
        assert caught.value.chamber_safe is True
        assert physics.setpoint == pytest.approx(ROOM + 2.0, abs=0.05)
        assert physics.running
        chamber.safe(ROOM, hold=False)
        assert not physics.running and physics.setpoint == pytest.approx(ROOM, abs=0.05)


def test_leaving_on_an_error_says_when_the_chamber_could_not_be_made_safe():
    with bench() as (physics, twin, chamber):
        with pytest.raises(KeyError) as caught, \
                driver(twin, INT16, safe_kelvin=ROOM) as other:
            other.set_setpoint(330.0)
            twin.silent = True
            raise KeyError("something else failed")
        assert caught.value.chamber_safe is False
        assert "set it by hand" in caught.value.__notes__[0]
