"""CAN IMU driver against its virtual twin on a python-can virtual bus (no mocks)."""

import dataclasses
import os
import time
import uuid

import can
import numpy as np
import pytest

from drivers.can_imu import CanBusError, CanImu, CanProfile, replay
from drivers.twins.can import CanImuTwin

PROFILE = CanProfile.load("imu12_can")
M = len(PROFILE.imu.channels)


def pattern(k: np.ndarray) -> np.ndarray:
    """Known counts of sample number k: sweeps the whole 14-bit signed range of every channel."""
    return (k[:, None] * 7919 + 1013 * np.arange(M)) % 16384 - 8192


def counting_source(mirrored: bool = False):
    """A source that returns `pattern` of the running sample number, whatever the times
    (`mirrored`: -1 - pattern, another unit's counts in the same range)."""
    state = {"k": 0}

    def source(times):
        k = state["k"] + np.arange(len(times))
        state["k"] += len(times)
        return -1 - pattern(k) if mirrored else pattern(k)

    return source


def virtual(name: str) -> dict:
    """The `can.Bus` keywords of virtual channel `name` (the driver opens its own bus)."""
    return {"interface": "virtual", "channel": name}


def channel() -> str:
    """A unique virtual channel name; it ends in a letter because the BLF writer turns trailing
    digits into a 16-bit channel number and fails on larger ones."""
    return f"can-test-{uuid.uuid4().hex}-bus"


def read_all(imu: CanImu, expected: int, timeout: float = 10.0):
    """Blocks until `expected` samples arrived (or timeout); returns them as one list of blocks."""
    blocks, got, deadline = [], 0, time.monotonic() + timeout
    while got < expected and time.monotonic() < deadline:
        block = imu.read_block(timeout=0.05)
        if block is not None:
            blocks.append(block)
            got += len(block)
    return blocks


def test_2khz_three_frames_per_sample_decodes_and_replays_exactly(tmp_path):
    name, n, first = channel(), 1000, 200  # 0.5 s at 2 kHz; the 8-bit counter wraps 4 times
    log = tmp_path / "raw.blf"
    twin = CanImuTwin(name, PROFILE, counting_source(), samples=n, first_seq=first)
    with CanImu(virtual(name), PROFILE, log_path=log) as imu, twin:
        assert twin.wait(timeout=120)
        assert twin.error is None
        blocks = read_all(imu, n)
    stats = imu.stats
    got = np.concatenate([b.counts for b in blocks])
    seq = np.concatenate([b.seq for b in blocks])
    np.testing.assert_array_equal(seq, np.arange(first, first + n))
    np.testing.assert_array_equal(got, pattern(np.arange(n)))
    assert (stats.frames, stats.samples, stats.errors) == (3 * n, n, 0)
    assert (stats.incomplete, stats.gaps, stats.dropped) == (0, 0, 0)
    host = np.concatenate([b.host_time for b in blocks])
    assert np.all(np.diff(host) >= 0) and np.all(np.isnan(blocks[0].device_time))

    replayed, replay_stats = replay(log, PROFILE)
    np.testing.assert_array_equal(replayed.counts, got)
    np.testing.assert_array_equal(replayed.seq, seq)
    assert replayed.channels == PROFILE.imu.channels
    assert (replay_stats.frames, replay_stats.samples) == (3 * n, n)


def test_lost_frames_are_counted_and_foreign_frames_ignored(tmp_path):
    name, n = channel(), 200
    drop = {(10, 1), (20, 0), (30, 0), (30, 1), (30, 2)}  # 10, 20 incomplete; 30 entirely lost
    intruder = can.Bus(interface="virtual", channel=name)
    try:
        with CanImu(virtual(name), PROFILE) as imu:
            with CanImuTwin(name, PROFILE, counting_source(), samples=n, drop=drop) as twin:
                for intrusion in [  # unknown id, short known frame, remote frame, extended id
                    {"arbitration_id": 0x7FF, "data": b"\x01\x02"},
                    {"arbitration_id": 0x180, "data": b"\x01"},
                    {"arbitration_id": 0x181, "is_remote_frame": True, "dlc": 8},
                    {"arbitration_id": 0x180, "data": bytes(8), "is_extended_id": True},
                ]:
                    intruder.send(can.Message(**({"is_extended_id": False} | intrusion)))
                assert twin.wait(timeout=120)
                blocks = read_all(imu, n - 3)
            stats = imu.stats
    finally:
        intruder.shutdown()
    seq = np.concatenate([b.seq for b in blocks])
    expected_seq = np.setdiff1d(np.arange(n), [10, 20, 30])
    np.testing.assert_array_equal(seq, expected_seq)
    np.testing.assert_array_equal(np.concatenate([b.counts for b in blocks]), pattern(expected_seq))
    assert (stats.incomplete, stats.orphaned, stats.gaps, stats.dropped) == (2, 4, 3, 3)
    assert (stats.unknown, stats.short) == (3, 1)
    assert stats.frames == stats.used + stats.unknown + stats.short + stats.orphaned


def test_two_units_on_one_bus_each_decoded_by_its_id_offset(tmp_path):
    """Two units of one model on one bus, node offsets 0 and 0x10 (ids 0x180-0x182 and
    0x190-0x192): each driver decodes exactly its own unit's samples (another pattern per unit)
    and counts the other's frames as unknown; its raw log replays with its offset."""
    name, n = channel(), 300
    second = dataclasses.replace(PROFILE, can=dataclasses.replace(PROFILE.can, id_offset=0x10))
    log = tmp_path / "second.blf"
    with (CanImu(virtual(name), PROFILE) as first_imu,
          CanImu(virtual(name), second, log_path=log) as second_imu,
          CanImuTwin(name, PROFILE, counting_source(), samples=n) as one,
          CanImuTwin(name, second, counting_source(mirrored=True), samples=n) as two):
        assert one.wait(timeout=120) and two.wait(timeout=120)
        blocks = [read_all(first_imu, n), read_all(second_imu, n)]
    for imu, got, twin in zip((first_imu, second_imu), blocks, (one, two), strict=True):
        np.testing.assert_array_equal(np.concatenate([b.counts for b in got]),
                                      np.array(twin.sent_counts))
        assert (imu.stats.samples, imu.stats.unknown, imu.stats.incomplete) == (n, 3 * n, 0)
    assert not np.array_equal(np.array(one.sent_counts), np.array(two.sent_counts))
    replayed, _ = replay(log, second)
    np.testing.assert_array_equal(replayed.counts, np.array(two.sent_counts))



def test_failing_log_is_counted_and_decoding_goes_on(tmp_path):
    """A log on a full disk (/dev/full) raises inside the listener: counted, samples still come."""
    if not os.path.exists("/dev/full"):
        pytest.skip("needs /dev/full to simulate a full disk")
    log = tmp_path / "raw.log"
    log.symlink_to("/dev/full")
    name, n = channel(), 600
    twin = CanImuTwin(name, PROFILE, counting_source(), samples=n)
    with CanImu(virtual(name), PROFILE, log_path=log) as imu, twin:
        assert twin.wait(timeout=120)
        blocks = read_all(imu, n)
    stats = imu.stats
    assert sum(len(b) for b in blocks) == n
    assert stats.errors >= 1 and "No space" in stats.last_error


def test_read_before_open_says_what_to_do():
    with pytest.raises(CanBusError, match="call open"):
        CanImu(virtual(channel()), PROFILE).read_block()


def test_bus_that_cannot_open_names_the_channel():
    with pytest.raises(CanBusError, match="no-such-interface") as info:
        CanImu({"interface": "no-such-interface", "channel": "x"}, PROFILE).open()
    assert info.value.channel == "no-such-interface:x"


def test_twin_rejects_a_source_of_the_wrong_shape():
    name = channel()
    with CanImuTwin(name, PROFILE, lambda t: np.zeros((len(t), M - 1), int), samples=5) as twin:
        assert twin.wait(timeout=120)
    assert isinstance(twin.error, ValueError) and "shape" in str(twin.error)


def test_duplicated_samples_are_dropped_and_counted_never_a_forward_jump():
    """500 samples sent twice (all their frames repeated): each dropped once and counted; the
    numbering has no jump (without the check each became a +256 jump: 128 ms at 2 kHz)."""
    name, n = channel(), 2000
    twice = set(np.random.default_rng(7).choice(n - 1, size=500, replace=False).tolist())
    twin = CanImuTwin(name, PROFILE, counting_source(), samples=n, duplicate=twice)
    with CanImu(virtual(name), PROFILE) as imu, twin:
        assert twin.wait(timeout=120) and twin.error is None
        blocks = read_all(imu, n)
    seq = np.concatenate([b.seq for b in blocks])
    np.testing.assert_array_equal(seq, np.arange(n))
    np.testing.assert_array_equal(np.concatenate([b.counts for b in blocks]),
                                  pattern(np.arange(n)))
    assert (imu.stats.duplicates, imu.stats.gaps, imu.stats.dropped) == (500, 0, 0)


@pytest.mark.parametrize("first_run", [100, 130, 200, 251, 256 + 77])
def test_a_counter_falling_back_to_0_after_a_reset_is_a_restart_not_a_forward_jump(first_run):
    """The unit resets after `first_run` samples (its 8-bit counter at first_run - 1 mod 256,
    below or above half the range) and counts again from 0: a new segment, counted as a restart
    (a gap of unknown length), never a forward step of 256 - counter samples that would shift the
    instants of every later sample (issue 30: 495 of 500 fuzzed streams were).

    The unit is off for at least 0.1 s: a step forward that the host time since the last sample
    explains (within a quarter, at 2 kHz) is read as an outage of the adapter, and a pause of
    about 64 ms after 130 samples explains the step of 127 (one loaded run found it); from 0.1 s
    on no step of this counter is explained, however much longer a busy host makes the pause."""
    name, second_run = channel(), 120
    with CanImu(virtual(name), PROFILE) as imu:
        for samples in (first_run, second_run):
            with CanImuTwin(name, PROFILE, counting_source(), samples=samples) as twin:
                assert twin.wait(timeout=120) and twin.error is None
            time.sleep(0.1)  # the reset
        blocks = read_all(imu, first_run + second_run)
    seq = np.concatenate([b.seq for b in blocks])
    assert len(seq) == first_run + second_run
    np.testing.assert_array_equal(np.diff(seq[:first_run]), 1)
    np.testing.assert_array_equal(np.diff(seq[first_run:]), 1)
    assert seq[first_run] <= seq[first_run - 1]  # the numbering does not go forward there
    assert (imu.stats.restarts, imu.stats.gaps, imu.stats.dropped) == (1, 0, 0)


def test_a_short_step_forward_is_still_a_gap_of_lost_samples():
    """Samples lost on the bus (a step of max_gap or less) stay a gap with its count, across
    the counter's wrap too: only a step beyond max_gap is a restart."""
    name, n = channel(), 600
    lost = {250, 251, 252, 400}  # 3 samples across the wrap at 256, then 1
    drop = {(k, j) for k in lost for j in range(3)}
    with CanImu(virtual(name), PROFILE) as imu:
        with CanImuTwin(name, PROFILE, counting_source(), samples=n, drop=drop) as twin:
            assert twin.wait(timeout=120) and twin.error is None
        blocks = read_all(imu, n - len(lost))
    seq = np.concatenate([b.seq for b in blocks])
    np.testing.assert_array_equal(seq, [k for k in range(n) if k not in lost])
    assert (imu.stats.restarts, imu.stats.gaps, imu.stats.dropped) == (0, 2, 4)


def test_a_device_restarting_at_the_same_counter_starts_a_new_segment():
    """The unit resets and counts again from the counter value it had: a new segment (the
    numbering goes back to the raw counter), not a jump of 256 that would shift every sample."""
    name, first_run, second_run = channel(), 257, 300  # the first run ends at counter 256 % 256
    with CanImu(virtual(name), PROFILE) as imu:
        for samples in (first_run, second_run):
            with CanImuTwin(name, PROFILE, counting_source(), samples=samples) as twin:
                assert twin.wait(timeout=120) and twin.error is None
        blocks = read_all(imu, first_run + second_run)
    seq = np.concatenate([b.seq for b in blocks])
    np.testing.assert_array_equal(seq, np.r_[np.arange(first_run), np.arange(second_run)])
    assert (imu.stats.restarts, imu.stats.gaps, imu.stats.duplicates) == (1, 0, 0)
