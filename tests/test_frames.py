"""Binary frame and ASCII line parsing (drivers/wire/: crc.py, binary.py, ascii.py): exact
decoding, CRC catalogue values, resynchronisation, the sequence guard against CRC false locks,
counters, the decode contract (bytes used)."""

import binascii
import dataclasses
import struct
import zlib

import numpy as np
import pytest

from drivers.profile import SerialImuProfile
from drivers.samples import SampleBlock
from drivers.twins.serial import corrupt_frame
from drivers.wire.ascii import AsciiLineParser, encode_lines
from drivers.wire.binary import BinaryFrameParser, encode_frames
from drivers.wire.crc import CHECKSUMS, CRCS

PROFILE = SerialImuProfile.load("imu12_serial")
FMT, CHANNELS = PROFILE.serial.frame, PROFILE.imu.channels
SIZE = 2 + 2 + 4 + 12 * 4 + 2  # the profile's layout, counted by hand


def pattern(seq):
    """Full-range int32 counts that are a known function of the sequence number; every 7th frame
    carries the sync word A5 5A inside its payload."""
    seq = np.asarray(seq, dtype=np.int64)
    counts = (seq[:, None] * 2654435761 + np.arange(12) * 40503) % 2**32 - 2**31
    counts[seq % 7 == 0, 3] = 0x5AA5 - 2**15  # little-endian bytes A5 5A ...
    return counts


def stream(seq):
    """Frames for sequence numbers `seq` (device time = seq * 500 us)."""
    return encode_frames(FMT, seq, np.asarray(seq) * 500, pattern(seq))


def parse(data: bytes, fmt=FMT, chunk=None) -> tuple:
    """All samples of `data` fed at once or in chunks of `chunk` bytes, and the parser's stats."""
    parser = BinaryFrameParser(fmt, CHANNELS)
    step = chunk or max(len(data), 1)
    decoded = [parser.decode(data[i : i + step], float(i)) for i in range(0, len(data), step)]
    decoded.append(parser.decode(b"", float(len(data)), final=True))  # end of stream
    assert sum(d.used for d in decoded) == len(data)  # at the end every byte is decided
    return SampleBlock.concat([d.block for d in decoded]), parser.stats


def manual_frame(seq: int, ticks: int, counts) -> bytes:
    """One frame of the profile's layout built with struct and the stdlib CRC-16/CCITT-FALSE."""
    body = struct.pack("<HI12i", seq, ticks, *counts)
    return b"\xa5\x5a" + body + struct.pack("<H", binascii.crc_hqx(body, 0xFFFF))


def test_crc_catalogue_check_values():
    # check values of "123456789" from the CRC catalogue (reveng), and the stdlib implementations
    expected = {"crc8": 0xF4, "crc8-maxim": 0xA1, "crc16-ccitt-false": 0x29B1,
                "crc16-kermit": 0x2189, "crc16-arc": 0xBB3D, "crc16-xmodem": 0x31C3,
                "crc16-modbus": 0x4B37, "crc32": 0xCBF43926, "crc32c": 0xE3069283}
    assert {name: crc.of(b"123456789") for name, crc in CRCS.items()} == expected
    data = np.random.default_rng(0).integers(0, 256, 300, dtype=np.uint8).tobytes()
    assert CRCS["crc16-ccitt-false"].of(data) == binascii.crc_hqx(data, 0xFFFF)
    assert CRCS["crc16-xmodem"].of(data) == binascii.crc_hqx(data, 0)
    assert CRCS["crc32"].of(data) == zlib.crc32(data)


def crc_bit_by_bit(crc, data: bytes) -> int:
    """The Rocksoft/Williams definition: one bit a step through a register of `crc.width` bits
    (bytes and result reflected for reflected CRCs)."""
    top, mask, reg = 1 << (crc.width - 1), (1 << crc.width) - 1, crc.init
    for byte in data:
        bits = f"{byte:08b}"
        for bit in bits[::-1] if crc.reflected else bits:
            feedback = bool(reg & top) ^ (bit == "1")
            reg = ((reg << 1) & mask) ^ (crc.poly if feedback else 0)
    if crc.reflected:
        reg = int(f"{reg:0{crc.width}b}"[::-1], 2)
    return reg ^ crc.xorout


@pytest.mark.parametrize("name", sorted(CRCS))
def test_crc_tables_equal_the_bit_by_bit_definition(name):
    """`rows` (the positional table: what each byte value adds at each position, odd lengths
    too) and `bytewise` (the byte table) against the definition, for every CRC of CHECKSUMS."""
    crc, rng = CRCS[name], np.random.default_rng(len(name))
    for n in (0, 1, 2, 3, 8, 33, 56, 59):
        rows = rng.integers(0, 256, (5, n), dtype=np.uint8)
        expected = [crc_bit_by_bit(crc, row.tobytes()) for row in rows]
        assert crc.rows(rows).tolist() == expected
        assert crc.bytewise(rows).tolist() == expected
    assert crc.rows(np.zeros((0, 56), np.uint8)).shape == (0,)


def test_encoder_matches_a_hand_built_frame():
    counts = pattern([5])[0]
    assert stream([5]) == manual_frame(5, 2500, counts)
    assert len(stream([5])) == SIZE


def frames_of(seq) -> list:
    """The frames of `seq`, one bytes object each."""
    data = stream(seq)
    return [data[i : i + SIZE] for i in range(0, len(data), SIZE)]


def test_clean_stream_decodes_exactly_in_any_chunking():
    for chunk, k in ((None, 3000), (1, 40), (7, 300), (SIZE - 1, 3000), (SIZE + 1, 3000),
                     (4096, 3000)):
        seq = np.arange(k)
        block, stats = parse(stream(seq), chunk=chunk)
        assert np.array_equal(block.seq, seq) and np.array_equal(block.counts, pattern(seq))
        assert np.allclose(block.device_time, seq * 500e-6)
        assert (stats.crc_failures, stats.gaps, stats.resyncs, stats.skipped_bytes) == (0, 0, 0, 0)


def test_host_time_is_the_read_that_completed_the_frame():
    data = stream(np.arange(4))
    parser = BinaryFrameParser(FMT, CHANNELS)
    # a complete frame waits until every frame that could overlap it is complete (and frame 0,
    # having no predecessor, until frame 1 vouches for it)
    assert len(parser.decode(data[: SIZE + 10], 1.0).block) == 0
    b = parser.decode(data[SIZE + 10 : 3 * SIZE], 2.0).block
    c = parser.decode(data[3 * SIZE :], 3.0, final=True).block
    assert list(b.host_time) == [1.0, 2.0] and list(c.host_time) == [2.0, 3.0]


def test_resync_after_garbage_and_partial_first_frame():
    seq = np.arange(200)
    data = stream(seq)
    garbage = np.random.default_rng(1).integers(0, 256, 333, dtype=np.uint8).tobytes()
    mangled = data[17 : 100 * SIZE] + garbage + data[100 * SIZE :]
    block, stats = parse(mangled, chunk=64)
    assert np.array_equal(block.seq, np.arange(1, 200))  # frame 0 was cut, all others intact
    assert np.array_equal(block.counts, pattern(block.seq))
    assert stats.resyncs == 1 and stats.gaps == 0
    assert stats.skipped_bytes == (SIZE - 17) + 333


def test_dropped_frames_counted_as_gaps():
    seq = np.concatenate([np.arange(0, 50), np.arange(53, 80), np.arange(81, 100)])
    block, stats = parse(stream(seq))
    assert np.array_equal(block.seq, seq)
    assert (stats.gaps, stats.dropped, stats.resyncs) == (2, 4, 0)


def test_sequence_and_time_unwrap_past_the_counter_width():
    fmt = dataclasses.replace(FMT, seq_type="uint8", time_type="uint16", max_gap=8)
    seq = np.arange(1000)
    data = encode_frames(fmt, seq, seq * 500, pattern(seq))
    parser = BinaryFrameParser(fmt, CHANNELS)
    block = parser.decode(data, 0.0, final=True).block
    assert np.array_equal(block.seq, seq)  # the uint8 counter wrapped 3 times
    assert np.allclose(block.device_time, seq * 500e-6)  # the uint16 tick counter wrapped 7 times


def test_other_layouts_big_endian_crc32_over_sync_without_time():
    fmt = dataclasses.replace(FMT, sync=b"\xaa\x55\x01", layout=("sync", "counts", "seq", "crc"),
                              byte_order="big", count_type="int16", crc="crc32",
                              crc_covers_sync=True, time_type=None)
    seq = np.arange(100)
    counts = pattern(seq) % 2**16 - 2**15
    data = encode_frames(fmt, seq, seq, counts)
    one = data[: len(data) // 100]
    assert one[:3] == b"\xaa\x55\x01" and one[3:5] == struct.pack(">h", counts[0, 0])
    assert one[-4:] == struct.pack(">I", zlib.crc32(one[:-4]))
    block = BinaryFrameParser(fmt, CHANNELS).decode(data, 0.0, final=True).block
    assert np.array_equal(block.counts, counts) and np.all(np.isnan(block.device_time))


def test_crc_valid_fake_with_inconsistent_sequence_is_rejected():
    # a forged frame with a correct CRC but a sequence number far from its neighbours, placed
    # between frames 9 and 10: CRC alone would accept it, the sequence guard must not
    fake = manual_frame(4000, 123, np.arange(12))
    data = stream(np.arange(10)) + fake + stream(np.arange(10, 20))
    block, stats = parse(data, chunk=50)
    assert np.array_equal(block.seq, np.arange(20))
    assert np.array_equal(block.counts, pattern(np.arange(20)))
    assert stats.resyncs == 1 and stats.skipped_bytes == SIZE


def test_frames_in_a_corrupted_stream_are_recovered_and_false_accepts_zero():
    rng = np.random.default_rng(7)
    seq = np.arange(20000)
    frames = frames_of(seq)
    hit = rng.random(len(seq)) < 0.05
    data = b"".join(corrupt_frame(f, rng) if h else f for f, h in zip(frames, hit, strict=True))
    block, stats = parse(data, chunk=1000)
    truth = pattern(block.seq)
    assert np.array_equal(block.counts, truth)  # nothing decoded that was not sent
    assert np.all(np.diff(block.seq) > 0)
    assert set(seq[~hit]) <= set(block.seq)  # every intact frame recovered
    assert stats.dropped == len(seq) - len(block)


def test_chunking_does_not_change_the_result_of_a_corrupted_stream():
    rng = np.random.default_rng(11)
    frames = frames_of(np.arange(600))
    data = b"".join(corrupt_frame(f, rng) if rng.random() < 0.2 else f for f in frames)
    whole, stats = parse(data)
    for chunk in (3, 61, 997):
        pieces, pieces_stats = parse(data, chunk=chunk)
        assert np.array_equal(pieces.seq, whole.seq)
        assert np.array_equal(pieces.counts, whole.counts)
        assert pieces_stats == dataclasses.replace(stats)


# --------------------------------------------------------------------------------------------------
# ASCII

ASCII = SerialImuProfile.load("imu_ascii")


def ascii_parse(text: bytes, chunk=None, fmt=ASCII.serial.frame):
    parser = AsciiLineParser(fmt, ASCII.imu.channels)
    step = chunk or max(len(text), 1)
    blocks = [parser.decode(text[i : i + step], 0.0).block for i in range(0, len(text), step)]
    return SampleBlock.concat(blocks), parser.stats


def test_ascii_lines_with_timestamp_partial_first_line_and_bad_lines():
    text = (b"34,5,6\r\n"  # tail of a line that began before the port was opened: discarded
            b"1000.5,1,-2,3,4,5,6\r\n"
            b"1001.0,1,2,3\r\n"  # too few fields
            b"1001.5, 7 , 8,9,10,11,-12\n"
            b"1002.0,1,2,x,4,5,6\n"  # not a number
            b"1002.5,1.5,2,3,4,5,6\n"  # decimals where the profile has none
            b"\n"
            b"1003.0,-1,-2,-3,-4,-5,-6\n1003.5,1,2")  # last line incomplete
    block, stats = ascii_parse(text, chunk=5)
    assert block.counts.tolist() == [[1, -2, 3, 4, 5, 6], [7, 8, 9, 10, 11, -12],
                                     [-1, -2, -3, -4, -5, -6]]
    assert np.allclose(block.device_time, [1.0005, 1.0015, 1.003])
    assert block.seq.tolist() == [0, 1, 2]
    assert (stats.samples, stats.bad_lines, stats.skipped_bytes) == (3, 3, 8)


def test_ascii_decoder_uses_whole_lines_and_everything_at_the_end():
    parser = AsciiLineParser(ASCII.serial.frame, ASCII.imu.channels)
    first = parser.decode(b"partial\n1.0,1,2,3,4,5,6\n2.0,1,2", 0.0)
    assert first.used == len(b"partial\n1.0,1,2,3,4,5,6\n") and len(first.block) == 1
    last = parser.decode(b",3", 0.0, final=True)  # an unterminated line is decided: dropped
    assert (last.used, len(last.block)) == (len(b"2.0,1,2,3"), 0)


def test_ascii_fixed_point_space_separated_round_trip():
    fmt = dataclasses.replace(ASCII.serial.frame, delimiter=" ", timestamp="last", time_scale=1.0,
                              decimals=3)
    counts = np.array([[1, -1, 1234, -1234, 0, 999999]] * 3)
    text = encode_lines(fmt, [0.0, 0.5, 1.0], counts)
    assert text.splitlines()[0] == b"0.001 -0.001 1.234 -1.234 0.000 999.999 0.0"
    block, _ = ascii_parse(b"garbage\n" + text.replace(b" ", b"  \t"), fmt=fmt)
    assert np.array_equal(block.counts, counts) and block.device_time.tolist() == [0.0, 0.5, 1.0]


def test_ascii_overlong_line_is_dropped_and_parsing_resumes():
    text = b"x\n" + b"9" * 5000 + b"\n1,1,2,3,4,5,6\n2,1,2,3,4,5,6\n"
    block, stats = ascii_parse(text, chunk=1000)
    # the overlong line is discarded, then the rest of it (up to its newline) as a partial line
    assert block.counts.tolist() == [[1, 2, 3, 4, 5, 6]] * 2
    assert stats.resyncs == 1


def test_truncated_frame_whose_crc_matches_by_chance_yields_to_the_next_frame():
    # frame 10 lost its last byte; with the next frame's first sync byte (A5) its 58-byte window
    # still has a valid CRC (searched for below), but its data is wrong. Frame 11 overlaps it and
    # follows it in sequence, so frame 10 must be dropped and frame 11 kept.
    for k in range(4096):
        window = manual_frame(10, 5000, [k] * 12)
        if window[-1] == 0xA5:
            break
    data = stream(np.arange(10)) + window[:-1] + stream(np.arange(11, 20))
    block, stats = parse(data, chunk=100)
    assert np.array_equal(block.seq, np.concatenate([np.arange(10), np.arange(11, 20)]))
    assert np.array_equal(block.counts, pattern(block.seq))
    assert (stats.gaps, stats.dropped) == (1, 1)


def test_byte_sum_checksum_and_length_field():
    """The OpenShoe-style frame (drivers/profiles/mimu4444.toml's language): a 16-bit byte sum over
    the sync byte on, and a length field every frame must carry with the profile's value."""
    assert CHECKSUMS["sum16"].of(b"123456789") == sum(b"123456789")
    assert CHECKSUMS["sum16"].of(b"\xff" * 300) == (255 * 300) % 65536
    fmt = dataclasses.replace(FMT, sync=b"\xaa", layout=("sync", "seq", "length", "time", "counts",
                                                          "crc"),
                              byte_order="big", count_type="int16", crc="sum16",
                              crc_covers_sync=True, length_type="uint8", length_value=52)
    seq = np.arange(40)
    counts = pattern(seq) % 2**16 - 2**15
    data = bytearray(encode_frames(fmt, seq, seq * 1000, counts))
    size = len(data) // 40
    assert size == 1 + 2 + 1 + 4 + 24 + 2 and data[3] == 52
    frame = bytes(data[:size])
    assert frame[-2:] == struct.pack(">H", sum(frame[:-2]) & 0xFFFF)
    # frame 10 claims another length, its byte sum made valid again: refused all the same
    bad = 10 * size
    data[bad + 3] = 53
    data[bad + size - 2 : bad + size] = struct.pack(">H", sum(data[bad : bad + size - 2]) & 0xFFFF)
    block, stats = parse(bytes(data), fmt=fmt)
    assert np.array_equal(block.seq, np.delete(seq, 10))
    assert np.array_equal(block.counts, np.delete(counts, 10, axis=0))
    assert stats.crc_failures == 1 and stats.dropped == 1


def test_a_resent_buffer_of_frames_is_dropped_not_a_restart():
    """A CRC-valid resend of several frames (an adapter repeating its buffer): each repeated frame
    is a duplicate of one of the last 16, so the numbering goes on without a restart."""
    seq = np.arange(100, 200)
    data = stream(seq)
    frame = len(data) // len(seq)
    for at, frames in ((10, 2), (40, 5), (80, 15)):  # repeat frames at-frames .. at-1 after at
        cut = (at + sum(f for a, f in ((10, 2), (40, 5), (80, 15)) if a < at)) * frame
        data = data[:cut] + data[cut - frames * frame:cut] + data[cut:]
    got, stats = parse(data, chunk=37)
    np.testing.assert_array_equal(got.seq, seq)
    np.testing.assert_array_equal(got.counts, pattern(seq))
    assert stats.duplicates == 22 and stats.restarts == 0 and stats.gaps == 0
