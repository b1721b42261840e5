"""The serial driver against its pseudo-terminal twin: exact samples, faults, unplug, reconnect.

The twin streams at 2 kHz of simulated time. Tests whose verdicts count frames or sample numbers
run in lockstep (`drivers.clock.SteppedClock`): on a scaled wall clock a starved reader leaves
bytes unread and the twin loses the frames due as OVERFLOW (loaded runs saw 38 CRC failures of
the 50 expected, and 4 of 200 frames PAUSED); the unplug test, which waits for the port to
close, and the twins' own refusals keep a ScaledClock."""

import numpy as np
import pytest

from drivers.clock import ScaledClock, SteppedClock
from drivers.profile import SerialImuProfile
from drivers.samples import SampleBlock
from drivers.serial_imu import DeviceLostError, SerialImu, SerialPortError
from drivers.twins.serial import PAUSED, SENT, SerialTwin

BINARY = SerialImuProfile.load("imu12_serial")
ASCII = SerialImuProfile.load("imu_ascii")


def source(times):
    """Deterministic full-range counts, a known function of time (microsecond resolution)."""
    n = np.round(np.asarray(times) * 1e6).astype(np.int64)
    return (n[:, None] * 2654435761 + np.arange(12) * 40503) % 2**32 - 2**31


def small_source(times):
    """Six channels of small counts for the ASCII twin."""
    n = np.round(np.asarray(times) * 1e3).astype(np.int64)
    return (n[:, None] * 37 + np.arange(6) * 1001) % 40000 - 20000


def read_until(imu, last_seq, limit=5.0):
    """Blocks until a sample with seq >= last_seq arrived (or `limit` clock seconds of no data)."""
    blocks = []
    while not blocks or blocks[-1].seq[-1] < last_seq:
        block = imu.read_block(timeout=limit)
        assert block is not None, "the twin stopped streaming"
        blocks.append(block)
    return SampleBlock.concat(blocks)


def intact_between(twin, first, last):
    seq, fate = twin.log()
    return seq[(fate == SENT) & (seq >= first) & (seq <= last)]


def test_stream_with_faults_every_intact_frame_exact():
    clock = SteppedClock(step=0.1)
    twin = SerialTwin(BINARY, source, clock=clock, corrupt=0.02, drop=0.01, seed=1,
                      max_lag=np.inf)
    with twin, SerialImu(twin.port, BINARY, clock=clock) as imu:
        got = read_until(imu, 6000, limit=30.0)
    assert np.array_equal(got.counts, source(twin.time_of(got.seq)))  # no false accept
    assert np.all(np.diff(got.seq) > 0)
    intact = intact_between(twin, got.seq[0], got.seq[-1])
    assert np.setdiff1d(intact, got.seq).size == 0  # every intact frame recovered
    assert imu.stats.dropped == got.seq[-1] - got.seq[0] + 1 - len(got)
    assert imu.stats.crc_failures > 50 and imu.stats.gaps > 50
    device_steps = np.diff(got.device_time) * BINARY.imu.rate_hz
    assert np.allclose(device_steps, np.diff(got.seq), atol=0.01)


def test_pause_loses_the_frames_due_and_the_stream_resumes():
    clock = SteppedClock(step=0.1)
    twin = SerialTwin(BINARY, source, clock=clock, seed=2, max_lag=np.inf)
    with twin, SerialImu(twin.port, BINARY, clock=clock) as imu:
        read_until(imu, 200, limit=30.0)
        twin.pause(0.1)
        got = read_until(imu, 1200, limit=30.0)
    seq, fate = twin.log()
    paused = seq[fate == PAUSED]
    assert len(paused) == pytest.approx(200, abs=1)  # 0.1 s at 2 kHz
    assert np.intersect1d(paused, got.seq).size == 0
    assert np.setdiff1d(intact_between(twin, got.seq[0], got.seq[-1]), got.seq).size == 0
    assert imu.stats.dropped >= len(paused)


def test_unplug_names_the_port_keeps_samples_and_reconnects():
    clock = ScaledClock(speed=10)
    twin = SerialTwin(BINARY, source, clock=clock, seed=3)
    imu = SerialImu(twin.port, BINARY, clock=clock)
    blocks = []
    with twin:
        imu.open()
        blocks.append(read_until(imu, 500))
        twin.unplug()  # mid-stream
        with pytest.raises(DeviceLostError) as info:
            while True:
                block = imu.read_block(timeout=1.0)
                if block is not None:
                    blocks.append(block)
        assert twin.port in str(info.value) and info.value.port == twin.port
        before = SampleBlock.concat(blocks)
        # every sample before the unplug: consecutive, exact, up to the last frame fully written
        seq, fate = twin.log()
        last_written = seq[fate == SENT].max()
        assert np.setdiff1d(intact_between(twin, before.seq[0], before.seq[-1]),
                            before.seq).size == 0
        assert np.array_equal(before.counts, source(twin.time_of(before.seq)))
        assert before.seq[-1] <= last_written
        with pytest.raises(SerialPortError, match="not open"):
            imu.read_block()
        twin.plug()
        imu.open()
        after = read_until(imu, last_written + 400)
        imu.close()
    assert after.seq[0] > before.seq[-1]
    assert np.array_equal(after.counts, source(twin.time_of(after.seq)))
    assert imu.connections == 2


def test_ascii_device_through_the_pty():
    clock = SteppedClock(step=0.1)
    twin = SerialTwin(ASCII, small_source, clock=clock, seed=5, max_lag=np.inf)
    with twin, SerialImu(twin.port, ASCII, clock=clock) as imu:
        got = SampleBlock.concat([imu.read_block(timeout=30.0) for _ in range(5)])
    # ASCII carries no sequence number: match samples to frames by their timestamp (ms column)
    frame = np.round((got.device_time - twin.start_time) * twin.rate_hz).astype(np.int64)
    assert np.array_equal(got.counts, small_source(twin.time_of(frame)))
    assert np.array_equal(frame, np.arange(frame[0], frame[0] + len(frame)))


def test_open_errors_name_the_port(tmp_path):
    missing = str(tmp_path / "ttyUSB9")
    with pytest.raises(SerialPortError, match="ttyUSB9.*plugged in"):
        SerialImu(missing, BINARY).open()
    twin = SerialTwin(BINARY, source)
    try:
        with SerialImu(twin.port, BINARY), \
                pytest.raises(SerialPortError, match="no other program holds the port"):
            SerialImu(twin.port, BINARY).open()  # exclusive=True
    finally:
        twin.stop()


def test_twin_refuses_a_source_of_the_wrong_shape():
    clock = ScaledClock(speed=10)
    twin = SerialTwin(BINARY, lambda t: np.zeros((len(t), 3), np.int64), clock=clock)
    twin.start()
    clock.sleep(0.05)
    with pytest.raises(ValueError, match=r"shape \(\d+, 12\)"):
        twin.stop()


def test_duplicated_frames_are_dropped_and_counted_never_a_forward_jump():
    """At least 300 frames sent twice byte for byte (a CRC-valid repeat): each is dropped and
    counted; the numbering has no jump (without the check each became +65536: 32.8 s at 2 kHz).
    The twins here never skip frames when they fall behind (max_lag inf: flow control only)."""
    clock = SteppedClock(step=0.1)
    twin = SerialTwin(BINARY, source, clock=clock, seed=4, duplicate=0.05, max_lag=np.inf)
    with twin, SerialImu(twin.port, BINARY, clock=clock) as imu:
        got = read_until(imu, 8000, limit=30.0)
    repeated = np.array(twin.duplicated)
    assert np.count_nonzero(repeated < got.seq[-1]) >= 300
    np.testing.assert_array_equal(got.seq, np.arange(got.seq[0], got.seq[-1] + 1))
    assert np.array_equal(got.counts, source(twin.time_of(got.seq)))
    assert imu.stats.gaps == 0 and imu.stats.restarts == 0
    # repeats of frames sent before the port was first read are never seen: count from seq[0]
    seen = (repeated >= got.seq[0]) & (repeated < got.seq[-1])
    sent_twice = np.count_nonzero(repeated <= got.seq[-1])
    assert np.count_nonzero(seen) <= imu.stats.duplicates <= sent_twice


def test_a_restarted_device_starts_a_new_segment_and_earlier_samples_keep_their_times():
    """The device resets mid-stream (numbering and device time from 0): the samples after it are
    a new segment (numbering goes back, not a forward jump), those before keep their numbers, and
    the timeline gives both sides their true sampling instants."""
    from station.reduce.timeline import sample_times

    clock = SteppedClock(step=0.1)  # lockstep: each frame read within one step of its instant
    twin = SerialTwin(BINARY, source, clock=clock, seed=6, max_lag=np.inf)
    with twin, SerialImu(twin.port, BINARY, clock=clock) as imu:
        before = read_until(imu, 3000, limit=30.0)
        twin.restart()
        blocks, after = [before], 0
        while after < 3000:  # samples of the new segment (a read block may hold hundreds)
            blocks.append(imu.read_block(timeout=30.0))
            assert blocks[-1] is not None, "the twin stopped streaming"
            seq = np.concatenate([b.seq for b in blocks])
            back = np.flatnonzero(np.diff(seq) <= 0)
            after = len(seq) - back[0] - 1 if len(back) else 0
            assert len(seq) < 200_000, "no restart seen in the stream"
    got = SampleBlock.concat(blocks)
    cut = int(np.flatnonzero(np.diff(got.seq) <= 0)[0]) + 1  # the one place it does not increase
    assert np.all(np.diff(got.seq[cut:]) == 1) and np.all(np.diff(got.seq[:cut]) == 1)
    assert imu.stats.restarts == 1 and imu.stats.gaps == 0
    origin = twin.restarts[0]
    frames = np.r_[got.seq[:cut], origin + got.seq[cut:] - got.seq[cut]]  # the twin's numbering
    assert got.seq[cut] == 0 and got.device_time[cut] == 0.0  # the device's own 0
    assert np.array_equal(got.counts, source(twin.time_of(frames)))
    rate = BINARY.imu.rate_hz
    times = sample_times(got.seq, got.host_time, rate)
    np.testing.assert_array_equal(times[:cut], sample_times(got.seq[:cut], got.host_time[:cut],
                                                            rate))
    # each side's instants: the true ones, late by the least arrival latency (less than the
    # clock's step: the twin writes at each step what fell due since the last one, and time
    # stands still until the reader has taken it)
    late = times - twin.time_of(frames)
    assert np.all((late[:cut] >= -1e-9) & (late[:cut] < clock.step))
    assert np.all((late[cut:] >= -1e-9) & (late[cut:] < clock.step))


def test_the_recorder_follows_a_restarted_device_into_the_session(tmp_path):
    """Recording through a device restart: `drain` sees the newest samples at once (it waited for
    the restarted numbering to catch up with the old one), and the file holds one new segment."""
    from station.acquire.recorder import Recorder
    from station.session import Session, SessionWriter, StreamSpec

    clock = SteppedClock(step=0.1)  # lockstep: the same stream however busy the host
    spec = StreamSpec.from_profile(BINARY.imu)
    twin = SerialTwin(BINARY, source, clock=clock, seed=8, max_lag=np.inf)
    with twin, SerialImu(twin.port, BINARY, clock=clock) as imu, \
            SessionWriter.create(tmp_path / "s.h5", {"protocol": "rotary", "unit_serial": "T"},
                                 {"imu": spec}, clock=clock) as writer, \
            Recorder(writer, imu, clock=clock, drain_timeout=2.0) as recorder:
        clock.sleep(40.0)
        recorder.drain(clock.now(), stale=10.0)
        twin.restart()
        # the old numbering is 40 s ahead: had `drain` taken the restart for the old count, it
        # would wait for it to catch up and fail after `stale` s of clock
        recorder.drain(clock.now() + 1.0, stale=10.0)
    with Session.open(tmp_path / "s.h5") as s:
        seq = s.stream("imu").seq
    assert np.count_nonzero(np.diff(seq) <= 0) == 1 == imu.stats.restarts
    assert np.count_nonzero(np.diff(seq) > 1) == 0
