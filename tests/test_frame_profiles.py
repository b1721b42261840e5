"""Frame profiles of real wire formats (drivers/wire/fields.py, crc.py, ascii.py): typed fields,
the checks against published check values and independent loops, frames built by hand with
`struct` from the manuals' field tables, status rules, message-id framing, NMEA sentences, and
each commercial profile's twin through the real serial driver on a pty at the device's rate."""

import functools
import os
import struct
import threading
import time
import tty
from pathlib import Path

import numpy as np
import pytest

from drivers.clock import SteppedClock
from drivers.errors import ProfileError
from drivers.profile import SerialImuProfile
from drivers.samples import SampleBlock
from drivers.serial_imu import SerialImu
from drivers.twins.serial import SENT, SerialTwin
from drivers.wire.ascii import AsciiLineParser
from drivers.wire.binary import BinaryFrameParser, encode_frames
from drivers.wire.crc import CHECKSUMS

XSENS = SerialImuProfile.load("xsens_mtdata2")
VN_BIN = SerialImuProfile.load("vectornav_binary")
VN_ASCII = SerialImuProfile.load("vectornav_ascii")
MIMU = SerialImuProfile.load("mimu4444")
REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "mimu4444-array"
if not REAL.exists():  # a worktree outside /work
    REAL = Path("/work/shared/data/real/mimu4444-array")


def parser_of(profile):
    return BinaryFrameParser(profile.serial.frame, profile.imu.channels, profile.imu.scale)


def decode_all(profile, data: bytes):
    parser = parser_of(profile)
    block = SampleBlock.concat([parser.decode(data, 0.0).block,
                                parser.decode(b"", 0.0, final=True).block])
    return block, parser.stats


# -- checks ----------------------------------------------------------------------------------------

def test_fletcher16_published_values_and_the_mod256_form_by_a_plain_loop():
    # Fletcher-16 check values (Fletcher 1982; the values Wikipedia's "Fletcher's checksum" lists)
    fletcher = CHECKSUMS["fletcher16"]
    assert [fletcher.of(t) for t in (b"abcde", b"abcdef", b"abcdefgh")] == [0xC8F0, 0x2057,
                                                                           0x0627]
    data = np.random.default_rng(1).integers(0, 256, 500, dtype=np.uint8).tobytes()
    a = b = 0
    for byte in data:  # u-blox UBX / MIP: CK_A += byte; CK_B += CK_A (8 bits), sent CK_A first
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    assert CHECKSUMS["fletcher16-mod256"].of(data) == a << 8 | b


def test_sums_and_xor_against_their_definitions():
    data = np.random.default_rng(2).integers(0, 256, 300, dtype=np.uint8).tobytes()
    assert CHECKSUMS["sum8"].of(data) == sum(data) % 256
    assert (sum(data) + CHECKSUMS["sum8-twos"].of(data)) % 256 == 0  # Xbus: all add up to 0
    assert CHECKSUMS["xor8"].of(data) == functools.reduce(lambda x, y: x ^ y, data)
    rows = np.frombuffer(data, np.uint8).reshape(30, 10)
    for check in CHECKSUMS.values():  # many rows at once equal one at a time
        assert list(check.rows(rows)) == [check.of(r.tobytes()) for r in rows]


# -- Xsens MTData2 ---------------------------------------------------------------------------------

def xsens_message(counter, stf, acc, gyr, temp_c, status) -> bytes:
    """One MTData2 message built from the MT Low Level Communication Protocol's tables."""
    data = (struct.pack(">HBH", 0x1020, 2, counter) + struct.pack(">HBI", 0x1060, 4, stf)
            + struct.pack(">HB3f", 0x4020, 12, *acc) + struct.pack(">HB3f", 0x8020, 12, *gyr)
            + struct.pack(">HBf", 0x0810, 4, temp_c) + struct.pack(">HBI", 0xE020, 4, status))
    body = bytes([0xFF, 0x36, len(data)]) + data
    return b"\xfa" + body + bytes([-sum(body) & 0xFF])


def test_xsens_message_by_hand_decodes_to_si_counts():
    msg = xsens_message(65535, 123456, (0.5, -9.80665, 3.25), (0.01, -0.2, 1.5), 25.5, 1)
    assert len(msg) == 61 and sum(msg[1:]) % 256 == 0
    block, stats = decode_all(XSENS, msg + xsens_message(0, 123481, (0, 0, 0), (0, 0, 0), 25.5, 1))
    f32 = np.float32
    expected = [round(float(f32(v)) * s) for v, s in zip(
        (0.5, -9.80665, 3.25, 0.01, -0.2, 1.5), (1e5,) * 3 + (1e6,) * 3, strict=True)]
    assert list(block.counts[0, :6]) == expected
    assert block.counts[0, 6] == round((25.5 + 273.15) * 100)
    assert list(block.seq) == [65535, 65536]  # 65535 -> 0 is one step, unwrapped
    assert block.device_time[1] - block.device_time[0] == pytest.approx(25e-4)
    assert stats.crc_failures == 0


def test_xsens_values_not_finite_or_beyond_64_bit_counts_make_the_sample_invalid():
    """A float that is NaN, infinite or too large for int64 counts (1e30 m/s^2 is 1e35 counts)
    makes its sample invalid (not returned, counted), in any read size; the others decode."""
    frames = [xsens_message(i, 25 * i, (0.1 * i, 0, 9.8), (0, 0.01 * i, 0), 30.0, 1)
              for i in range(12)]
    frames[3] = xsens_message(3, 75, (0.3, 0, 9.8), (float("nan"), 0.03, 0), 30.0, 1)
    frames[7] = xsens_message(7, 175, (1e30, 0, 9.8), (0, 0.07, 0), 30.0, 1)
    frames[10] = xsens_message(10, 250, (1.0, 0, 9.8), (0, 0.1, 0), float("inf"), 1)
    stream = b"".join(frames)
    block, stats = decode_all(XSENS, stream)
    assert list(block.seq) == [i for i in range(12) if i not in (3, 7, 10)]
    assert (stats.invalid, stats.samples, stats.dropped) == (3, 9, 0)
    assert block.counts[:, 4].tolist() == [round(float(np.float32(0.01 * i)) * 1e6)
                                          for i in range(12) if i not in (3, 7, 10)]
    parser = parser_of(XSENS)
    chunks = [parser.decode(stream[i : i + 5], 0.0).block for i in range(0, len(stream), 5)]
    chunked = SampleBlock.concat([*chunks, parser.decode(b"", 0.0, final=True).block])
    assert np.array_equal(chunked.counts, block.counts) and parser.stats == stats


def test_xsens_status_rule_and_other_messages_skipped():
    """A sample the device marks clipped is not returned (and counted); a message with another
    MID or another output configuration is refused by its constants, not decoded."""
    good = [xsens_message(i, 25 * i, (0.1 * i, 0, 9.8), (0, 0.01 * i, 0), 30.0, 1)
            for i in range(20)]
    good[5] = xsens_message(5, 125, (0.5, 0, 9.8), (0, 0.05, 0), 30.0, 1 | 1 << 11)  # gyr x clip
    other = bytearray(xsens_message(99, 0, (1, 2, 3), (4, 5, 6), 7, 1))
    other[2] = 0x3E  # another MID (its checksum then fails too: fix it, it must still be skipped)
    other[-1] = -sum(other[1:-1]) & 0xFF
    error_msg = bytes([0xFA, 0xFF, 0x42, 1, 0x04]) + bytes([-(0xFF + 0x42 + 1 + 4) & 0xFF])
    stream = b"".join(good[:8]) + bytes(other) + error_msg + b"".join(good[8:])
    block, stats = decode_all(XSENS, stream)
    assert list(block.seq) == [i for i in range(20) if i != 5]
    assert stats.invalid == 1 and stats.dropped == 0
    # the two other messages are skipped by their LEN (FA FF MID LEN ... CS), not as garbage
    assert (stats.other_messages, stats.skipped_bytes, stats.resyncs) == (2, 0, 0)
    parser = parser_of(XSENS)  # the same when the bytes arrive 7 at a time
    chunks = [parser.decode(stream[i : i + 7], 0.0).block for i in range(0, len(stream), 7)]
    chunked = SampleBlock.concat([*chunks, parser.decode(b"", 0.0, final=True).block])
    assert np.array_equal(chunked.counts, block.counts) and parser.stats == stats
    # a damaged other message is garbage again: skipped and a resync
    broken = stream.replace(error_msg, error_msg[:-1] + bytes([error_msg[-1] ^ 1]))
    _, stats = decode_all(XSENS, broken)
    assert (stats.other_messages, stats.skipped_bytes, stats.resyncs) == (0, 67, 1)
    assert block.counts[:, 0].tolist() == [round(float(np.float32(0.1 * i)) * 1e5)
                                          for i in range(20) if i != 5]
    # encode_frames writes the same bytes as the manual's table
    counts = np.array([[50000, 0, 980000, 0, 50000, 0, 30315]])
    assert encode_frames(XSENS.serial.frame, [5], [125], counts, XSENS.imu.channels,
                         XSENS.imu.scale) == xsens_message(5, 125, (0.5, 0, 9.8), (0, 0.05, 0),
                                                           np.float32(303.15 - 273.15), 0)


# -- VectorNav binary ------------------------------------------------------------------------------

def crc_ccitt(data: bytes) -> int:
    """CRC-16-CCITT as the VN-100 manual prints it (section "Checksum / CRC")."""
    crc = 0
    for byte in data:
        crc = (crc >> 8 | crc << 8) & 0xFFFF
        crc ^= byte
        crc ^= (crc & 0xFF) >> 4
        crc ^= (crc << 12) & 0xFFFF
        crc ^= ((crc & 0xFF) << 5) & 0xFFFF
    return crc


def vn_message(ns, gyr, acc, mag, temp, pres) -> bytes:
    body = struct.pack("<BHQ3f3f3fff", 0x01, 0x0521, ns, *gyr, *acc, *mag, temp, pres)
    return b"\xfa" + body + struct.pack(">H", crc_ccitt(body))


def test_vectornav_binary_message_by_hand():
    msgs = [vn_message(10**9 + 1250000 * i, (0.1, 0.2, -0.3), (0, 0, -9.8), (0.5, 0, -0.25), 21.0,
                       101.3) for i in (0, 1, 3)]
    block, stats = decode_all(VN_BIN, b"".join(msgs))
    assert list(np.diff(block.seq)) == [1, 2] and stats.dropped == 1  # counted by TimeStartup
    f = float(np.float32(0.5))
    assert block.counts[0, 6] == round(f * 1e-4 * 1e9)  # gauss -> T -> counts
    assert block.counts[0, 9] == round((21.0 + 273.15) * 100)
    assert block.device_time[2] - block.device_time[0] == pytest.approx(3.75e-3)


# -- fields in general -----------------------------------------------------------------------------

FIELDS = """
[imu]
name = "t"
channels = ["a", "b", "c", "d"]
units = "m/s^2"
scale = [1.0, 1.0, 1000.0, 1.0]
rate_hz = 100
[serial]
baudrate = 115200
protocol = "binary"
[serial.binary]
sync = [0x55]
byte_order = "little"
crc = "fletcher16"
crc_byte_order = "big"
[[serial.binary.fields]]
name = "seq"
type = "uint8"
[[serial.binary.fields]]
name = "a"
type = "int24"
byte_order = "big"
[[serial.binary.fields]]
name = "b"
type = "uint24"
[[serial.binary.fields]]
name = "c"
type = "int16"
scale = 0.01
offset = -1.5
[[serial.binary.fields]]
name = "d"
type = "int64"
[[serial.binary.fields]]
name = "reserved"
type = "float64"
"""


def fields_frame(seq, a, b, c_raw, d) -> bytes:
    """A frame of FIELDS built by hand: 24-bit big- and little-endian, int16, int64, float64."""
    body = (bytes([seq]) + (a & 0xFFFFFF).to_bytes(3, "big") + b.to_bytes(3, "little")
            + struct.pack("<hqd", c_raw, d, 2.5))
    return b"\x55" + body + struct.pack(">H", CHECKSUMS["fletcher16"].of(body))


def test_24_bit_fields_byte_orders_scale_offset_and_int64(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text(FIELDS)
    profile = SerialImuProfile.load(path)
    values = [(-8388608 + 3, 0xFEDCBA, -1234, -2**62 + 7), (8388607, 0, 32767, 2**63 - 1)]
    block, _ = decode_all(profile, fields_frame(9, *values[0]) + fields_frame(10, *values[1]))
    assert block.counts.tolist() == [[a, b, round((c * 0.01 - 1.5) * 1000), d]
                                     for a, b, c, d in values]
    again = encode_frames(profile.serial.frame, [9, 10], [0, 0], block.counts,
                          profile.imu.channels, profile.imu.scale)
    frames = fields_frame(9, *values[0]) + fields_frame(10, *values[1])
    size = len(frames) // 2
    for i in (0, 1):  # equal but for the ignored float64 (written 0) and the check
        assert again[i * size : i * size + size - 10] == frames[i * size : i * size + size - 10]


@pytest.mark.parametrize("change, words", [
    (('name = "c"', 'name = "e"'), ["every [imu] channel", "missing ['c']"]),
    (('name = "seq"\ntype = "uint8"', 'name = "seq"\ntype = "int8"'), ["unsigned"]),
    (('type = "int64"', 'type = "int64"\nvalue = 3'), ["unsigned integer"]),
    (('name = "seq"\ntype = "uint8"', 'name = "seq"\ntype = "uint8"\nvalue = 256'),
     ["fields[0]] value", "0..255"]),
    (('name = "seq"', 'name = "tick"'), ["need a \"seq\" field"]),
    (('type = "int24"', 'type = "int23"'), ["fields[1]] type"]),
    (('crc_byte_order = "big"', 'crc_byte_order = "big"\nlength_field = "d"\nlength_adds = 3'),
     ["length_field", "uint8, uint16 or uint32"]),
])
def test_bad_fields_are_refused_naming_the_field(tmp_path, change, words):
    path = tmp_path / "p.toml"
    path.write_text(FIELDS.replace(*change, 1))
    with pytest.raises(ProfileError) as info:
        SerialImuProfile.load(path)
    for word in words:
        assert word in str(info.value)


# -- NMEA sentences --------------------------------------------------------------------------------

def sentence(body: str) -> bytes:
    return f"${body}*{functools.reduce(lambda x, y: x ^ y, body.encode()):02X}\r\n".encode()


def test_vnimu_sentences_checksum_columns_and_other_sentences():
    line = "VNIMU,+0.2814,-0.0623,+0.5924,-0.208,+0.041,-9.777,+0.002186,-0.000349,+0.000215," \
           "+25.4,+101.592"
    bad = bytearray(sentence(line))
    bad[10] = ord("7") if bad[10] != ord("7") else ord("6")
    data = (b"partial\r\n" + sentence(line) + sentence("VNYMR,+1.0,+2.0,+3.0") + bytes(bad)
            + sentence(line.replace("-9.777", "-9.778")))
    parser = AsciiLineParser(VN_ASCII.serial.frame, VN_ASCII.imu.channels)
    block = parser.decode(data, 0.0).block
    assert block.counts.tolist() == [
        [281400, -62300, 592400, -208000, 41000, -9777000, 2186, -349, 215],
        [281400, -62300, 592400, -208000, 41000, -9778000, 2186, -349, 215]]
    assert parser.stats.bad_lines == 1  # the flipped digit; $VNYMR is skipped, not bad
    assert VN_ASCII.imu.to_si(block.counts)[0, 0] == pytest.approx(0.2814e-4)  # gauss -> T


# -- live twins through the real driver ------------------------------------------------------------

LIMITS = {"m/s^2": 1_500_000, "rad/s": 3_000_000, "T": 50_000, "K": 30_000}
"""Count ranges of the twins' sources: within them float32 carries every count exactly."""


def source_for(profile):
    """Counts that are a known function of the sampling time (0.1 ms resolution), within each
    channel's LIMITS (temperatures around 25 degrees C)."""
    imu = profile.imu
    span = np.array([LIMITS.get(u, 30000) for u in imu.units], dtype=np.int64)
    if "MIMU" in imu.name.upper():
        span[:] = 30000
    base = np.array([29815 if u == "K" else 0 for u in imu.units], dtype=np.int64)

    def source(times):
        n = np.round(np.asarray(times) * 1e4).astype(np.int64)
        h = (n[:, None] * 2654435761 + np.arange(len(span)) * 40503) % (2 * span + 1) - span
        return np.where(base > 0, base + h % 200, h)
    return source


@pytest.mark.parametrize("profile", [XSENS, VN_BIN, MIMU], ids=lambda p: p.imu.name)
def test_binary_twin_at_its_rate_with_1pct_corruption(profile):
    """The twin at the device's rate, 1 % of frames damaged: every intact frame recovered with its
    exact counts, nothing else."""
    source = source_for(profile)
    seconds = 2.5 if profile.imu.rate_hz >= 400 else 8.0
    twin, got = stream_in_lockstep(profile, source, seconds, seed=7)
    frame = got.seq - got.seq[0] + twin_seq_of_first(twin, got, source)
    assert np.array_equal(got.counts, source(twin.time_of(frame)))  # no false accept
    seq, fate = twin.log()
    intact = seq[(fate == SENT) & (seq >= frame[0]) & (seq <= frame[-1])]
    assert np.setdiff1d(intact, frame).size == 0  # every intact frame recovered
    assert len(intact) > 0.97 * (frame[-1] - frame[0] + 1) and len(frame) > 400


def stream_in_lockstep(profile, source, seconds, seed):
    """(twin, samples) of `seconds` of the twin's stream, 1 % of frames damaged, read by the
    driver in lockstep time (`SteppedClock`: the same frames however busy the host; on the wall
    clock a starved reader once saw too few frames to judge)."""
    clock = SteppedClock(step=0.1)
    twin = SerialTwin(profile, source, clock=clock, corrupt=0.01, seed=seed, max_lag=np.inf)
    got = []
    with twin, SerialImu(twin.port, profile, clock=clock) as imu:
        end = clock.now() + seconds
        while clock.now() < end:
            got.append(imu.read_block(timeout=30.0))
            assert got[-1] is not None, "the twin stopped streaming"
    return twin, SampleBlock.concat(got)


def twin_seq_of_first(twin, got, source) -> int:
    """The twin's frame number of the first decoded sample (the driver's sequence starts from
    the device's counter, or from the device time)."""
    seq, _ = twin.log()
    candidates = source(twin.time_of(seq))
    match = np.flatnonzero(np.all(candidates == got.counts[0], axis=1))
    assert len(match) == 1
    return int(seq[match[0]])


def test_vnimu_twin_at_its_rate_with_1pct_corruption():
    source = source_for(VN_ASCII)
    twin, got = stream_in_lockstep(VN_ASCII, source, 6.0, seed=8)
    seq, fate = twin.log()
    sent = source(twin.time_of(seq))
    rows = {tuple(r): s for r, s in zip(sent.tolist(), seq.tolist(), strict=True)}
    frames = [rows.get(tuple(r)) for r in got.counts.tolist()]
    assert None not in frames  # every decoded line is a line that was sent
    intact = seq[(fate == SENT) & (seq > min(frames)) & (seq <= max(frames))]
    assert np.setdiff1d(intact, frames).size == 0 and len(frames) > 250


@pytest.mark.skipif(not REAL.exists(), reason="needs ../shared/data/real/mimu4444-array")
def test_real_mimu4444_packets_through_a_pty_and_the_driver():
    """exp_1.bin's first 600 packets written to a pty at 62.5 Hz x 8 and read by the serial
    driver: every packet decoded to its struct-unpacked values, packet numbers consecutive."""
    raw = (REAL / "exp_1.bin").read_bytes()[4 : 4 + 106 * 600]
    expected = [struct.unpack(">BHBI48hH", raw[i : i + 106]) for i in range(0, len(raw), 106)]
    assert all(sum(raw[i : i + 104]) & 0xFFFF == p[-1] for i, p in zip(
        range(0, len(raw), 106), expected, strict=True))  # every checksum holds
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)

    def write():
        for i in range(0, len(raw), 106 * 8):
            os.write(master, raw[i : i + 106 * 8])
            time.sleep(8 / 62.5 / 8)  # 8 x the real rate
    writer = threading.Thread(target=write)
    got = []
    with SerialImu(os.ttyname(slave), MIMU) as imu:
        writer.start()
        while sum(map(len, got)) < len(expected) - 1:
            block = imu.read_block(timeout=2.0)
            assert block is not None, "the packets stopped"
            got.append(block)
        got.append(imu.parser.decode(b"", 0.0, final=True).block)
    writer.join()
    os.close(master)
    os.close(slave)
    got = SampleBlock.concat(got)
    assert len(got) == len(expected) and np.all(np.diff(got.seq) == 1)
    assert np.array_equal(got.counts, np.array([p[4:52] for p in expected]))
    assert [p[1] for p in expected] == list((got.seq - got.seq[0] + expected[0][1]) % 65536)


def test_a_dump_of_typed_frames_imports_with_device_time_and_kelvin(tmp_path):
    """`station import binary` reads a typed-field profile through the same parser: SI values
    of the float fields, the temperature in kelvin, times from SampleTimeFine (not from the
    packet counter: the stamps below run 14 % faster than the nominal 400 Hz)."""
    from station.imports.recordings import import_binary
    from station.session import Session

    n = 500
    stf = np.arange(n) * 22  # 10 kHz ticks, 454.5 Hz
    msgs = [xsens_message(i, int(stf[i]), (0.0, 0.0, 9.80665), (0.0, 0.0, 0.5), 21.5, 0)
            for i in range(n)]
    (tmp_path / "x.bin").write_bytes(b"".join(msgs))
    out = import_binary(tmp_path / "x.h5", tmp_path / "x.bin", "xsens_mtdata2")
    with Session.open(out) as s:
        data, link = s.stream("imu"), s.metadata["import"]["link"]
    si = data.to_si()
    assert data.spec.units[-1] == "K" and si[0, -1] == pytest.approx(294.65, abs=0.005)
    assert si[0, 2] == pytest.approx(9.80665, abs=1e-5) and si[0, 5] == pytest.approx(0.5)
    assert np.diff(data.device_time) == pytest.approx(2.2e-3, abs=1e-9)
    assert link["rate_hz"] == pytest.approx(1 / 2.2e-3)
