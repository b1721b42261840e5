"""Property tests: random and mutated byte streams into the binary and ASCII parsers.

No exception may escape, and every accepted binary frame must exist in the input with a correct
CRC (checked with the stdlib CRC, independent of drivers/wire/crc.py)."""

import binascii
import struct

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.profile import SerialImuProfile
from drivers.wire.ascii import AsciiLineParser
from drivers.wire.binary import BinaryFrameParser, encode_frames

PROFILE = SerialImuProfile.load("imu12_serial")
ASCII = SerialImuProfile.load("imu_ascii")
SETTINGS = settings(max_examples=150, deadline=None, derandomize=True)


def frame_bytes(seq_raw: int, ticks_raw: int, counts) -> bytes:
    """The wire bytes of a decoded frame, rebuilt with struct and binascii.crc_hqx."""
    body = struct.pack("<HI12i", seq_raw, ticks_raw, *counts)
    return b"\xa5\x5a" + body + struct.pack("<H", binascii.crc_hqx(body, 0xFFFF))


def feed_in_chunks(parser, data: bytes, cuts) -> list:
    bounds = sorted({0, len(data), *(c % (len(data) + 1) for c in cuts)})
    return [parser.decode(data[a:b], 0.0).block for a, b in zip(bounds, bounds[1:], strict=False)]


def assert_only_true_frames(blocks, data: bytes) -> None:
    """Each accepted frame appears verbatim, with a valid CRC, in the input; seq increases."""
    seq = []
    for block in blocks:
        for s, t, counts in zip(block.seq, block.device_time, block.counts, strict=True):
            ticks = int(round(t / 1e-6)) % 2**32
            assert frame_bytes(int(s) % 2**16, ticks, counts.tolist()) in data
            seq.append(int(s))
    assert all(b > a for a, b in zip(seq, seq[1:], strict=False))


@SETTINGS
@given(st.binary(max_size=3000), st.lists(st.integers(0, 3000), max_size=8))
def test_random_bytes_never_raise_and_never_yield_a_bad_frame(data, cuts):
    parser = BinaryFrameParser(PROFILE.serial.frame, PROFILE.imu.channels)
    assert_only_true_frames(feed_in_chunks(parser, data, cuts), data)


mutation = st.tuples(st.sampled_from(["flip", "delete", "insert", "sync"]),
                     st.integers(0, 10**6), st.integers(1, 80), st.binary(min_size=1, max_size=80))


@SETTINGS
@given(st.integers(0, 2**16 - 1), st.integers(5, 40), st.lists(mutation, max_size=12),
       st.lists(st.integers(0, 3000), max_size=8))
def test_mutated_frame_streams_yield_only_frames_that_were_sent(first, k, mutations, cuts):
    seq = first + np.arange(k)
    counts = (seq[:, None] * 7919 + np.arange(12) * 104729) % 2**32 - 2**31
    data = bytearray(encode_frames(PROFILE.serial.frame, seq, seq * 500, counts))
    for kind, where, length, payload in mutations:
        at = where % (len(data) + 1)
        if kind == "flip":
            data[at : at + len(payload)] = bytes(
                a ^ b for a, b in zip(data[at:], payload, strict=False))
        elif kind == "delete":
            del data[at : at + length]
        elif kind == "insert":
            data[at:at] = payload
        else:  # a stray sync word, the worst case for false locks
            data[at:at] = b"\xa5\x5a" + payload
    data = bytes(data)
    parser = BinaryFrameParser(PROFILE.serial.frame, PROFILE.imu.channels)
    assert_only_true_frames(feed_in_chunks(parser, data, cuts), data)


line = st.tuples(st.floats(0, 1e9),
                 st.lists(st.integers(-(2**40), 2**40), min_size=6, max_size=6)).map(
    lambda v: (",".join(map(str, [v[0], *v[1]])) + "\n").encode())
chunk = st.one_of(line, st.binary(max_size=60),
                  st.text(alphabet="0123456789,.-+ \n\re", max_size=60).map(str.encode))


@SETTINGS
@given(st.lists(chunk, max_size=30), st.lists(st.integers(0, 3000), max_size=8))
def test_ascii_parser_accepts_only_complete_well_formed_lines(pieces, cuts):
    data = b"".join(pieces)
    fmt = ASCII.serial.frame
    parser = AsciiLineParser(fmt, ASCII.imu.channels)
    blocks = feed_in_chunks(parser, data, cuts)
    # oracle: every complete line after the first newline: a float (ms) and 6 integers
    lines = set()
    for raw in data.split(b"\n")[1:-1]:
        try:
            fields = raw.decode("ascii").split(",")
            values = (float(fields[0]) * 0.001, *(int(v) for v in fields[1:]))
        except (ValueError, IndexError):
            continue
        if len(values) == 7:
            lines.add(values)
    for block in blocks:
        for t, counts in zip(block.device_time, block.counts, strict=True):
            assert (t, *counts.tolist()) in lines
