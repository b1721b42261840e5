"""The rotary protocol on the virtual bench: state sequence, recorded windows, stopping the table on
every kind of failure, resuming, refusing lossy recordings; orientation suggestions; operators."""

import io
import logging

import numpy as np
import pytest

from drivers.rotary_table import TableFault
from station.acquire.operator import (
    ConsoleOperator,
    Instruction,
    OperatorAbort,
    SimulatedTechnician,
)
from station.acquire.recorder import Recorder, RecordingError
from station.errors import CalibrationInputError
from station.protocols.rotary import (
    ProtocolError,
    RotaryProtocol,
    RotarySettings,
    mounting,
    suggested_axes,
)
from station.reduce.rotary import position_windows, rotary_readings
from station.reduce.timeline import sample_times
from station.session import Event, Session, SessionWriter
from station.twin.rotary_bench import VirtualBench

# short windows: one position is about 20 s of clock; the sessions run in lockstep time (the bench's
# default), so what they record does not depend on the host's speed
FAST = RotarySettings(rate=1.0, revolutions=1, static=3.0, rest=0.5, guard=0.5, steady=0.5)
"""Short windows; the bench raises the margins to its host-latency floor (`with_margins`)."""
KINDS = ["position_start", "static_start", "static_end", "rotate_start", "rotate_end",
         "position_done"]


class BenchSession:
    """A bench, its drivers, a session writer and a running recorder, for one test."""

    def __init__(self, path, imu="serial", technician=None, settings=FAST, axes=None, speed=None,
                 reply=None):
        self.bench = VirtualBench(imu, seed=3, speed=speed, remount_time=1.0).start()
        self.path = path
        self._drivers = self.bench.drivers(reply)
        self.imu, self.table = self._drivers.__enter__()
        self.protocol = RotaryProtocol(self.table, technician or self.bench.technician,
                                       self.bench.clock, self.bench.with_margins(settings),
                                       suggested_axes(3) if axes is None else axes)
        self.writer = SessionWriter.create(
            path, {**self.protocol.metadata(), "unit_serial": "TEST"},
            {"imu": self.bench.stream_spec}, clock=self.bench.clock)
        self.recorder = Recorder(self.writer, self.imu, clock=self.bench.clock).start()
        self.closed = False

    def close(self):
        """Stop everything (a second call does nothing)."""
        if self.closed:
            return
        self.closed = True
        self.recorder.stop()
        self.writer.close()
        self._drivers.__exit__(None, None, None)
        self.bench.close()


@pytest.fixture
def session(tmp_path):
    opened = []

    def open_(**kwargs):
        s = BenchSession(tmp_path / f"s{len(opened)}.h5", **kwargs)
        opened.append(s)
        return s

    yield open_
    for s in opened:
        s.close()


class Interrupting:
    """The real table driver, running `action(reading)` on each read in the middle of the rotating
    window of the `run`-th spin: the table has turned 4 rad since it reached the rate (2 rad of
    the bench's 2 s steady margin at 1 rad/s, then 2 rad into the window)."""

    def __init__(self, table, action, run=1):
        self.table, self.action, self.run = table, action, run
        self.starts, self.at_rate_angle = 0, None

    def __getattr__(self, name):
        return getattr(self.table, name)

    def start(self):
        self.starts += 1
        self.at_rate_angle = None
        return self.table.start()

    def state(self):
        reading = self.table.state()
        if self.starts == self.run and reading.at_rate:
            if self.at_rate_angle is None:
                self.at_rate_angle = reading.angle
            if reading.angle - self.at_rate_angle > 4.0:
                self.action(reading)
        return reading


def wait_for_rest(physics, clock, seconds=10.0):
    end = clock.now() + seconds
    while physics.state().moving and clock.now() < end:
        clock.sleep(0.1)
    return physics.state()


# -------------------------------------------------------------------------------------------------


def test_protocol_records_each_position_in_order_with_windows_the_table_confirms(session):
    s = session()
    s.protocol.run(s.recorder)
    s.close()
    with Session.open(s.path) as f:
        events = [e for e in f.events() if e.position is not None]
        table, stream = f.table(), f.stream("imu")
        reduced = rotary_readings(f)
    assert [(e.position, e.kind) for e in events] == [(j, k) for j in range(3) for k in KINDS]
    windows = position_windows(events)
    for w in windows.values():
        static = (table.time > w["static"][0]) & (table.time < w["static"][1])
        rotating = (table.time > w["rotating"][0]) & (table.time < w["rotating"][1])
        # polled during the window (how often depends on the host: 3 s are 75 ms of wall)
        assert static.sum() >= 2 and not table.flag("moving")[static].any()
        assert np.all(np.abs(table.rate[rotating] - 1.0) < FAST.tolerance)
        swept = np.interp(w["rotating"][1], table.time, table.angle) - np.interp(
            w["rotating"][0], table.time, table.angle)
        assert swept >= 2 * np.pi  # at least the one whole turn asked for
        assert w["static"][1] - w["static"][0] >= FAST.static
    assert not table.flag("running")[-1]
    # Eq. (18): the reading of position j is a^T (c u_j) within a few noise sigmas
    truth = s.bench.truth()
    expected = truth.a.T @ truth.v(1.0)
    assert reduced.M.shape == (12, 3) and np.all(reduced.revolutions == 1)
    assert np.all(np.abs(reduced.M - expected) < 6 * reduced.sigma)
    assert len(stream.seq) > 0.9 * windows[2]["rotating"][1] * 200  # the whole session streamed


def test_the_technician_mounts_the_suggested_axes(session):
    s = session()
    s.protocol.run(s.recorder)
    felt = s.bench.truth().orientations[:, :, 2]
    angle = np.degrees(np.arccos(np.clip(np.sum(felt * suggested_axes(3), axis=1), -1, 1)))
    assert np.all(angle < 5 * 0.5 * np.sqrt(2))  # placement error 0.5 deg per axis
    assert len(s.bench.technician.messages) >= 3


@pytest.mark.parametrize("failure", ["interrupt", "table_fault"])  # unplug: tests/test_faults.py
def test_any_failure_mid_rotation_stops_the_table_and_leaves_a_consistent_session(session, failure):
    s = session(axes=suggested_axes(3))
    physics = s.bench.table
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    fired = []

    def act(reading):
        if fired:
            return
        fired.append(reading)
        if failure == "interrupt":
            raise KeyboardInterrupt
        s.bench.table_twin.inject("exception", count=1, code=4)

    s.protocol.table = Interrupting(s.table, act, run=2)  # position 1 completes first
    expected = {"interrupt": KeyboardInterrupt, "table_fault": TableFault}[failure]
    with pytest.raises(expected):
        s.protocol.run(s.recorder)
    assert fired and fired[0].running
    assert not physics.state().running  # stopped at once ...
    assert wait_for_rest(physics, s.bench.clock).rate == 0.0  # ... and comes to rest
    s.close()
    with Session.open(s.path) as f:
        assert f.closed_cleanly
        events = f.events()
        assert f.last_completed_position() == 0
        abort = [e for e in events if e.kind == "abort"]
        assert len(abort) == 1 and abort[0].position == 1 and abort[0].detail["state"] == "rotating"
        assert set(position_windows(events)) == {0}


def test_resume_after_an_abort_records_the_position_again(session):
    s = session()
    calls = []

    def interrupt_once(reading):
        if not calls:
            calls.append(reading)
            raise KeyboardInterrupt

    real = s.protocol.table
    s.protocol.table = Interrupting(real, interrupt_once, run=1)
    with pytest.raises(KeyboardInterrupt):
        s.protocol.run(s.recorder)
    s.protocol.table = real
    s.protocol.run(s.recorder, first=0)
    s.close()
    with Session.open(s.path) as f:
        reduced = rotary_readings(f)
        kinds = [e.kind for e in f.events()]
    assert kinds.count("abort") == 1 and kinds.count("position_done") == 3
    assert reduced.M.shape == (12, 3)
    truth = s.bench.truth()  # the technician mounted position 1 twice: the last one counts
    expected = truth.a.T @ truth.v(1.0)[:, 1:]
    assert np.all(np.abs(reduced.M - expected) < 6 * reduced.sigma)


class PausingTechnician(SimulatedTechnician):
    """Silences the IMU for `seconds` when the static window of the first position starts."""

    def __init__(self, bench, seconds):
        super().__init__(bench.mounted, bench.clock, 1.0, 0.5, 0)
        self.bench, self.seconds = bench, seconds

    def prompt(self, text):
        super().prompt(text)
        if text.startswith("position 1: static"):
            self.bench.imu_twin.pause(self.seconds)


def test_samples_lost_in_a_window_are_refused_at_reduction(session):
    s = session()
    s.protocol.operator = PausingTechnician(s.bench, 1.0)  # 1 s of 3 s lost
    s.protocol.axes = suggested_axes(1)
    s.protocol.run(s.recorder)
    s.close()
    with Session.open(s.path) as f, pytest.raises(CalibrationInputError,
                                                  match="position 1: the static window"):
        rotary_readings(f)


def test_a_silent_imu_aborts_the_session(session):
    s = session()
    s.recorder.busy_grace = 0.2  # wall seconds: 10 s of silence on the clock is 0.25 s at 40x
    s.protocol.operator = PausingTechnician(s.bench, 60.0)
    with pytest.raises(RecordingError, match="no IMU sample"):
        s.protocol.run(s.recorder)
    assert not s.bench.table.state().running


def test_a_table_that_never_reaches_the_rate_times_out_and_stops(session):
    slow = RotarySettings(rate=1.0, revolutions=1, static=1.0, rest=0.5, guard=0.5, steady=0.5,
                          tolerance=1e-9, timeout=5.0)  # tighter than the table's encoder noise
    s = session(settings=slow)
    with pytest.raises(ProtocolError, match="timed out after 5 s waiting for the table to reach"):
        s.protocol.run(s.recorder)
    assert not s.bench.table.state().running


# ------------------------------------------------------------------------ pure parts, no devices


def test_suggested_axes_are_unit_spread_and_isotropic():
    for n in (6, 12, 20, 30):
        u = suggested_axes(n)
        assert u.shape == (n, 3) and np.allclose(np.linalg.norm(u, axis=1), 1)
        # isotropic: sum u u^T close to n/3 I, so every direction is excited about equally
        eig = np.linalg.eigvalsh(u.T @ u)
        assert eig.min() > 0.8 * n / 3 and eig.max() < 1.2 * n / 3
    cos = suggested_axes(20) @ suggested_axes(20).T
    nearest = np.degrees(np.arccos(np.max(cos - 2 * np.eye(20), axis=1)))
    assert nearest.min() > 30  # 20 points on a sphere: the dodecahedron's spacing is 41.8 deg
    with pytest.raises(ValueError):
        suggested_axes(0)


@pytest.mark.parametrize("axis", [(0, 0, 1), (0, 0, -1), (1, 0, 0), (0.3, -0.4, 0.866)])
def test_mounting_is_a_rotation_putting_the_axis_up_the_table(axis):
    r = mounting(axis)
    assert np.allclose(r.T @ r, np.eye(3)) and np.isclose(np.linalg.det(r), 1)
    assert np.allclose(r[:, 2], np.asarray(axis) / np.linalg.norm(axis))


def test_sample_times_undo_the_arrival_delays():
    rng = np.random.default_rng(0)
    seq = np.arange(1000, 3000)
    true = 12.5 + seq / 200.0
    delay = np.repeat(rng.exponential(0.05, 200), 10)  # blocks of 10 share one read
    delay[517] = 0.0  # one sample read at once
    arrival = np.maximum.accumulate(true + delay)
    assert np.allclose(sample_times(seq, arrival, 200.0), true)


def test_position_windows_keep_completed_positions_and_the_last_run():
    def run(j, t, done=True):
        kinds = KINDS if done else KINDS[:4]
        return [Event(t + i, j, k, {}) for i, k in enumerate(kinds)]

    events = run(0, 0) + run(1, 10, done=False) + [Event(14, 1, "abort", {})] + run(1, 20)
    events += run(2, 30, done=False)
    w = position_windows(events)
    assert set(w) == {0, 1}
    assert w[1] == {"static": (21, 22), "rotating": (23, 24)}


def test_settings_are_checked():
    with pytest.raises(ValueError, match="non-zero"):
        RotarySettings(rate=0.0)
    with pytest.raises(ValueError, match="revolutions"):
        RotarySettings(revolutions=0)
    with pytest.raises(ValueError, match="static"):
        RotarySettings(static=-1)


def test_console_operator_reads_the_technicians_answers():
    out = io.StringIO()
    op = ConsoleOperator(io.StringIO("\nmaybe\nY\nn\n"), out)
    op.wait(Instruction("turn the unit"))
    assert op.confirm("ready?") is True
    assert op.confirm("again?") is False
    assert "turn the unit" in out.getvalue() and "please answer y or n" in out.getvalue()
    with pytest.raises(OperatorAbort):
        op.wait(Instruction("one more"))


def test_recorded_sample_times_match_the_instants_the_twin_sampled(session):
    s = session()
    twin = s.bench.imu_twin
    s.bench.clock.sleep(20.0)
    s.recorder.drain(s.bench.clock.now(), stale=5.0)
    s.close()
    with Session.open(s.path) as f:
        stream = f.stream("imu")
    assert len(stream.seq) > 0.9 * 20 * 200
    t = sample_times(stream.seq, stream.host_time, 200.0)
    # one common offset for all samples (sample times from seq), and it is the delay of the least
    # delayed of thousands of samples: in lockstep at most a step of the clock (well under 1.6 s)
    late = t - twin.time_of(stream.seq)
    assert np.ptp(late) < 1e-9 and 0 <= late[0] < 1.6


def test_drain_gives_up_when_samples_stop_coming(session):
    # the lag guard reads the wall clock: only a real-time bench can lag (here 40x)
    s = session(speed=40.0)
    s.recorder.drain_timeout = 0.3
    s.recorder.busy_grace = 0.2
    s.bench.imu_twin.pause(1e6)
    with pytest.raises(RecordingError, match="lag"):
        s.recorder.drain(s.bench.clock.now() + 1e5, stale=np.inf)
    s.recorder.drain_timeout = 600.0  # the silence guard alone: 5 s of the bench's clock
    with pytest.raises(RecordingError, match="no IMU sample for"):
        s.recorder.drain(s.bench.clock.now() + 1e5, stale=5.0)
