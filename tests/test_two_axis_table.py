"""Position axis of a two-axis rotary table: the driver against its Modbus twin (a real pymodbus
server on 127.0.0.1) with `station.sim.table.PositionAxis` physics."""

import tomllib
from pathlib import Path

import numpy as np
import pytest

from drivers.clock import ScaledClock
from drivers.profile import ProfileError
from drivers.rotary_table import RotaryTable, TableError, TableRegisterMap, TableTimeout
from drivers.twins.table import TableTwin
from station.sim.table import PositionAxis, TablePhysics

TWO_AXIS = TableRegisterMap.load("table_two_axis")
ONE_AXIS = TableRegisterMap.load("table_modbus")
AXIS_RATE = 0.5  # rad/s, the position axis' slew rate in these tests
PROFILES = Path(__file__).resolve().parent.parent / "drivers" / "profiles"


REPLY = 2.0  # wall s for a Modbus reply: no test here is about a silent table; a busy host is slow

pytestmark = pytest.mark.usefixtures("quiet_pymodbus")


@pytest.fixture
def bench():
    """(table physics, position axis, twin, clock) at 20x speed on an ephemeral port."""
    clock = ScaledClock(speed=20.0)
    physics = TablePhysics(clock, max_accel=4.0, settle_time=0.5)
    axis = PositionAxis(clock, max_rate=AXIS_RATE)
    with TableTwin(physics, TWO_AXIS, lifetime=30.0, position=axis) as twin:
        yield physics, axis, twin, clock


def driver(twin, clock, register_map=TWO_AXIS) -> RotaryTable:
    return RotaryTable("127.0.0.1", twin.port, register_map, timeout=REPLY, retries=1, clock=clock)


@pytest.mark.parametrize("target", [1.2, -0.7])
def test_set_position_waits_until_the_axis_is_there(bench, target):
    physics, axis, twin, clock = bench
    with driver(twin, clock) as table:
        assert table.state().in_position and table.state().position == 0.0
        t0 = clock.now()
        reading = table.set_position(target)
        took = clock.now() - t0
    # the axis slews at AXIS_RATE: it cannot be there sooner; the register resolution is 1e-4 rad
    assert took >= abs(target) / AXIS_RATE
    assert reading.in_position
    assert reading.position == pytest.approx(target, abs=1 / TWO_AXIS.angle_scale)
    assert axis.state().angle == pytest.approx(target, abs=1 / TWO_AXIS.angle_scale)


def test_not_in_position_in_time_is_a_timeout_naming_the_table_and_the_table_is_stopped(bench):
    physics, axis, twin, clock = bench
    with driver(twin, clock) as table:
        table.set_rate(1.0)
        table.start()
        needed = 2.0 / AXIS_RATE  # clock seconds the move takes
        with pytest.raises(TableTimeout, match=rf"rotary table at 127.0.0.1:{twin.port}: position "
                                               r"axis not in position.*check") as caught:
            table.set_position(2.0, timeout=needed / 4)
        assert caught.value.table_stopped is True
        assert not physics.state().running
        halted = axis.state()  # the stop halts the position axis' slew too, short of 2 rad
        assert halted.in_position and halted.angle < 2.0 and not halted.moving


def test_a_one_axis_map_reads_as_before_and_refuses_a_position(bench):
    clock = ScaledClock(speed=20.0)
    with TableTwin(TablePhysics(clock), ONE_AXIS, lifetime=30.0) as twin, \
            driver(twin, clock, ONE_AXIS) as table:
        reading = table.state()
        assert (reading.position, reading.position_setpoint, reading.in_position) == (None,) * 3
        with pytest.raises(TableError, match="no position axis; use a two-axis profile"):
            table.set_position(0.5)
    assert not ONE_AXIS.two_axis and TWO_AXIS.two_axis
    assert ONE_AXIS.span == (0, 8) and TWO_AXIS.span == (0, 17)


@pytest.mark.parametrize("drop, missing", [
    ("position", "position"), ("position_setpoint", "position_setpoint"),
    ("in_position", "in_position"),
])
def test_half_a_position_axis_is_refused(tmp_path, drop, missing):
    data = (PROFILES / "table_two_axis.toml").read_text()
    kept = [line for line in data.splitlines() if not line.startswith(f"{drop} =")]
    path = tmp_path / "table.toml"
    path.write_text("\n".join(kept) + "\n")
    assert tomllib.loads(path.read_text())  # still a valid TOML file
    with pytest.raises(ProfileError, match=f"lacks .*'{missing}'"):
        TableRegisterMap.load(path)


def test_the_virtual_bench_turns_its_unit_with_the_position_axis():
    """`VirtualBench(two_axis=True)`: the real driver sets phi over Modbus and the simulated unit
    takes `two_axis.orientation(phi)` from the instant the axis arrives, not before."""
    from station.model.two_axis import orientation
    from station.twin.rotary_bench import VirtualBench

    # a real-time clock: nothing reads the IMU here, and in lockstep time a twin whose port is
    # full waits for its reader (docs/simulator.md "Time on the virtual bench")
    with VirtualBench(seed=2, speed=40.0, two_axis=True) as bench, \
            bench.drivers() as (_, table):
        assert np.allclose(bench.mounted.orientation_at(bench.clock.now()), orientation(0.0))
        t0 = bench.clock.now()
        reading = table.set_position(1.0)
        arrival = t0 + 1.0 / bench.position.max_rate
        assert reading.in_position and bench.clock.now() >= arrival  # not in position sooner
        assert np.allclose(bench.mounted.orientation_at(bench.clock.now()), orientation(1.0))
        assert np.allclose(bench.mounted.orientation_at(t0), orientation(0.0))
        assert bench.metadata()["two_axis"] is True


def test_a_two_axis_session_records_with_no_mounting_and_the_unit_follows_phi(tmp_path):
    """The rotary protocol on `VirtualBench(two_axis=True)`: the mount step sets phi over Modbus
    (recorded in `position_start`), the technician never mounts anything, and the rotating-window
    readings are Eq. (18)'s a^T (w u(phi_j)) within 6 of their sigmas (u: the cone direction)."""
    from station.model.two_axis import position_angles, rate_axis
    from station.protocols.rotary import RotarySettings
    from station.reduce.rotary import rotary_readings
    from station.session import Session
    from station.twin.rotary_bench import VirtualBench, record_rotary

    fast = RotarySettings(rate=1.0, revolutions=1, static=3.0, rest=0.5, guard=0.5, steady=0.5)
    phis = position_angles(3)
    path = tmp_path / "two_axis.h5"
    with VirtualBench(seed=3, two_axis=True) as bench:
        record_rotary(bench, path, fast, phis=phis)
        truth = bench.truth()
    assert len(truth.orientations) == 0  # nobody mounted anything
    with Session.open(path) as f:
        starts = [e for e in f.events() if e.kind == "position_start"]
        reduced = rotary_readings(f)
        assert f.metadata["phis"] == pytest.approx(phis.tolist())
    assert [e.detail["phi"] for e in starts] == pytest.approx(phis.tolist())
    expected = truth.a.T @ (1.0 * rate_axis(phis)).T
    assert reduced.M.shape == (12, 3)
    assert np.all(np.abs(reduced.M - expected) < 6 * reduced.sigma)


def test_resume_sets_phi_again_for_the_positions_left(tmp_path):
    """A two-axis session aborted by a table fault after its first position: `resume_rotary`
    builds a two-axis bench from the file's metadata and records the rest, setting phi itself."""
    import threading
    import time

    from drivers.rotary_table import TableFault
    from station.model.two_axis import position_angles, rate_axis
    from station.protocols.rotary import RotarySettings
    from station.reduce.rotary import rotary_readings
    from station.session import Session
    from station.twin.rotary_bench import VirtualBench, record_rotary, resume_rotary

    fast = RotarySettings(rate=1.0, revolutions=1, static=3.0, rest=0.5, guard=0.5, steady=0.5)
    phis = position_angles(3)
    path = tmp_path / "two_axis.h5"

    def fault_after_the_first_position(bench):
        def watch(writer):
            def wait():
                while writer.last_completed_position is None:
                    time.sleep(0.005)
                bench.table_twin.inject("exception", count=1, code=4)
            threading.Thread(target=wait, daemon=True).start()
        return watch

    with VirtualBench(seed=3, two_axis=True) as bench, \
            pytest.raises(TableFault):
        a = bench.unit.a  # the resumed bench is built from the same seed: the same unit
        record_rotary(bench, path, fast, phis=phis, watch=fault_after_the_first_position(bench))
    assert resume_rotary(path) == 1
    with Session.open(path) as f:
        starts = [e for e in f.events() if e.kind == "position_start"]
        reduced = rotary_readings(f)
    resumed = [e.detail["phi"] for e in starts if e.position > 0]
    assert resumed[-2:] == pytest.approx(phis[1:].tolist())
    expected = a.T @ rate_axis(phis).T
    assert np.all(np.abs(reduced.M - expected) < 6 * reduced.sigma)
