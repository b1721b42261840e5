"""The MAVLink IMU driver against the MAVLink twin, pymavlink on both sides, over a real pty and
UDP on 127.0.0.1: every IMU message decodes to the SI values the twin sent (expected values from
the message definitions of MAVLink's common.xml, applied here to what the twin logged), lost and
corrupted messages are counted exactly, and the errors name what was seen."""

import numpy as np
import pytest

from drivers import ImuDriver, LinkStats, open_imu
from drivers.clock import ScaledClock, SteppedClock
from drivers.errors import DeviceLostError, MavlinkError, ProfileError, SerialPortError
from drivers.mavlink_imu import MavlinkImu, MavlinkProfile
from drivers.twins.mavlink import CORRUPTED, DROPPED, SENT, MavlinkTwin, free_udp_port

G0 = 9.80665  # MAVLink's g (mG fields), standard gravity
FIELDS = ["xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag"]
# SI value of one unit of each field, per message family (common.xml): m/s^2, rad/s, gauss
# (1e-4 T) for HIGHRES_IMU; mG, mrad/s, mgauss for SCALED_IMU
SI_PER_UNIT = {"HIGHRES_IMU": [1.0] * 6 + [1e-4] * 3,
               "SCALED_IMU": [G0 / 1000] * 3 + [1e-3] * 3 + [1e-7] * 3}
RAW_SCALE = [2048 / G0] * 3 + [16.4 * 180 / np.pi] * 3 + [1e7] * 3  # an MPU-6000-like sensor


def write_profile(tmp_path, message, instance=0, wait_s=3.0, raw=False, name="fc.toml"):
    """A 9-channel profile of `message` (the scale left to the defaults but for RAW_IMU)."""
    scale = f"scale = {RAW_SCALE!r}\n" if raw else ""
    (tmp_path / name).write_text(
        f'[imu]\nname = "fc"\nchannels = {[f"c{i}" for i in range(9)]!r}\nrate_hz = 200.0\n'
        f'{scale}\n[mavlink]\nmessage = "{message}"\ninstance = {instance}\n'
        f'fields = {FIELDS!r}\nwait_s = {wait_s}\n'.replace("'", '"'))
    return MavlinkProfile.load(tmp_path / name)


def source(times):
    """Counts that move every sample and use the int16 range: (k, 9)."""
    t = np.asarray(times)[:, None]
    return np.round(20000 * np.sin(2 * np.pi * 0.7 * t + np.arange(9))).astype(np.int64)


def read(imu, samples: int, wall: float = 600.0):
    """At least `samples` samples (one SampleBlock), or fail after `wall` s (a hang guard)."""
    import time

    blocks, end = [], time.monotonic() + wall
    while sum(len(b) for b in blocks) < samples:
        assert time.monotonic() < end, f"only {sum(len(b) for b in blocks)} samples came"
        block = imu.read_block(0.2)
        if block is not None:
            blocks.append(block)
    from drivers.samples import SampleBlock

    return SampleBlock.concat(blocks)


def matched(block, log):
    """Index into the twin's log of each sample read, by its time stamp (within 0.5 ms)."""
    i = np.clip(np.searchsorted(log.time, block.device_time - 5e-4), 0, len(log.time) - 1)
    assert np.all(np.abs(log.time[i] - block.device_time) < 5e-4)
    return i


def expected_si(family, values, scale):
    """SI values of the field values the twin sent, from the message definitions."""
    if family == "RAW_IMU":
        return values / np.asarray(scale)
    if family == "HIGHRES_IMU":
        values = values.astype(np.float32).astype(float)  # the fields are float32 on the wire
    return values * SI_PER_UNIT[family]


CASES = [("HIGHRES_IMU", 0, False, False), ("SCALED_IMU", 0, False, False),
         ("SCALED_IMU", 1, True, False), ("SCALED_IMU", 2, False, True),
         ("RAW_IMU", 0, True, False), ("HIGHRES_IMU", 0, False, True)]


@pytest.mark.parametrize("family, instance, udp, mavlink1", CASES)
def test_every_message_decodes_to_the_si_values_sent(tmp_path, family, instance, udp, mavlink1):
    profile = write_profile(tmp_path, family, instance, raw=family == "RAW_IMU")
    clock = SteppedClock()  # lockstep time: the same samples however busy the host
    port = free_udp_port() if udp else None
    with MavlinkTwin(profile, source, clock, udp_port=port, mavlink1=mavlink1) as twin, \
            open_imu("mavlink", twin.port, profile, clock) as imu:
        block = read(imu, 300)
        assert isinstance(imu, ImuDriver) and isinstance(imu.stats, LinkStats)
    log = twin.log()
    i = matched(block, log)
    assert np.all(log.fate[i] == SENT)
    want = expected_si(family, log.values[i], profile.imu.scale)
    got = profile.imu.to_si(block.counts)
    if family == "HIGHRES_IMU":  # floats: the count is the value rounded to 1 / scale
        assert np.all(np.abs(got - want) <= 0.5 / np.asarray(profile.imu.scale) * (1 + 1e-9))
    else:  # integers: the count is the field
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=0)
    assert np.all(np.diff(block.seq) == np.diff(i))  # one number per sample, none missing
    assert twin.requests[0] == (profile.mavlink.message.msg_id, pytest.approx(5000.0))
    assert imu.stats.samples == len(block) and imu.stats.lost_messages == 0


@pytest.mark.parametrize("udp", [False, True])
def test_lost_and_corrupted_messages_are_counted_and_skipped(tmp_path, udp):
    """5 % of the IMU messages lost on the way, 5 % with a byte changed: the driver hands out
    every intact one, numbered as the twin numbered them, and counts the others exactly."""
    profile = write_profile(tmp_path, "SCALED_IMU")
    clock = SteppedClock()  # lockstep time: the same samples however busy the host
    with MavlinkTwin(profile, source, clock, udp_port=free_udp_port() if udp else None,
                     drop=0.05, corrupt=0.05, seed=3) as twin, \
            MavlinkImu(twin.port, profile, clock) as imu:
        block = read(imu, 1500)
    log = twin.log()
    i = matched(block, log)
    assert np.all(log.fate[i] == SENT)
    np.testing.assert_array_equal(block.counts, log.values[i])
    np.testing.assert_array_equal(block.seq - block.seq[0], i - i[0])
    between = log.fate[i[0]:i[-1] + 1]
    lost = int(np.sum(between == DROPPED) + np.sum(between == CORRUPTED))
    assert np.sum(between == CORRUPTED) > 20 and np.sum(between == DROPPED) > 20
    assert np.count_nonzero(between == SENT) == len(block)
    stats = imu.stats
    assert stats.crc_failures == np.sum(between == CORRUPTED)
    assert stats.dropped == lost
    # packet numbers count from the first message of any type: a heartbeat just before the first
    # sample read, or just after the last, may add a lost IMU message on either side
    assert lost <= stats.lost_messages <= lost + 2
    assert stats.gaps == np.count_nonzero(np.diff(i) > 1)


def test_a_burst_of_noise_is_skipped(tmp_path):
    """Random bytes between messages: pymavlink skips them (a false start may swallow a message
    or two behind it); no sample is made up, and the stream goes on after the burst."""
    profile = write_profile(tmp_path, "HIGHRES_IMU")
    clock = SteppedClock()  # lockstep time: the same samples however busy the host
    with MavlinkTwin(profile, source, clock, seed=4) as twin, \
            MavlinkImu(twin.port, profile, clock) as imu:
        first = read(imu, 100)
        for _ in range(5):
            twin.burst(300)
            read(imu, 50)
        after = read(imu, 200)
    log = twin.log()
    for block in (first, after):
        i = matched(block, log)
        got = profile.imu.to_si(block.counts)
        want = expected_si("HIGHRES_IMU", log.values[i], profile.imu.scale)
        assert np.all(np.abs(got - want) <= 0.5 / np.asarray(profile.imu.scale) * (1 + 1e-9))
    assert imu.stats.bad_bytes + imu.stats.crc_failures > 0
    assert np.all(log.fate == SENT) and after.seq[0] > first.seq[-1]


def test_no_stream_names_the_messages_seen(tmp_path):
    """A vehicle that ignores SET_MESSAGE_INTERVAL: only its HEARTBEATs come."""
    profile = write_profile(tmp_path, "SCALED_IMU", wait_s=1.0)
    expected = r"seen only: HEARTBEAT x\d+ from 1/1.*Enable the IMU stream: SET_MESSAGE_INTERVAL"
    with MavlinkTwin(profile, source, ScaledClock(5.0), answer=False) as twin, \
            pytest.raises(MavlinkError, match=expected) as error:
        MavlinkImu(twin.port, profile).open()
    assert "SCALED_IMU (#26)" in str(error.value) and twin.requests


def test_a_wrong_instance_names_the_one_seen(tmp_path):
    sent = write_profile(tmp_path, "HIGHRES_IMU", instance=0, name="sent.toml")
    wanted = write_profile(tmp_path, "HIGHRES_IMU", instance=2, wait_s=1.0)
    expected = r"seen: .*HIGHRES_IMU instance 0 x.* Set \[mavlink\] instance"
    with MavlinkTwin(sent, source, ScaledClock(5.0), stream=True) as twin, \
            pytest.raises(MavlinkError, match=expected):
        MavlinkImu(twin.port, wanted).open()


def test_silence_and_bad_addresses(tmp_path):
    profile = write_profile(tmp_path, "SCALED_IMU", wait_s=0.3)
    port = free_udp_port()
    with pytest.raises(MavlinkError, match="nothing came: check that the flight controller"):
        MavlinkImu(f"udpin:127.0.0.1:{port}", profile).open()
    with pytest.raises(SerialPortError, match="cannot open serial port /dev/nonexistent-fc"):
        MavlinkImu("/dev/nonexistent-fc", profile).open()
    for bad in ("udp:127.0.0.1:14550", "udpin:localhost:14550", "udpin:127.0.0.1:0"):
        with pytest.raises(MavlinkError, match="give udpin:HOST:PORT"):
            MavlinkImu(bad, profile)


def test_unplug_hands_out_the_samples_then_raises_and_reopens(tmp_path):
    profile = write_profile(tmp_path, "SCALED_IMU")
    clock = ScaledClock(5.0)  # the reconnect guard: a real-time clock
    with MavlinkTwin(profile, source, clock) as twin, \
            MavlinkImu(twin.port, profile, clock) as imu:
        before = read(imu, 100)
        twin.unplug()
        with pytest.raises(DeviceLostError, match="was lost"):
            read(imu, 10**6)
        twin.plug()
        imu.open()
        after = read(imu, 100)
    assert imu.connections == 2 and after.seq[0] > before.seq[-1]
    log = twin.log()
    for block in (before, after):
        np.testing.assert_array_equal(block.counts, log.values[matched(block, log)])


@pytest.mark.parametrize("imu, mavlink, message", [
    ('scale = 1000.0', 'message = "SCALED_IMU"\nfields = ["xacc"]', "SCALED_IMU fixes"),
    ('', 'message = "RAW_IMU"\nfields = ["xacc"]', "scale: missing"),
    ('', 'message = "SCALED_IMU"\nfields = ["xacc", "yacc"]', "1 channels and .* fields 2"),
    ('', 'message = "SCALED_IMU"\ninstance = 3\nfields = ["xacc"]', "must be 0..2"),
    ('', 'message = "SCALED_IMU"\nfields = ["temperature"]', "must be distinct fields of"),
    ('units = "rad/s"', 'message = "HIGHRES_IMU"\nfields = ["xacc"]', "differ from the fields'"),
    ('', 'message = "ATTITUDE"\nfields = ["xacc"]', "must be one of"),
])
def test_profile_errors_name_the_problem(tmp_path, imu, mavlink, message):
    (tmp_path / "p.toml").write_text(f'[imu]\nname = "x"\nchannels = ["a"]\nrate_hz = 100.0\n'
                                     f'{imu}\n[mavlink]\n{mavlink}\n')
    with pytest.raises(ProfileError, match=message):
        MavlinkProfile.load(tmp_path / "p.toml")


def test_the_decoder_numbers_duplicates_reboots_and_invalid_values():
    """The pure decoder on frames built here with pymavlink: a repeated message (same packet
    number and bytes) is dropped, a time stamp going back starts a new segment, a message lost
    in between steps the numbering by the periods it covers, NaN is refused."""
    from pymavlink.dialects.v20 import common as mavlink

    from drivers.mavlink_imu import MavlinkDecoder

    profile = MavlinkProfile.load("imu6_mavlink")
    fc = mavlink.MAVLink(None, 1, 1)

    def frame(t, value, seq):
        fc.seq = seq
        return bytes(fc.highres_imu_encode(round(t * 1e6), value, 0, 9.8, 0.01, 0, 0, 0, 0, 0,
                                           0, 0, 0, 0, 0x3F, 0).pack(fc))

    stream = [frame(1.000, 0.5, 10), frame(1.005, 0.25, 11), frame(1.005, 0.25, 11),  # repeat
              frame(1.020, 0.125, 14),  # packets 12, 13 lost: samples at 1.010 and 1.015
              frame(0.002, 1.0, 15),  # rebooted
              frame(0.007, float("nan"), 16), frame(0.012, -2.0, 17)]
    decoder = MavlinkDecoder(profile.mavlink, profile.imu.scale, 200.0)
    block = decoder.decode(b"".join(stream), host_time=3.0)
    np.testing.assert_array_equal(block.seq, [0, 1, 4, 4, 6])
    np.testing.assert_allclose(block.device_time, [1.0, 1.005, 1.02, 0.002, 0.012])
    np.testing.assert_array_equal(block.counts[:, 0], np.array([0.5, 0.25, 0.125, 1.0, -2.0]) * 1e5)
    np.testing.assert_array_equal(block.counts[:, 3], [10000] * 5)  # 0.01 rad/s at 1e6 per rad/s
    s = decoder.stats
    assert (s.samples, s.duplicates, s.lost_messages, s.gaps, s.dropped, s.restarts, s.invalid) \
        == (5, 1, 2, 2, 3, 1, 1)
