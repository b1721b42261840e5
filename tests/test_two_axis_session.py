"""A complete two-axis rotary session (issue 16): the position axis' rate mode (register map,
driver, physics, twin), the session of cone positions plus a spin of the position axis recorded by
`station record` with no operator input and solved by `station solve`, its resume after an abort
during the spin, and the safety of both axes (every stop stops both)."""

import io
import json
import signal
import subprocess
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy import stats
from twinproc import ENV, STATION, TwinProcess, station_run

import station
from drivers.clock import ScaledClock
from drivers.profile import ProfileError
from drivers.rotary_table import RotaryTable, TableError, TableRegisterMap, TableTimeout
from drivers.twins.table import TableTwin
from station.acquire.bench import BenchProfile, record, stop_table
from station.acquire.operator import ConsoleOperator
from station.calfiles.calfile import load
from station.commands.solve import solve_session
from station.errors import CalibrationInputError
from station.model.two_axis import position_angles, position_axis, spin_axes
from station.protocols.rotary import RotaryProtocol, RotarySettings
from station.reduce.rotary import position_spins, rotary_readings
from station.session import Event, Session
from station.sim.table import PositionAxis, TablePhysics
from station.solve.uncertainty import eps_tail_probability
from station.twin.rotary_bench import VirtualBench, record_rotary, resume_rotary
from station.twin.served import BenchTwin

ROOT = Path(__file__).resolve().parent.parent
PROFILES = ROOT / "drivers" / "profiles"
TWO_AXIS = TableRegisterMap.load("table_two_axis")
CONE = 8  # positions on the cone of the acceptance session, then one spin of the position axis
ALARM = 1e-4  # false-alarm probability of each statistical check
FAST = RotarySettings(rate=1.0, revolutions=1, static=3.0, rest=0.5, guard=0.5, steady=0.5)

pytestmark = pytest.mark.usefixtures("quiet_pymodbus")


def check_solution(cal, truth_a, truth_bias, axes, sigma, rate=1.0) -> None:
    """The calibration against the twin's truth, each check at false-alarm probability ALARM:
    chi2 within its two-sided chi-square bounds, eps (Eq. 19) consistent with the Cramer-Rao
    bound, scale factors within the normal quantile of their sigmas, biases within Student's t
    (mean of n static means, sigma from their scatter: n - 1 dof), Bonferroni over the sensors."""
    a = np.asarray(truth_a)
    m, n = a.shape[1], len(axes)
    dof = cal.fit["dof"]
    low, high = stats.chi2.ppf([ALARM / 2, 1 - ALARM / 2], dof)
    assert low < cal.fit["chi2"] < high, (cal.fit["chi2"], dof)
    v = rate * np.asarray(axes).T
    assert eps_tail_probability(station.eps(a, cal.a), station.crlb(a, v, sigma)) > ALARM
    k = stats.norm.ppf(1 - ALARM / (2 * m))
    assert np.all(np.abs(cal.scale_factors - np.linalg.norm(a, axis=0))
                  < k * cal.scale_factors_sigma)
    t = stats.t.ppf(1 - ALARM / (2 * m), n - 1)
    assert np.all(np.abs(cal.bias - np.asarray(truth_bias)) < t * cal.bias_sigma)


def test_a_two_axis_session_on_the_twin_needs_no_input_and_solves(tmp_path):
    """`station twin --two-axis` and `station record --profile` with stdin closed: 8 positions on
    the cone and one spin of the position axis, set by the station over Modbus; `station solve`
    then finds the twin's unit within the statistical bounds."""
    profile, session, cal = tmp_path / "two_axis.toml", tmp_path / "s.h5", tmp_path / "cal.json"
    with TwinProcess("--two-axis", "--positions", str(CONE), "--seed", "3",
                     "--profile-out", str(profile), "--lifetime", "1500") as twin:  # lockstep
        assert twin.started["table"]["profile"] == "table_two_axis"
        rec = station_run("record", "--profile", str(profile), "--out", str(session), "--json")
        assert rec.returncode == 0, rec.stderr
        summary = json.loads(rec.stdout)
        assert summary["positions_done"] == summary["positions_planned"] == CONE + 1
        assert "press Enter" not in rec.stderr and "mount the unit" not in rec.stderr
        assert rec.stderr.count("the position axis spins (the rate axis at rest)") == 1
        solved = station_run("solve", str(session), "--out", str(cal), "--json")
        assert solved.returncode == 0, solved.stderr
        # the report leaves the spin out of the rate axis' stability (no false warning); the
        # diagnosis, which models the rate axis' motion only, refuses the session by name
        report = station_run("report", str(session), "--out", str(tmp_path / "r.html"))
        assert report.returncode == 0, report.stderr
        assert "report written" in report.stdout and "left its tolerance" not in report.stdout
        diagnosed = station_run("diagnose", str(session))
        assert diagnosed.returncode == 2
        assert f"spins the position axis of a two-axis table at position(s) {CONE + 1}" in \
            diagnosed.stderr
    truth = twin.truth
    assert truth["orientations"] == []  # nobody mounted anything
    axes = np.array(truth["axes"])
    assert axes.shape == (CONE + 1, 3) and np.allclose(axes[-1], position_axis())
    with Session.open(session) as s:
        events = s.events()
        metadata = s.metadata
        reduced = rotary_readings(s)
    assert metadata["phis"] == pytest.approx(position_angles(CONE).tolist())
    assert metadata["spins"] == 1
    starts = [e for e in events if e.kind == "position_start"]
    assert [e.detail.get("spin") for e in starts] == [None] * CONE + ["position"]
    assert [e.kind for e in events].count("position_done") == CONE + 1
    spun = [e for e in events if e.kind in ("rotate_start", "rotate_end") and e.position == CONE]
    assert [e.detail["axis"] for e in spun] == ["position"] * 2
    # 2 turns + a quarter of margin of the position axis, cut to 2 whole turns
    assert spun[1].detail["angle"] - spun[0].detail["angle"] >= 2.25 * 2 * np.pi
    assert list(reduced.revolutions) == [2] * (CONE + 1)
    # every reading, the spin's included, is a^T (w u_j) (Eq. 18) within its sigma's quantile
    k = stats.norm.ppf(1 - ALARM / (2 * reduced.M.size))
    assert np.all(np.abs(reduced.M - np.array(truth["a"]).T @ axes.T) < k * reduced.sigma)
    check_solution(load(cal), truth["a"], truth["bias"], axes, reduced.sigma)


def test_station_record_interrupted_in_the_spin_is_resumed_by_station_resume(tmp_path):
    """Ctrl-C to `station record` while the position axis spins (the twin in its own process):
    the session ends with `abort` (table stopped), `station resume` (stdin closed) records the
    spin again on the same twin and the file solves within the statistical bounds."""
    cone = 5  # with c, the 6 directions Eq. (7)'s g needs
    profile, session, cal = tmp_path / "two_axis.toml", tmp_path / "s.h5", tmp_path / "cal.json"
    with TwinProcess("--two-axis", "--positions", str(cone), "--seed", "6",  # lockstep: at 40x
                     "--profile-out", str(profile), "--lifetime", "1500") as twin:  # real time a
        # loaded host's late samples made position 1's rotating window spiky (2,976 readings
        # beyond 8 sigma beside 6 CPU hogs): the recorded data must not depend on the host
        rec = subprocess.Popen(  # --json: the prompts on stderr
            [*STATION, "record", "--profile", str(profile), "--out", str(session), "--json"],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            env=ENV)
        for line in rec.stderr:
            if f"position {cone + 1}: rotating window" in line:
                rec.send_signal(signal.SIGINT)
                break
        rec.communicate(timeout=600)
        assert rec.returncode == 130
        with Session.open(session) as s:
            aborts = [e for e in s.events() if e.kind == "abort"]
            assert s.last_completed_position() == cone - 1
        assert [(e.position, e.detail["table_stopped"]) for e in aborts] == [(cone, True)]
        resumed = station_run("resume", str(session), "--json")
        assert resumed.returncode == 0, resumed.stderr
        solved = station_run("solve", str(session), "--out", str(cal), "--json")
        assert solved.returncode == 0, solved.stderr
    truth = twin.truth
    with Session.open(session) as s:
        starts = [e for e in s.events() if e.kind == "position_start"]
        reduced = rotary_readings(s)
    assert [e.position for e in starts if e.detail.get("spin")] == [cone, cone]
    check_solution(load(cal), truth["a"], truth["bias"], truth["axes"], reduced.sigma)


@pytest.mark.parametrize("args, words", [
    (["--two-axis", "--cube"], "--cube and --two-axis exclude each other"),
    (["--two-axis", "--protocol", "static"], "--two-axis: a static bench has no rotary table"),
])
def test_station_twin_refuses_a_two_axis_bench_it_cannot_serve(tmp_path, args, words):
    refused = station_run("twin", *args, "--profile-out", str(tmp_path / "p.toml"), timeout=600)
    assert refused.returncode == 2 and words in refused.stderr, refused.stderr
    assert not (tmp_path / "p.toml").exists()


def test_three_units_on_a_two_axis_table_recorded_and_solved_each_against_its_truth(tmp_path):
    """A plate of three units (each its own truth and mounting) on the two-axis table, no
    operator: the station sets the cone positions and the spin itself; each unit, turned about
    the same two physical axes, sees them in its own frame and is solved within the statistical
    bounds against its own truth and axes (ALARM per unit)."""
    path, profile = tmp_path / "s.h5", tmp_path / "b.toml"
    with BenchTwin(seed=9, positions=6, rate_hz=100, two_axis=True,
                   units=3) as twin:
        profile.write_text(twin.profile_text())
        bench = BenchProfile.load(profile)
        assert bench.plate and bench.spins == 1
        record(bench, path, ConsoleOperator(stdin=io.StringIO(), stdout=io.StringIO()))
        truth = twin.truth()
    for unit in truth["units"]:
        with Session.open(path) as s:
            sigma = rotary_readings(s, unit["stream"]).sigma
        cal = solve_session(path, unit["stream"])
        check_solution(cal, unit["a"], unit["bias"], unit["axes"], sigma)
    # the units' axes: one physical axis each time, in three frames
    first, second = (np.array(u["axes"]) for u in truth["units"][:2])
    assert np.allclose(np.linalg.norm(second, axis=1), 1) and not np.allclose(first, second)


class AbortsInTheSpin:
    """The bench's technician, who raises KeyboardInterrupt at the rotating window of position
    `at` (1-based: the spin, the position axis at rate), noting then the state of both axes."""

    def __init__(self, bench, at: int):
        self.bench, self.technician, self.at = bench, bench.technician, at
        self.seen = None

    def __getattr__(self, name):
        return getattr(self.technician, name)

    def prompt(self, text: str) -> None:
        self.technician.prompt(text)
        if f"position {self.at}: rotating window" in text and self.seen is None:
            self.seen = (self.bench.position.state(), self.bench.table.state())
            raise KeyboardInterrupt


def test_an_abort_during_the_spin_stops_both_axes_and_the_session_resumes_and_solves(tmp_path):
    """An exception during the position axis' spin: the protocol stops the table, both axes come
    to rest, `abort` is recorded; `resume_rotary` records the spin again and the file solves."""
    # 6 on the cone: with c, the 6 directions Eq. (7)'s g needs (+-c are one for it)
    cone, path, cal = 6, tmp_path / "two_axis.h5", tmp_path / "cal.json"
    phis = position_angles(cone)
    with VirtualBench(seed=4, two_axis=True) as bench:
        a, bias = bench.unit.a.copy(), bench.unit.bias.copy()
        quitter = AbortsInTheSpin(bench, cone + 1)
        original = bench.technician
        bench.technician = quitter
        try:
            with pytest.raises(KeyboardInterrupt):
                record_rotary(bench, path, FAST, phis=phis, spins=1)
        finally:
            bench.technician = original
        spinning, table = quitter.seen
        assert spinning.spinning and spinning.at_rate and spinning.rate == pytest.approx(1.0)
        assert not table.moving  # the rate axis at rest during the spin
        stopped = bench.position.state()
        assert not stopped.spinning and not bench.table.state().running  # both commanded to stop
        bench.clock.sleep(1.0)  # from 1 rad/s at the bench's 2 rad/s^2: 0.5 s
        assert not bench.position.state().moving and not bench.table.state().moving
    with Session.open(path) as f:
        aborts = [e for e in f.events() if e.kind == "abort"]
        assert [(e.position, e.detail["state"], e.detail["table_stopped"]) for e in aborts] == [
            (cone, "rotating", True)]
        assert f.last_completed_position() == cone - 1
    assert resume_rotary(path) == cone
    with Session.open(path) as f:
        reduced = rotary_readings(f)
        events = f.events()
    spins = [e for e in events if e.kind == "position_start" and e.detail.get("spin")]
    assert [e.position for e in spins] == [cone, cone]  # the spin recorded again
    axes = spin_axes(phis, 1)
    k = stats.norm.ppf(1 - ALARM / (2 * reduced.M.size))
    assert np.all(np.abs(reduced.M - a.T @ axes.T) < k * reduced.sigma)
    solved = station_run("solve", str(path), "--out", str(cal), "--json")
    assert solved.returncode == 0, solved.stderr
    check_solution(load(cal), a, bias, axes, reduced.sigma)
    with Session.open(path) as f:
        assert RotaryProtocol.from_metadata(f.metadata, None, None, None).spins == 1


@pytest.mark.parametrize("drop", ["position_mode", "position_rate_setpoint", "position_rate",
                                  "position_at_rate", "position_moving"])
def test_half_a_rate_mode_is_refused_naming_what_is_missing(tmp_path, drop):
    data = (PROFILES / "table_two_axis.toml").read_text()
    kept = [line for line in data.splitlines() if not line.startswith(f"{drop} =")]
    assert len(kept) == len(data.splitlines()) - 1
    path = tmp_path / "table.toml"
    path.write_text("\n".join(kept) + "\n")
    assert tomllib.loads(path.read_text())
    with pytest.raises(ProfileError, match=rf"lacks \['{drop}'\]"):
        TableRegisterMap.load(path)


def test_a_rate_mode_without_a_position_axis_is_refused(tmp_path):
    data = (PROFILES / "table_two_axis.toml").read_text()
    drop = ("position_setpoint =", "position =", "in_position =")
    path = tmp_path / "table.toml"
    path.write_text("\n".join(line for line in data.splitlines()
                              if not line.startswith(drop)) + "\n")
    with pytest.raises(ProfileError, match="lacks .*'position_setpoint', 'position', "
                                           "'in_position'"):
        TableRegisterMap.load(path)


@pytest.fixture
def table_bench():
    """(table physics, position axis, twin, clock) of a two-axis table at 20x on 127.0.0.1."""
    clock = ScaledClock(speed=20.0)
    physics = TablePhysics(clock, max_accel=4.0, settle_time=0.5)
    axis = PositionAxis(clock, max_accel=0.5, settle_time=0.5)
    with TableTwin(physics, TWO_AXIS, lifetime=30.0, position=axis) as twin:
        yield physics, axis, twin, clock


def driver(twin, clock) -> RotaryTable:
    return RotaryTable("127.0.0.1", twin.port, TWO_AXIS, timeout=1.0, retries=1, clock=clock)


def test_spin_position_reaches_its_rate_and_the_angle_is_cumulative(table_bench):
    physics, axis, twin, clock = table_bench
    with driver(twin, clock) as table:
        t0 = clock.now()
        reading = table.spin_position(-1.0)
        # ramped at 0.5 rad/s^2, then settled 0.5 s: not at rate sooner
        assert clock.now() - t0 >= 1.0 / 0.5 + 0.5
        assert reading.position_spinning and reading.position_at_rate
        assert reading.position_rate == pytest.approx(-1.0, abs=1e-3) and not reading.moving
        clock.sleep(10.0)
        later = table.state()
        assert later.position < -10.0  # cumulative, past a turn: no wrap at 2 pi
        table.stop()
        rest = table.state()
        assert not rest.position_spinning and not rest.running
    clock.sleep(1.0 / 0.5 + 0.1)  # the deceleration from 1 rad/s at 0.5 rad/s^2
    final = axis.state()
    assert not final.moving and final.in_position
    assert final.setpoint == final.angle  # held where it came to rest


def test_a_spin_that_does_not_reach_its_rate_in_time_is_a_timeout_with_both_axes_stopped(
        table_bench):
    physics, axis, twin, clock = table_bench
    with driver(twin, clock) as table:
        table.set_rate(1.0)
        table.start()
        words = rf"127.0.0.1:{twin.port}: position axis not at 2 rad/s within 1.0 s \(at .*; check"
        with pytest.raises(TableTimeout, match=words) as caught:
            table.spin_position(2.0, timeout=1.0)  # the ramp alone takes 4 s
        assert caught.value.table_stopped is True
        assert not physics.state().running and not axis.state().spinning


@pytest.mark.parametrize("how", ["stop", "exit", "station resume"])
def test_every_stop_stops_both_axes(tmp_path, table_bench, how):
    """`RotaryTable.stop`, the driver's exit and `station resume`'s first stop (`stop_table` of
    a bench profile): the rate axis and a spinning position axis both come to rest."""
    physics, axis, twin, clock = table_bench
    table = driver(twin, clock)
    with table:
        table.set_rate(1.0)
        table.start()
        table.spin_position(1.0)
        assert physics.state().running and axis.state().spinning
        if how == "stop":
            table.stop()
        elif how == "station resume":
            profile = tmp_path / "bench.toml"
            profile.write_text(f'[table]\nhost = "127.0.0.1"\nport = {twin.port}\n'
                               'profile = "table_two_axis"\n')
            assert stop_table(profile) is True
        if how != "exit":
            assert not physics.state().running and not axis.state().spinning
    assert not physics.state().running and not axis.state().spinning
    clock.sleep(1.0 / 0.5 + 0.1)
    assert not physics.state().moving and not axis.state().moving


def test_damaged_spin_bounds_are_refused():
    def events(detail):
        return [Event(0.0, 0, "position_start", {}),
                Event(1.0, 0, "rotate_start", {"axis": "position", "angle": 0.0, "time": 1.0}),
                Event(9.0, 0, "rotate_end", {"axis": "position", **detail})]

    good = position_spins(events({"angle": 14.0, "time": 9.0}))
    assert good == {0: ((1.0, 0.0), (9.0, 14.0))}
    for bad in ({"angle": "14", "time": 9.0}, {"angle": float("nan"), "time": 9.0},
                {"angle": 14.0, "time": 0.5}, {"angle": 14.0}):
        with pytest.raises(CalibrationInputError, match="position 1: the position axis' "
                                                        "rotating window"):
            position_spins(events(bad))


def test_a_bench_profile_on_a_two_axis_table(tmp_path):
    """`spins` defaults to 1 on a two-axis table; a two-axis map without the rate mode and a
    `spins` key on a one-axis table are refused."""
    base = ('[bench]\nunit_serial = "X"\n[imu]\nlink = "serial"\nport = "/dev/null"\n'
            'profile = "imu12_serial"\n[table]\nhost = "127.0.0.1"\nport = 5020\n')
    for name, spins in (("table_two_axis", 1), ("table_modbus", 0)):
        path = tmp_path / f"{name}.toml"
        path.write_text(base + f'profile = "{name}"\n[protocol]\npositions = 6\n')
        assert BenchProfile.load(path).spins == spins
    path = tmp_path / "three.toml"
    path.write_text(base + 'profile = "table_two_axis"\n[protocol]\npositions = 6\nspins = 3\n')
    assert BenchProfile.load(path).spins == 3
    path.write_text(base + 'profile = "table_modbus"\n[protocol]\npositions = 6\nspins = 1\n')
    with pytest.raises(ProfileError, match="spins: only a two-axis table"):
        BenchProfile.load(path)
    no_rate = tmp_path / "no_rate.toml"
    no_rate.write_text("\n".join(
        line for line in (PROFILES / "table_two_axis.toml").read_text().splitlines()
        if not line.startswith(("position_mode", "position_rate", "position_at_rate",
                                "position_moving"))) + "\n")
    path.write_text(base + f'profile = "{no_rate}"\n[protocol]\npositions = 6\n')
    with pytest.raises(ProfileError, match="no rate mode of the position axis"):
        BenchProfile.load(path)
    # the driver refuses a spin on it before it sends anything
    with pytest.raises(TableError, match="no rate mode of the position axis; use a two-axis "
                                         "profile with one"):
        RotaryTable("127.0.0.1", 1, TableRegisterMap.load(no_rate)).spin_position(1.0)



def test_the_live_view_follows_the_spinning_axis():
    """During a spin of the position axis the live view counts the turns of that axis (not of
    the rate axis, at rest) and shows its rate."""
    from rich.console import Console

    from drivers.rotary_table import TableReading
    from station.acquire.live_view import LiveView

    class Clock:
        def now(self) -> float:
            return 50.0

    view = LiveView(Clock(), rate_hz=200.0)
    phis = position_angles(6)
    protocol = view.follow(RotaryProtocol(table=None, operator=None, clock=Clock(),
                                          axes=spin_axes(phis, 1), phis=phis, spins=1))
    protocol.position, protocol.state = 6, "rotating"
    view.on_event("position_start", 6, {"spin": "position"})
    view.on_event("rotate_start", 6, {"angle": 2.0, "axis": "position", "time": 49.0})
    view.on_table(TableReading(50.0, 0.0, 7.0, 1.0, False, True, False, False, False,
                               position=2.0 + 3 * np.pi, position_setpoint=0.0,
                               in_position=False, position_rate=1.0, position_rate_setpoint=1.0,
                               position_spinning=True, position_at_rate=True,
                               position_moving=True))
    console = Console(file=io.StringIO(), width=130, record=True)
    console.print(view.render())
    text = console.export_text()
    assert "1.50 of 2 turns" in text  # 3 pi of the position axis, 2 turns (default settings)
    assert "position axis +1.0000 rad/s at 11.425 rad" in text
