"""A twin whose thread cannot go on (drivers/twins/failure.py): it goes silent at once, its owner
is told at once from the twin's own thread (not at stop()), and the station's error names the
twin's cause. Real twins and real drivers throughout; only the simulation behind a twin breaks,
at a moment the test chooses (a clock instant, or once the driver has read), never at a wall time.
"""

import threading
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from drivers.can_imu import CanImu, CanProfile
from drivers.clock import ScaledClock
from drivers.errors import ChamberError, ChamberLinkError, DeviceLostError, TwinError
from drivers.mavlink_imu import MavlinkImu, MavlinkProfile
from drivers.profile import SerialImuProfile
from drivers.serial_imu import SerialImu
from drivers.thermal_chamber import ChamberRegisterMap, ThermalChamber
from drivers.twins.can import CanImuTwin
from drivers.twins.chamber import ChamberTwin
from drivers.twins.mavlink import MavlinkTwin
from drivers.twins.serial import SerialTwin
from drivers.twins.thermal import ChamberPhysics
from station.errors import StationError
from station.protocols.rotary import RotarySettings, suggested_axes
from station.twin.rotary_bench import VirtualBench, record_rotary

BROKE = "the simulation broke"
GUARD = 600.0
"""Clock seconds a test waits at most for what must happen (a hang guard, never a figure)."""


class Breaks:
    """`func`, until `when(*args)` holds: then it raises, as a simulation's bug would, mid-stream;
    `broke` counts the calls that raised."""

    def __init__(self, func, when):
        self.func, self.when, self.broke = func, when, 0

    def __call__(self, *args):
        if self.when(*args):
            self.broke += 1
            raise RuntimeError(BROKE)
        return self.func(*args)


class Owner:
    """An owner's `on_error`: what it was told, in which thread, and `look(twin)` then."""

    def __init__(self, twin, look):
        self.twin, self.look = twin, look
        self.told = []
        twin.on_error = self

    def __call__(self, exc):
        self.told.append((exc, threading.current_thread().name, self.look(self.twin)))


def counts(m: int):
    """A source of m channels of small integer counts."""
    return lambda times: (np.arange(len(times))[:, None] + np.arange(m)).astype(np.int64)


def read_until_lost(clock, imu) -> None:
    """Read `imu` until its driver says the device is lost (within GUARD clock seconds)."""
    end = clock.now() + GUARD
    with pytest.raises(DeviceLostError):
        while clock.now() < end:
            imu.read_block(timeout=1.0)


def serial_pair(clock, armed):
    profile = SerialImuProfile.load("imu12_serial")
    twin = SerialTwin(profile, Breaks(counts(12), lambda _: armed.is_set()), clock=clock)
    return twin, lambda: SerialImu(twin.port, profile, clock=clock)


def mavlink_pair(clock, armed):
    profile = MavlinkProfile.load("imu6_scaled_mavlink")
    twin = MavlinkTwin(profile, Breaks(counts(6), lambda _: armed.is_set()), clock, stream=True)
    return twin, lambda: MavlinkImu(twin.port, profile, clock)


@pytest.mark.parametrize("pair, thread", [(serial_pair, "serial-twin"),
                                          (mavlink_pair, "mavlink-twin")],
                         ids=["serial", "mavlink"])
def test_a_streamer_whose_source_breaks_is_unplugged_and_tells_its_owner_at_once(pair, thread):
    clock, armed = ScaledClock(10.0), threading.Event()
    twin, driver = pair(clock, armed)
    owner = Owner(twin, look=lambda t: not t.plugged)
    with twin, driver() as imu:
        assert imu.read_block(timeout=GUARD) is not None
        armed.set()
        read_until_lost(clock, imu)  # the station's driver sees a lost device, not a silence
        for ending in [t for t in threading.enumerate() if t.name == thread]:
            ending.join(30)  # it tells its owner right after silencing the device
        (exc, told_in, silent), = owner.told
        assert str(exc) == BROKE and twin.error is exc
        assert told_in == thread and silent  # from the twin's thread, once it was unplugged
        assert twin.source.broke == 1  # and it asked nothing more
        twin.plug()
        assert not twin.plugged  # a crashed device stays silent
    assert owner.told == [(exc, thread, True)]  # stop() told nobody twice, raised nothing


def test_without_an_owner_stop_raises_the_streaming_error_as_before():
    clock, armed = ScaledClock(10.0), threading.Event()
    twin, driver = serial_pair(clock, armed)
    with pytest.raises(RuntimeError, match=BROKE), twin, driver() as imu:
        assert imu.read_block(timeout=GUARD) is not None
        armed.set()
        read_until_lost(clock, imu)


def test_a_can_twin_whose_source_breaks_goes_silent_and_tells_at_once():
    profile = CanProfile.load("imu12_can")
    channel, clock, armed = f"failure-{uuid.uuid4().hex}", ScaledClock(10.0), threading.Event()
    twin = CanImuTwin(channel, profile, Breaks(counts(12), lambda _: armed.is_set()), clock)
    owner = Owner(twin, look=lambda t: len(t.sent_seq))
    with CanImu({"interface": "virtual", "channel": channel}, profile, clock=clock) as imu, twin:
        assert imu.read_block(timeout=GUARD) is not None
        armed.set()
        assert twin.wait(timeout=GUARD)  # the stream ended by itself
        (exc, told_in, sent), = owner.told
        assert str(exc) == BROKE and twin.error is exc and told_in.startswith("CanImuTwin")
        assert len(twin.sent_seq) == sent and twin.source.broke == 1
    assert twin.error is exc  # stop() kept it, as before


class BreakingChamber(ChamberPhysics):
    """The chamber's physics, which breaks once `armed`."""

    armed = False

    def state(self):
        if self.armed:
            raise RuntimeError(BROKE)
        return super().state()


@pytest.mark.usefixtures("quiet_pymodbus")
def test_a_modbus_twin_whose_physics_breaks_closes_and_tells_at_once():
    register_map = ChamberRegisterMap.load("chamber_modbus")
    physics = BreakingChamber(ScaledClock(10.0))
    twin = ChamberTwin(physics, register_map, lifetime=GUARD)
    owner = Owner(twin, look=lambda t: t.error is not None)

    def driver():
        return ThermalChamber(register_map, host="127.0.0.1", port=twin.port, timeout=1.0,
                              retries=1, clock=physics.clock)

    with twin:
        with driver() as chamber:
            chamber.state()
            physics.armed = True
            with pytest.raises(ChamberError):
                chamber.state()
        (exc, told_in, _), = owner.told
        assert str(exc) == BROKE and twin.error is exc and told_in == "ChamberTwin"
        with pytest.raises(ChamberLinkError), driver() as chamber:  # the server has closed
            chamber.state()


@pytest.mark.parametrize("speed", [40.0, None], ids=["40x", "lockstep"])
@pytest.mark.parametrize("imu, lost", [("serial", "did not come back"),
                                       ("can", "no IMU sample for")])
def test_the_stations_error_names_the_twin_that_broke_and_why(imu, lost, speed, tmp_path,
                                                              caplog):
    """The IMU twin's unit breaks 20 s of clock into the session: the serial port goes at once
    (the protocol's reconnections fail), the CAN bus goes silent (the recorder's guard); either
    way the bench warns at once, before the station gives up, and the error that ends the session
    says which twin stopped and why - on a real-time clock and in lockstep time."""
    bench = VirtualBench(imu, seed=3, speed=speed, rate_hz=50.0, remount_time=1.0)
    with pytest.raises(StationError, match=lost) as info, bench:
        bench.unit.sample = Breaks(bench.unit.sample, lambda v, times, *_: times[-1] >= 20.0)
        record_rotary(bench, tmp_path / "s.h5", RotarySettings(), suggested_axes(4))
    notes = " ".join(getattr(info.value, "__notes__", ()))
    words = f"the {dict(serial='serial', can='CAN')[imu]} IMU twin stopped: RuntimeError: {BROKE}"
    assert f"the virtual bench failed: {words}" in notes
    assert bench.failures.failed[0][1].args == (BROKE,)
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert warnings[0] == words and "aborted" in warnings[-1]  # told before the station knew


def test_station_twin_ends_at_once_naming_the_twin(monkeypatch, tmp_path, capsys):
    """`station twin` whose IMU's unit breaks once a station has read from it: the command ends
    at once (long before its lifetime) with one line naming the twin and the error, exit 1."""
    from station import cli
    from station.twin import served

    armed = threading.Event()

    def breaking_twin(options):
        twin = rotary(options)
        twin.bench.unit.sample = Breaks(twin.bench.unit.sample, lambda *_: armed.is_set())
        return twin

    def station(profile: Path, lost: list) -> None:
        """A station reading the twin's port until the device is lost."""
        import tomllib

        clock = ScaledClock(20.0)
        while not profile.exists():
            clock.sleep(0.2)
        port = tomllib.loads(profile.read_text())["imu"]["port"]
        with SerialImu(port, SerialImuProfile.load("imu12_serial"), clock=clock) as imu:
            while imu.read_block(timeout=1.0) is None:
                pass
            armed.set()
            read_until_lost(clock, imu)
            lost.append(True)

    rotary = served.rotary_twin
    monkeypatch.setattr(served, "rotary_twin", breaking_twin)
    profile, lost = tmp_path / "bench.toml", []
    reader = threading.Thread(target=station, args=(profile, lost), daemon=True)
    reader.start()
    lifetime, start = 300.0, time.monotonic()
    code = cli.main(["twin", "--speed", "20", "--rate-hz", "100", "--positions", "2",
                     "--lifetime", str(lifetime), "--profile-out", str(profile), "--json"])
    assert time.monotonic() - start < lifetime  # it ended, not served on until its lifetime
    reader.join(GUARD / 20.0)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == TwinError.exit_code == 1 and lost == [True]
    assert err[-1] == f"station twin: the serial IMU twin stopped: RuntimeError: {BROKE}"
