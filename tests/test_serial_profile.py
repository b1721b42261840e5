"""Device profiles (drivers/profile.py): the bundled serial profiles load; bad ones are refused with
a message naming the file, the key and the fix."""

import numpy as np
import pytest

from drivers.profile import ProfileError, SerialImuProfile, load_profile

GOOD = """
[imu]
name = "t"
channels = ["a", "b", "c"]
units = "rad/s"
scale = [100.0, 200, 300]
rate_hz = 100

[serial]
baudrate = 115200
protocol = "binary"

[serial.binary]
sync = [0xA5, 0x5A]
layout = ["sync", "seq", "time", "counts", "crc"]
byte_order = "little"
seq_type = "uint16"
time_type = "uint32"
time_tick = 1e-6
count_type = "int16"
crc = "crc16-ccitt-false"
"""


def load(tmp_path, text):
    path = tmp_path / "p.toml"
    path.write_text(text)
    return SerialImuProfile.load(path)


def test_bundled_profiles_describe_their_devices():
    binary = SerialImuProfile.load("imu12_serial")
    assert binary.imu.channels == tuple(f"g{i}" for i in range(1, 13))
    assert binary.serial.frame.sync == b"\xa5\x5a" and binary.serial.frame.max_gap == 32
    ascii_ = SerialImuProfile.load("imu_ascii")
    assert ascii_.serial.protocol == "ascii" and ascii_.serial.frame.time_scale == 0.001
    assert ascii_.imu.to_si([[16707, 0, 0, 75057, 0, 0]])[0, [0, 3]] == pytest.approx([10.0, 10.0])


def test_defaults_and_per_channel_lists(tmp_path):
    profile = load(tmp_path, GOOD)
    assert profile.imu.units == ("rad/s",) * 3 and profile.imu.scale == (100.0, 200.0, 300.0)
    assert profile.serial.frame.max_gap == 32 and profile.serial.frame.crc_covers_sync is False


@pytest.mark.parametrize("change, words", [
    (("rate_hz = 100", ""), ["[imu] rate_hz", "missing"]),
    (("baudrate = 115200", 'baudrate = "fast"'), ["[serial] baudrate", "must be int"]),
    (("rate_hz = 100", "rate_hz = 100\nrate = 5"), ["unknown keys ['rate']"]),
    (('units = "rad/s"', 'units = "deg/s"'), ["[imu] units", "SI"]),
    (("scale = [100.0, 200, 300]", "scale = [1.0, 2.0]"), ["[imu] scale", "one per channel"]),
    (("scale = [100.0, 200, 300]", "scale = -1.0"), ["[imu] scale", "positive"]),
    (('layout = ["sync", "seq", "time", "counts", "crc"]',
      'layout = ["seq", "sync", "counts", "crc"]'),
     ["[serial.binary] layout", "start with"]),
    (("sync = [0xA5, 0x5A]", "sync = [0xA5, 300]"), ["[serial.binary] sync"]),
    (('crc = "crc16-ccitt-false"', 'crc = "crc8"'), ["[serial.binary] crc", "crc16-modbus"]),
    (('seq_type = "uint16"', 'seq_type = "int16"'), ["[serial.binary] seq_type"]),
    (('crc = "crc16-ccitt-false"', 'crc = "crc16-ccitt-false"\nmax_gap = 9000'),
     ["[serial.binary] max_gap", "1..8192"]),
    (('protocol = "binary"', 'protocol = "ascii"'), ["[serial] binary", "remove [serial.binary]"]),
    (("[imu]", "[imux]"), ["no [imu] section"]),
    (("rate_hz = 100", "rate_hz = = 100"), ["invalid TOML"]),
])
def test_bad_profiles_are_refused_with_the_key_and_the_fix(tmp_path, change, words):
    with pytest.raises(ProfileError) as info:
        load(tmp_path, GOOD.replace(*change))
    message = str(info.value)
    assert str(tmp_path / "p.toml") in message
    for word in words:
        assert word in message


def test_missing_file_lists_the_bundled_profiles():
    with pytest.raises(ProfileError, match=r"cannot read device profile.*imu12_serial"):
        load_profile("no_such_profile")


def test_mimu4444_profile_describes_the_openshoe_packet():
    """PROVENANCE of the MIMU4444 recordings: 0xAA, packet number uint16 BE, length 100, 64 MHz
    stamp uint32 BE, 48 int16 BE, byte sum; 2048 counts per g and 16.4 counts per deg/s."""
    p = SerialImuProfile.load("mimu4444")
    f = p.serial.frame
    assert (f.sync, f.byte_order, f.seq_type, f.time_type, f.count_type) == (
        b"\xaa", "big", "uint16", "uint32", "int16")
    assert (f.length_type, f.length_value, f.crc, f.crc_covers_sync) == (
        "uint8", 100, "sum16", True)
    assert 1 / f.time_tick == pytest.approx(64e6)
    assert len(p.imu.channels) == 48 and p.imu.channels[-1] == "imu7_gz"
    assert p.imu.to_si([[2048, 0, 0, 164, 0, 0] * 8])[0, :4] == pytest.approx(
        [9.80665, 0, 0, np.radians(10.0)])


@pytest.mark.parametrize("change, words", [
    ('layout = ["sync", "seq", "length", "counts", "crc"]', ["[serial.binary] length_type",
                                                             "missing"]),
    ('layout = ["sync", "seq", "length", "counts", "crc"]\nlength_type = "uint8"\n'
     "length_value = 256", ["[serial.binary] length_value", "uint8"]),
    ('layout = ["sync", "seq", "seq", "counts", "crc"]', ["[serial.binary] layout", "once each"]),
])
def test_length_field_keys_are_checked(tmp_path, change, words):
    text = GOOD.replace('layout = ["sync", "seq", "time", "counts", "crc"]', change)
    text = text.replace('time_type = "uint32"\ntime_tick = 1e-6\n', "")
    with pytest.raises(ProfileError) as info:
        load(tmp_path, text)
    for word in words:
        assert word in str(info.value)
