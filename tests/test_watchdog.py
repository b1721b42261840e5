"""Device watchdogs (issue 30): the register maps' [table.watchdog] / [chamber.watchdog], the
drivers' heartbeat, the twins that act when it stops, and the unattended campaign refused
without them.

Every bound on a time comes from the configured watchdog period: the twin acts no earlier than
`period` after the last beat (the beat before the heartbeat stopped, at most `beat` before) and,
on a real-time clock, no later than `period` after it plus one more period for a loaded host.
"""

import dataclasses
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient

from drivers.clock import ScaledClock, SteppedClock
from drivers.errors import ProfileError, TableError
from drivers.profile import BUNDLED
from drivers.rotary_table import RotaryTable, TableRegisterMap
from drivers.thermal_chamber import ChamberRegisterMap, ThermalChamber
from drivers.twins.chamber import ChamberTwin
from drivers.twins.table import TableTwin
from drivers.twins.thermal import ChamberPhysics
from station.sim.table import TablePhysics

TABLE = TableRegisterMap.load("table_modbus")
CHAMBER = ChamberRegisterMap.load("chamber_modbus")
STATION = [sys.executable, "-m", "station"]
COLD = 263.15  # K: a campaign's setpoint, which the chamber must not be left at

pytestmark = pytest.mark.usefixtures("quiet_pymodbus")


def with_period(register_map, period: float):
    """`register_map` with its watchdog's period set to `period` s."""
    return dataclasses.replace(register_map,
                               watchdog=dataclasses.replace(register_map.watchdog, period=period))


# -- the register maps -------------------------------------------------------------------------

def test_every_bundled_table_and_chamber_profile_has_a_watchdog():
    """Short enough for the targets (table stopped within 2 s, chamber safe within 5 s); the
    chamber's safe setpoint is the campaign's default one, so the two never disagree."""
    from station.protocols.thermal import ROOM

    tables = [p.stem for p in BUNDLED.glob("table_*.toml")]
    chambers = [p.stem for p in BUNDLED.glob("chamber_*.toml")]
    assert len(tables) == 3 and len(chambers) == 2
    for name in tables:
        w = TableRegisterMap.load(name).watchdog
        assert w.action == "stop" and w.period == 1.0
    for name in chambers:
        w = ChamberRegisterMap.load(name).watchdog
        assert (w.action, w.safe_setpoint, w.period) == ("safe", ROOM, 2.0)


def test_a_map_without_a_watchdog_is_as_before(tmp_path):
    path = tmp_path / "plain.toml"
    text = (BUNDLED / "table_modbus.toml").read_text()
    path.write_text(text[:text.index("[table.watchdog]")])
    plain = TableRegisterMap.load(path)
    assert plain.watchdog is None and plain.span == (0, 8)


TABLE_EDITS = {
    "period negative": (("period = 1.0", "period = -1.0"), "period: must be a finite"),
    "period nan": (("period = 1.0", "period = nan"), "period: must be a finite"),
    "period missing": (("period = 1.0", ""), "period: missing"),
    "register clash": (("register = 20", "register = 4"), "register 4 is also the rate register"),
    "register range": (("register = 20", "register = 70000"), "register: must be an address"),
    "bit clash": (("tripped_bit = 7", "tripped_bit = 2"), "tripped_bit 2 is also status bit"),
    "action": (('action = "stop"', 'action = "safe"'), "action: must be one of 'stop'"),
    "typo": (("period = 1.0", "period = 1.0\nperiode = 2.0"), "unknown keys ['periode']"),
}
CHAMBER_EDITS = {
    "no safe setpoint": (("safe_setpoint = 296.15", ""), "safe_setpoint: give it"),
    "off with a setpoint": (('action = "safe"', 'action = "off"'), "safe_setpoint: give it"),
    "safe out of limits": (("safe_setpoint = 296.15", "safe_setpoint = 500.0"),
                           "safe_setpoint 500.0 K is outside the setpoint limits"),
    "register clash": (("register = 10 ", "register = 3 "), "register 3 is also the temperature"),
}


@pytest.mark.parametrize("case", TABLE_EDITS)
def test_a_bad_table_watchdog_is_refused_naming_the_field(tmp_path, case):
    (old, new), message = TABLE_EDITS[case]
    text = (BUNDLED / "table_modbus.toml").read_text()
    assert old in text
    path = tmp_path / "table.toml"
    path.write_text(text.replace(old, new))
    with pytest.raises(ProfileError, match="watchdog") as caught:
        TableRegisterMap.load(path)
    assert message in str(caught.value) and str(path) in str(caught.value)


@pytest.mark.parametrize("case", CHAMBER_EDITS)
def test_a_bad_chamber_watchdog_is_refused_naming_the_field(tmp_path, case):
    (old, new), message = CHAMBER_EDITS[case]
    text = (BUNDLED / "chamber_modbus.toml").read_text()
    assert old in text
    path = tmp_path / "chamber.toml"
    path.write_text(text.replace(old, new))
    with pytest.raises(ProfileError, match="watchdog") as caught:
        ChamberRegisterMap.load(path)
    assert message in str(caught.value) and str(path) in str(caught.value)


# -- the twins act when the heartbeat stops --------------------------------------------------------

class Bench:
    """A table or chamber twin on `clock`, its driver, and how to read what the watchdog acts on."""

    def __init__(self, device: str, clock, period: float):
        self.device, self.clock = device, clock
        if device == "table":
            self.map = with_period(TABLE, period)
            self.physics = TablePhysics(clock, max_accel=2.0, settle_time=0.1)
            self.twin = TableTwin(self.physics, self.map, lifetime=60.0).start()
            self.driver = RotaryTable("127.0.0.1", self.twin.port, self.map, clock=clock)
        else:
            self.map = with_period(CHAMBER, period)
            self.physics = ChamberPhysics(clock)
            self.twin = ChamberTwin(self.physics, self.map, lifetime=60.0).start()
            self.driver = ThermalChamber(self.map, host="127.0.0.1", port=self.twin.port,
                                         clock=clock)
        self.driver.connect()
        self.errors = []

    def run(self) -> None:
        """Turn the table at 1 rad/s, or send the chamber to COLD."""
        if self.device == "table":
            self.driver.set_rate(1.0)
            self.driver.start()
        else:
            self.driver.set_setpoint(COLD)
            self.driver.run()

    def acted(self) -> bool:
        """Has the device done its watchdog action (the table stopped, the chamber at safe)?"""
        if self.device == "table":
            return not self.physics.state().running
        s = self.physics.state()
        return s.setpoint == self.map.watchdog.safe_setpoint and s.running

    def close(self) -> None:
        self.driver.close()
        self.twin.close()


@pytest.mark.parametrize("device", ["table", "chamber"])
def test_at_a_speed_the_heartbeat_keeps_the_device_running_and_its_loss_trips_it(device):
    """A scaled clock 20x the wall: the watchdog's period is wall seconds (a controller's timer),
    so a held device runs on for several periods; once the beats stop it acts within the
    period (plus one for the host), not before; the tripped bit reads true until a run."""
    period = 0.5
    bench = Bench(device, ScaledClock(20.0), period)
    try:
        with bench.driver.heartbeat(bench.errors.append) as beat:
            bench.run()
            time.sleep(4 * period)
            assert not bench.acted() and bench.twin.watchdog.armed
            assert bench.driver.state().watchdog_tripped is False
        stopped = time.monotonic()
        assert beat.beats >= 4 * 3 - 2  # every period / 3, the first at once
        while not bench.acted() and time.monotonic() < stopped + 2 * period:
            time.sleep(0.01)
        took = time.monotonic() - stopped
        assert bench.acted(), f"no watchdog action {took:.2f} s after the last heartbeat"
        assert took >= period - period / 3 - 0.05  # not before the period after the last beat
        reading = bench.driver.state()
        assert reading.watchdog_tripped is True and not bench.twin.watchdog.armed
        bench.run()  # a fresh run command clears the bit
        assert bench.driver.state().watchdog_tripped is False and not bench.acted()
        assert bench.errors == []
    finally:
        bench.close()


@pytest.mark.parametrize("device", ["table", "chamber"])
def test_in_lockstep_the_device_acts_one_period_after_the_last_beat(device):
    """Lockstep time: the heartbeat is a member of the stepped clock, so the device runs on for
    as long as the session holds it however slowly the host goes; after the last beat it acts
    at that beat + period exactly (clock seconds)."""
    clock = SteppedClock()
    clock.enlist()
    bench = Bench(device, clock, 1.0)
    try:
        with bench.driver.heartbeat(bench.errors.append) as beat:
            bench.run()
            clock.sleep(30.0)
            assert not bench.acted() and bench.errors == []
            assert beat.beats == pytest.approx(30.0 / beat.watchdog.beat, abs=1)
            released = clock.now()
        clock.sleep(3.0)
        assert bench.acted()
        (trip,) = bench.twin.watchdog.trips
        last_beat = released - released % beat.watchdog.beat  # beats at 0, beat, 2 beat, ...
        assert trip == pytest.approx(last_beat + 1.0, abs=1e-6)
    finally:
        clock.leave()
        bench.close()


def test_a_heartbeat_that_cannot_be_written_is_told_once_and_goes_on():
    """The table's link goes silent: the failed beat is a TableError told to the session once
    (not swallowed); when the link comes back the beats go on and the table was stopped by its
    own watchdog meanwhile."""
    period = 0.5
    bench = Bench("table", ScaledClock(1.0), period)
    bench.driver.timeout, bench.driver.retries = period / 5, 0
    try:
        with bench.driver.heartbeat(bench.errors.append) as beat:
            bench.run()
            bench.twin.silent = True
            time.sleep(3 * period)
            bench.twin.silent = False
            before = beat.beats
            time.sleep(period)
            assert beat.beats > before
        assert len(bench.errors) == 1 and isinstance(bench.errors[0], TableError)
        assert "watchdog heartbeat could not be written" in " ".join(bench.errors[0].__notes__)
        assert bench.acted() and bench.twin.watchdog.trips
    finally:
        bench.close()


def test_a_station_restarted_after_one_beat_arms_the_watchdog_at_its_first():
    """A station killed right after its first beat leaves the register at that count; the next
    station's first beat must change it (the count goes on from the register), or the device
    would run unwatched until its second beat."""
    period = 0.5
    bench = Bench("chamber", ScaledClock(1.0), period)
    try:
        for station in range(2):
            with bench.driver.heartbeat(bench.errors.append) as beat:
                bench.run()  # at once: before the second beat
            assert beat.beats == 1 and bench.twin.watchdog.value == station + 1
            deadline = time.monotonic() + 2 * period
            while len(bench.twin.watchdog.trips) <= station and time.monotonic() < deadline:
                time.sleep(0.01)
            assert len(bench.twin.watchdog.trips) == station + 1 and bench.acted()
        assert bench.errors == []
    finally:
        bench.close()


def test_a_heartbeat_does_not_ask_the_physics():
    """The table's physics draws its reported rate's noise at every look: a beat (its read-back
    included) must not look, or a beat at the instant of a poll would change what the poll reads
    and a lockstep session would depend on the host's thread order."""
    looks = []

    class Counted(TablePhysics):
        def state(self):
            looks.append(1)
            return super().state()

    clock = ScaledClock(1.0)
    twin = TableTwin(Counted(clock), TABLE, lifetime=30.0).start()
    table = RotaryTable("127.0.0.1", twin.port, TABLE, clock=clock)
    try:
        table.connect()
        with table.heartbeat(print) as beat:
            time.sleep(2 * beat.watchdog.beat)
        assert beat.beats >= 2 and twin.watchdog.value == beat.beats and looks == []
        table.state()
        assert looks == [1]
    finally:
        table.close()
        twin.close()


def test_a_failed_beat_is_delivered_to_the_session_and_withdrawn_with_the_device():
    """`station.acquire.watchdog.fed`: the heartbeat's TableTimeout is what the protocol's next
    poll raises (`interrupts.raise_dropped`), as any lost device; released, it is withdrawn."""
    from drivers.errors import TableTimeout
    from station.acquire import interrupts
    from station.acquire.watchdog import fed

    bench = Bench("table", ScaledClock(1.0), 0.5)
    bench.driver.timeout, bench.driver.retries = 0.1, 0
    try:
        with fed(bench.driver):
            interrupts.raise_dropped()  # nothing yet
            bench.twin.silent = True
            deadline = time.monotonic() + 5.0
            with pytest.raises(TableTimeout, match="rotary table at 127.0.0.1"):
                while time.monotonic() < deadline:
                    interrupts.raise_dropped()
                    time.sleep(0.01)
            bench.twin.silent = False
        interrupts.raise_dropped()  # withdrawn with the device
    finally:
        interrupts.handled()
        bench.close()


LOCKSTEP_STATION = textwrap.dedent("""
    import sys
    from drivers.clock_link import connect
    from drivers.rotary_table import RotaryTable, TableRegisterMap
    clock = connect(sys.argv[1])
    clock.enlist()
    table = RotaryTable("127.0.0.1", int(sys.argv[2]), TableRegisterMap.load("table_modbus"),
                        clock=clock)
    table.connect()
    with table.heartbeat(print):
        table.set_rate(1.0)
        table.start()
        clock.sleep(5.0)
        print("turning", flush=True)
        clock.sleep(1e9)
""")


def test_in_lockstep_a_killed_station_still_trips_the_twin():
    """The station's process on the twin's served stepped clock dies: the clock server drops its
    member, the armed watchdog is the one member left that is not a producer, so time moves to
    its deadline and the table stops (1 period after the last beat, in clock seconds)."""
    from drivers.clock_link import ClockServer

    clock = SteppedClock()
    physics = TablePhysics(clock, max_accel=2.0, settle_time=0.1)
    server = ClockServer(clock)
    twin = TableTwin(physics, TABLE, lifetime=120.0).start()
    try:
        station = subprocess.Popen([sys.executable, "-c", LOCKSTEP_STATION, server.path,
                                    str(twin.port)], stdout=subprocess.PIPE, text=True,
                                   cwd=Path(__file__).parents[1])
        assert station.stdout.readline().strip() == "turning"
        assert physics.state().running
        station.send_signal(signal.SIGKILL)
        station.wait(10)
        killed = time.monotonic()
        while physics.state().running and time.monotonic() < killed + 30:
            time.sleep(0.01)
        assert not physics.state().running
        (trip,) = twin.watchdog.trips
        assert trip >= 5.0 + TABLE.watchdog.period - 1e-9  # turning 5 s in, beats going on
    finally:
        twin.close()
        server.close()


# -- station record -------------------------------------------------------------------------

def thermal_profile(tmp_path, table_watchdog: bool, chamber_watchdog: bool) -> Path:
    """A thermal bench profile (nothing behind its addresses) whose table and chamber maps have
    a watchdog or not."""
    def copy(name, section):
        text = (BUNDLED / f"{name}.toml").read_text()
        out = tmp_path / f"{name}.toml"
        out.write_text(text if section is None else text[:text.index(section)])
        return out.name

    table = copy("table_fixture", None if table_watchdog else "[table.watchdog]")
    chamber = copy("chamber_modbus", None if chamber_watchdog else "[chamber.watchdog]")
    path = tmp_path / "thermal.toml"
    path.write_text(
        '[bench]\nunit_serial = "SIM-1"\n\n[imu]\nlink = "serial"\nprofile = '
        '"imu12_serial_temp"\nport = "/dev/null"\n\n[table]\nhost = "127.0.0.1"\nport = 1\n'
        f'profile = "{table}"\n\n[protocol]\npositions = 3\n\n[chamber]\nhost = "127.0.0.1"\n'
        f'port = 1\nprofile = "{chamber}"\nsetpoints = [263.15, 313.15]\n')
    return path


@pytest.mark.parametrize("table, chamber", [(False, True), (True, False), (False, False)])
def test_an_unattended_campaign_without_a_watchdog_is_refused(tmp_path, capsys, table, chamber):
    from station import cli

    profile = thermal_profile(tmp_path, table, chamber)
    out = tmp_path / "campaign"
    assert cli.main(["record", "--profile", str(profile), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert ("[table.watchdog]" in err) == (not table)
    assert ("[chamber.watchdog]" in err) == (not chamber)
    assert "--no-watchdog" in err and not out.exists()


def test_no_watchdog_records_anyway(tmp_path, capsys):
    """--no-watchdog passes the refusal: the campaign starts (and fails on the devices that are
    not there, exit 3)."""
    from station import cli

    profile = thermal_profile(tmp_path, False, False)
    out = tmp_path / "campaign"
    code = cli.main(["record", "--profile", str(profile), "--out", str(out), "--no-watchdog"])
    err = capsys.readouterr().err
    assert code == 3 and "--no-watchdog" not in err and "thermal chamber at 127.0.0.1:1" in err
    assert (out / "campaign.json").exists()


def read_table(client, register_map) -> tuple:
    """(rate rad/s, running) read from the twin's registers by a plain pymodbus client."""
    first, count = register_map.span
    regs = client.read_holding_registers(first, count=count, device_id=1).registers
    rate = register_map.decode([regs[a - first] for a in register_map.addresses("rate")],
                               register_map.rate_scale)
    return rate, regs[register_map.registers["command"] - first] == register_map.run


def test_a_sigkilled_record_leaves_the_table_to_its_watchdog(tmp_path):
    """`station record` against `station twin --speed 1`, SIGKILLed while the table turns: the
    table's rate reads 0 (a plain Modbus client) within the watchdog period plus the time to
    decelerate from the rate it read (the twin's 2 rad/s^2) plus one period for a loaded host."""
    profile = tmp_path / "bench.toml"
    twin = subprocess.Popen([*STATION, "twin", "--speed", "1", "--positions", "2", "--json",
                             "--lifetime", "300", "--profile-out", str(profile)],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    record = None
    try:
        info = json.loads(twin.stdout.readline())
        profile.write_text(profile.read_text().replace("[protocol]\n",
                                                       "[protocol]\nstatic = 1.0\n"))
        table_map = TableRegisterMap.load(info["table"]["profile"])
        client = ModbusTcpClient("127.0.0.1", port=info["table"]["port"])
        assert client.connect()
        record = subprocess.Popen([*STATION, "record", "--profile", str(profile), "--out",
                                   str(tmp_path / "s.h5")], stdin=subprocess.DEVNULL,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 120
        while abs(read_table(client, table_map)[0]) < 0.5 and time.monotonic() < deadline:
            time.sleep(0.05)
        rate, running = read_table(client, table_map)
        assert running and abs(rate) >= 0.5, "the session never turned the table"
        os.kill(record.pid, signal.SIGKILL)
        killed = time.monotonic()
        record.wait(10)
        bound = 2 * table_map.watchdog.period + abs(rate) / 2.0
        while read_table(client, table_map)[0] != 0.0 and time.monotonic() < killed + 2 * bound:
            time.sleep(0.01)
        took = time.monotonic() - killed
        assert read_table(client, table_map) == (0.0, False)
        assert took <= bound, f"the table stopped {took:.2f} s after the kill (bound {bound} s)"
        client.close()
    finally:
        for process in (record, twin):
            if process is not None and process.poll() is None:
                process.send_signal(signal.SIGKILL)
                process.wait(10)


# -- the live view ---------------------------------------------------------------------------

def test_the_live_view_shows_the_watchdog_armed_tripped_or_missing():
    import io
    from types import SimpleNamespace

    import numpy as np
    from rich.console import Console

    from station.acquire.live_view import LiveView
    from station.protocols.rotary import RotarySettings

    def shown(watchdog, tripped=None) -> str:
        view = LiveView(ScaledClock(1.0), rate_hz=200.0, watchdog=watchdog)
        view.protocol = SimpleNamespace(axes=np.zeros((3, 3)), position=0, state="rotate",
                                        settings=RotarySettings(),
                                        instruction=lambda j: SimpleNamespace(text="mount"))
        view.on_table(SimpleNamespace(rate=1.0, rate_setpoint=1.0, moving=True, running=True,
                                      at_rate=True, fault=False, watchdog_tripped=tripped))
        console = Console(file=io.StringIO(), width=150, record=True)
        console.print(view.render())
        return " ".join(console.export_text().split())

    w = TABLE.watchdog
    assert f"armed, period {w.period:g} s, stops the table; heartbeat every 0.33 s" in \
        shown(w, False)
    assert "tripped: no heartbeat for 1 s" in shown(w, True)
    assert "none in the table's register map" in shown(False)
    assert "watchdog" not in shown(None)
