"""Faults during a rotary session on the virtual bench: an IMU unplugged in the middle of a window
(the window is discarded and recorded again after the reconnection), a Modbus timeout (table
stopped, session paused, going on or ending as the operator says). Nothing already recorded is lost
and the twin's table is stopped after every fault.

The bench runs in lockstep time (its default; it ran at 20x before): the serial twin computes a
frame's data when it sends it, with the table's state of that moment, and in lockstep that moment is
the sample's own instant on any host; at a real-time 20x a twin lagging behind on a loaded host put
rotation into samples taken before the table started."""

import logging

import numpy as np
import pytest
from test_rotary_protocol import FAST, Interrupting, session  # noqa: F401 - fixture

from drivers.rotary_table import TableLinkError
from drivers.twins.serial import SENT, UNPLUGGED
from station.acquire.operator import OperatorAbort, SimulatedTechnician
from station.protocols.rotary import ProtocolError, RotarySettings, SessionPaused
from station.reduce.rotary import position_windows, rotary_readings
from station.session import Session


@pytest.fixture(autouse=True)
def quiet_pymodbus():
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)


def once(action):
    """An `Interrupting` action that runs `action()` the first time only."""
    fired = []

    def act(reading):
        if not fired:
            fired.append(reading)
            action()
    act.fired = fired
    return act


def recorded(path):
    with Session.open(path) as f:
        return f.events(), f.table(), f.stream("imu"), rotary_readings(f), f.closed_cleanly


def table_after(table, t):
    """The first recorded table state after clock time t."""
    return np.flatnonzero(table.time > t)[0]


def check_readings(s, events, reduced):
    """Eq. (18) readings of every position within 6 sigma of the truth a^T (c u_j), u_j the
    table axis of the position's last mounting (restarts do not re-mount)."""
    mounts = [e.position for e in events
              if e.kind == "position_start" and not e.detail.get("again")]
    last = [max(i for i, j in enumerate(mounts) if j == p) for p in range(max(mounts) + 1)]
    mounted = np.array(s.protocol.operator.orientations)[last]  # what the technician really did
    expected = s.bench.truth().a.T @ mounted[:, :, 2].T
    assert reduced.M.shape == expected.shape
    assert np.all(np.abs(reduced.M - expected) < 6 * reduced.sigma)


@pytest.mark.parametrize("window", ["static", "rotating"])
def test_imu_unplugged_mid_window_is_recorded_again_after_reconnection(session, window):  # noqa: F811 - the fixture
    s = session()
    twin = s.bench.imu_twin
    act = once(twin.unplug)
    if window == "rotating":
        s.protocol.table = Interrupting(s.table, act, run=2)
    else:
        technician = s.bench.technician
        prompt = technician.prompt

        def unplug_in_static(text):
            prompt(text)
            if text.startswith("position 2: static"):
                s.bench.clock.sleep(1.5)  # half of the 3 s window
                act(None)
        technician.prompt = unplug_in_static
    s.protocol.run(s.recorder)
    physics = s.bench.table
    assert act.fired and not physics.state().running
    s.close()
    events, table, stream, reduced, clean = recorded(s.path)
    assert clean
    kinds = [(e.position, e.kind) for e in events if e.position == 1]
    fault = next(e for e in events if e.kind == "fault")
    assert fault.position == 1 and fault.detail["device"] == "imu"
    assert fault.detail["state"] == ("rotating" if window == "rotating" else "static")
    assert kinds.count((1, "position_start")) == 2 and kinds.count((1, "position_done")) == 1
    assert kinds.index((1, "fault")) < kinds.index((1, "resume")) < len(kinds) - 6
    # the table was stopped at once (the first state read after the fault) and the discarded
    # window is not used: both windows of position 1 start after the reconnection
    assert not table.flag("running")[table_after(table, fault.time)]
    resume = next(e for e in events if e.kind == "resume")
    w = position_windows(events)[1]
    assert w["static"][0] > resume.time and w["rotating"][0] > resume.time
    # every frame the twin sent before the unplug is in the file, except the head sent before the
    # driver opened the port (pyserial flushes input on open) and the tail still in flight (pty
    # buffers) when the cable was pulled - it dies with it, as on a real unplug; and the session
    # goes on after it
    assert np.all(np.diff(stream.seq) > 0)
    seq, fate = twin.log()
    sent = seq[(fate == SENT) & (seq < seq[fate == UNPLUGGED].min())]
    kept = stream.seq[stream.host_time <= fault.time]
    missing = np.setdiff1d(sent, kept)
    assert np.all((missing < kept.min()) | (missing > kept.max()))  # nothing lost in between
    assert kept.size > 0.9 * sent.size
    assert (stream.host_time > resume.time).sum() > 0.9 * 200 * 2 * (FAST.static + 2 * np.pi)
    check_readings(s, events, reduced)


def test_an_imu_that_stays_unplugged_ends_the_session_with_the_table_stopped(session):  # noqa: F811 - the fixture
    s = session(settings=RotarySettings(**{**vars(FAST), "retries": 1}))
    s.bench.technician.fixes_cables = False
    s.protocol.table = Interrupting(s.table, once(s.bench.imu_twin.unplug), run=1)
    with pytest.raises(ProtocolError, match="the IMU did not come back after 2 reconnections"):
        s.protocol.run(s.recorder)
    assert not s.bench.table.state().running
    assert sum("Reconnect the IMU" in m for m in s.bench.technician.messages) == 2
    s.close()
    with Session.open(s.path) as f:
        kinds = [e.kind for e in f.events()]
        assert f.last_completed_position() is None and f.closed_cleanly
    assert kinds[-4:] == ["fault", "resume", "resume", "abort"]


SILENT_TABLE_REPLY = 10.0
"""Wall seconds the table driver waits for each reply in the tests whose table stops answering:
each unanswered try costs that much, three of them a timeout (the lockstep default, 30 s, made
each such test last 90 s). A reply on the loopback takes milliseconds, a second on a very busy
host: ten is still a wide margin for the tries that are answered."""


class Declining(SimulatedTechnician):
    """A technician who answers 'no' to every question."""

    def confirm(self, question):
        self.prompt(question)
        return False


@pytest.mark.parametrize("answer", ["go on", "stop"])
def test_modbus_timeout_stops_the_table_and_pauses_the_session(session, answer):  # noqa: F811 - the fixture
    s = session(reply=SILENT_TABLE_REPLY)
    if answer == "stop":
        b = s.bench
        s.protocol.operator = Declining(b.mounted, b.clock, 1.0, 0.5, 0)
    # the driver tries 3 times (retries=2): 3 unanswered requests are a timeout, the 4th answers
    act = once(lambda: s.bench.table_twin.inject("drop", count=3))
    s.protocol.table = Interrupting(s.table, act, run=2)
    if answer == "stop":
        with pytest.raises(SessionPaused, match="paused.*station resume SESSION"):
            s.protocol.run(s.recorder)
        assert not s.bench.table.state().running
        s.protocol.table = s.table  # the operator fixed the table and resumes the session
        s.protocol.run(s.recorder, first=s.writer.last_completed_position + 1)
    else:
        s.protocol.run(s.recorder)
    assert act.fired and not s.bench.table.state().running
    s.close()
    events, table, stream, reduced, clean = recorded(s.path)
    assert clean
    pause = next(e for e in events if e.kind == "pause")
    assert pause.position == 1 and pause.detail["table_stopped"] is True
    assert f"rotary table at 127.0.0.1:{s.bench.table_twin.port}: no reply" in pause.detail["error"]
    assert not table.flag("running")[table_after(table, pause.time)]
    kinds = [e.kind for e in events]
    assert "abort" not in kinds and kinds.count("position_done") == 3
    assert kinds.count("resume") == (1 if answer == "go on" else 0)
    # the IMU went on streaming through the pause: not one sample missing
    assert np.all(np.diff(stream.seq) == 1)
    check_readings(s, events, reduced)


class ClosedInput(SimulatedTechnician):
    """A technician whose console input is closed: every question ends the session."""

    def confirm(self, question):
        raise OperatorAbort("the operator closed the input; session aborted")


def test_with_the_input_closed_the_device_cause_comes_first(session):  # noqa: F811 - the fixture
    """A table that stops answering while nobody can answer: the abort names the table's fault
    first, then the closed input (it said only "the operator closed the input" before)."""
    s = session(reply=SILENT_TABLE_REPLY)
    b = s.bench
    s.protocol.operator = ClosedInput(b.mounted, b.clock, 1.0, 0.5, 0)
    act = once(lambda: s.bench.table_twin.inject("drop", count=3))
    s.protocol.table = Interrupting(s.table, act, run=2)
    with pytest.raises(OperatorAbort) as ended:
        s.protocol.run(s.recorder)
    assert str(ended.value).startswith("the rotary table stopped answering during position 2 (")
    assert str(ended.value).endswith("; then the operator closed the input; session aborted")
    assert not s.bench.table.state().running
    s.close()


def abort_of(path):
    with Session.open(path) as f:
        return next(e for e in f.events() if e.kind == "abort")


def test_a_table_connection_reset_mid_rotation_aborts_naming_the_table_and_the_stop(session):  # noqa: F811 - the fixture
    """Resets on every try of a table read (the driver's 3): a TableLinkError, not a raw
    ConnectionResetError; the emergency stop gets through and the abort event says so."""
    s = session()
    act = once(lambda: s.bench.table_twin.inject("reset", count=3))
    s.protocol.table = Interrupting(s.table, act, run=1)
    with pytest.raises(TableLinkError, match="connection reset by the controller") as caught:
        s.protocol.run(s.recorder)
    assert caught.value.table_stopped is True and not s.bench.table.state().running
    s.close()
    abort = abort_of(s.path)
    where = f"rotary table at 127.0.0.1:{s.bench.table_twin.port}"
    assert abort.detail["devices"] == [where] and abort.detail["table_stopped"] is True
    assert abort.detail["error"].startswith(f"TableLinkError: {where}: connection reset")


def test_the_whole_bench_lost_mid_rotation_names_both_devices_and_the_unstopped_table(session):  # noqa: F811 - the fixture
    """IMU unplugged and table controller dead at once: the error names both devices and says the
    table could not be stopped (it keeps turning: the twin's physics runs on)."""
    s = session(settings=RotarySettings(**{**vars(FAST), "retries": 0}))
    s.bench.technician.fixes_cables = False
    s.table.stop_patience = 0.2

    def lose_everything():
        s.bench.imu_twin.unplug()
        s.bench.table_twin.die()
    s.protocol.table = Interrupting(s.table, once(lose_everything), run=1)
    with pytest.raises(Exception) as caught:  # noqa: PT011 - which device is noticed first varies
        s.protocol.run(s.recorder)
    words = "; ".join([str(caught.value), *caught.value.__notes__])
    port = s.bench.imu_twin.port
    assert f"rotary table at 127.0.0.1:{s.bench.table_twin.port}" in words
    assert f"IMU on {port}" in words or port in words
    assert "stop the table by hand" in words and caught.value.table_stopped is False
    assert s.bench.table.state().running
    s.closed = True
    s.recorder.stop()
    s.writer.close()
    s.imu.close()
    s.table.close()
    s.bench.close()
    abort = abort_of(s.path)
    assert abort.detail["table_stopped"] is False and len(abort.detail["devices"]) == 2


def test_the_stream_tap_a_session_records_through_reopens_a_lost_imu():
    """`continue_session` records through a StreamTap: `Recorder.reconnect` reopens the IMU
    through it (it once had no `open`, and every reconnection failed with an AttributeError)."""
    import time

    from station.protocols.still import StreamTap
    from station.twin.hand_bench import HandBench

    def blocks(tap, until=5.0):
        deadline = time.monotonic() + until
        while time.monotonic() < deadline:
            block = tap.read_block()
            if block is not None and len(block):
                return block
            time.sleep(0.01)
        return None

    with HandBench(seed=1, speed=10.0) as bench, bench.driver() as imu:
        spec = bench.stream_spec
        tap = StreamTap(imu, spec.rate_hz, spec.counts_per_unit)
        assert blocks(tap) is not None
        bench.twin.unplug()
        with pytest.raises(ConnectionError):
            for _ in range(500):  # what was in flight, then the loss
                tap.read_block()
                time.sleep(0.01)
        bench.twin.plug()
        assert tap.open() is tap
        block = blocks(tap)
        assert block is not None and len(block) > 0
