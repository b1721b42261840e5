"""A rotary table whose controller drives a motorised mounting fixture (profile table_fixture):
the driver asks for a position over Modbus and waits until the fixture holds the unit there; the
station's rotary protocol commands the mountings itself, so a session and its resume mount the
positions the station records, whatever the host's load (issue 18: `station twin`'s fixture used
to guess from the table's motion whether a position was completed, and guessed wrongly under
load)."""

import io
import threading
import tomllib
from pathlib import Path

import numpy as np
import pytest
from technicians import QuitsAt

from drivers.clock import ScaledClock
from drivers.profile import ProfileError
from drivers.rotary_table import RotaryTable, TableError, TableRegisterMap, TableTimeout
from drivers.twins.table import TableTwin
from station.acquire.bench import BenchProfile, record
from station.acquire.operator import ConsoleOperator
from station.session import Session
from station.sim.table import MountingFixture, TablePhysics
from station.twin.served import BenchTwin

FIXTURE = TableRegisterMap.load("table_fixture")
PROFILES = Path(__file__).resolve().parent.parent / "drivers" / "profiles"
MOUNT_TIME = 2.0  # clock s the served fixture below takes to mount

REPLY = 2.0  # wall s for a Modbus reply: no test here is about a silent table; a busy host is slow

pytestmark = pytest.mark.usefixtures("quiet_pymodbus")


@pytest.fixture
def served():
    """(table physics, fixture, twin, clock, mounted list): a fixture served by a thread that
    mounts each position asked for in MOUNT_TIME clock seconds, at 20x."""
    clock = ScaledClock(speed=20.0)
    physics, fixture, mounted, stop = TablePhysics(clock), MountingFixture(), [], threading.Event()

    def serve():
        while not stop.wait(0.002):
            if (position := fixture.pending()) is not None:
                clock.sleep(MOUNT_TIME)
                mounted.append(position)
                fixture.done(position)

    worker = threading.Thread(target=serve, daemon=True)
    worker.start()
    with TableTwin(physics, FIXTURE, lifetime=30.0, fixture=fixture) as twin:
        yield physics, fixture, twin, clock, mounted
    stop.set()
    worker.join()


def driver(twin, clock, register_map=FIXTURE) -> RotaryTable:
    return RotaryTable("127.0.0.1", twin.port, register_map, timeout=REPLY, retries=1, clock=clock)


def test_mount_waits_until_the_fixture_holds_the_position_asked_for(served):
    _, _, twin, clock, mounted = served
    with driver(twin, clock) as table:
        before = table.state()
        assert (before.mount, before.mounted) == (0, False)  # nothing asked yet
        t0 = clock.now()
        reading = table.mount(3)
        took = clock.now() - t0
        assert (reading.mount, reading.mounted) == (3, True) and took >= MOUNT_TIME
        t0 = clock.now()
        assert table.mount(3).mounted and clock.now() - t0 < MOUNT_TIME  # held: no move
        table.mount(1)
    assert mounted == [3, 1]


def test_a_fixture_that_does_not_mount_in_time_is_a_timeout_and_the_table_is_stopped():
    clock = ScaledClock(speed=20.0)
    physics = TablePhysics(clock)
    with TableTwin(physics, FIXTURE, lifetime=30.0, fixture=MountingFixture()) as twin, \
            driver(twin, clock) as table:
        table.set_rate(1.0)
        table.start()
        with pytest.raises(TableTimeout, match=rf"rotary table at 127.0.0.1:{twin.port}: fixture "
                                               r"did not report position 2 mounted.*asked: 2, "
                                               r"mounted: False") as caught:
            table.mount(2, timeout=1.0)
        assert caught.value.table_stopped is True
        assert not physics.state().running


def test_a_table_without_a_fixture_refuses_a_mount_and_reads_none():
    clock = ScaledClock(speed=20.0)
    plain = TableRegisterMap.load("table_modbus")
    with TableTwin(TablePhysics(clock), plain, lifetime=30.0) as twin, \
            driver(twin, clock, plain) as table:
        assert (table.state().mount, table.state().mounted) == (None, None)
        with pytest.raises(TableError, match="no mounting fixture; use a profile with one"):
            table.mount(1)
    with pytest.raises(ValueError, match="1..65535"):
        RotaryTable("127.0.0.1", 1, FIXTURE).mount(0)
    assert FIXTURE.fixture and not plain.fixture and FIXTURE.span == (0, 9)


@pytest.mark.parametrize("drop", ["mount", "mounted"])
def test_half_a_fixture_is_refused(tmp_path, drop):
    data = (PROFILES / "table_fixture.toml").read_text()
    path = tmp_path / "table.toml"
    path.write_text("\n".join(line for line in data.splitlines()
                              if not line.startswith(f"{drop} =")) + "\n")
    assert tomllib.loads(path.read_text())  # still a valid TOML file
    with pytest.raises(ProfileError, match=f"lacks .*'{drop}'"):
        TableRegisterMap.load(path)


def test_a_session_aborted_and_resumed_mounts_each_position_it_records(tmp_path):
    """`station twin`'s bench: the station asks the fixture for each position; aborted while it
    announces position 3 and resumed, the fixture mounts position 3 again and then 4..6 (never
    one ahead), and every rotating window reads Eq. (18)'s a^T (w u_j) of the direction the
    station recorded for it, within 6 of its sigma."""
    from station.acquire.bench import resume
    from station.acquire.operator import OperatorAbort
    from station.reduce.rotary import rotary_readings

    positions = 6
    with BenchTwin(seed=4, positions=positions) as twin:
        (tmp_path / "b.toml").write_text(twin.profile_text())
        bench = BenchProfile.load(tmp_path / "b.toml")
        assert bench.table_map.fixture
        with pytest.raises(OperatorAbort):
            record(bench, tmp_path / "s.h5", QuitsAt(f"position 3/{positions}"))
        assert resume(bench, tmp_path / "s.h5", ConsoleOperator(io.StringIO(""),
                                                                 io.StringIO())) == 2
        truth = twin.truth()
    assert truth["mounted"] == [1, 2, 3, 4, 5, 6]  # the first, then each asked for once
    with Session.open(tmp_path / "s.h5") as s:
        starts = [e for e in s.events() if e.kind == "position_start"]
        reduced = rotary_readings(s)
        axes = np.array(s.metadata["axes"])
    assert [e.detail["mount"] for e in starts] == [1, 2, 3, 4, 5, 6]
    a = np.array(truth["a"])
    set_ = np.array(truth["orientations"])[:, :, 2]  # one per mounting, in order
    assert np.all(np.einsum("ij,ij->i", set_, axes) > np.cos(np.radians(3)))  # 0.5 deg placement
    expected = a.T @ set_.T  # the rate is 1 rad/s
    assert np.all(np.abs(reduced.M - expected) < 6 * reduced.sigma)
