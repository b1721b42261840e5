"""Serial IMU link figures: parser speed, false locks, and a live stream through the pty twin.

    .venv/bin/python bench/serial.py [--frames 1000000] [--speed 25] [--json]

1. parser  : frames/s of BinaryFrameParser alone on the imu12_serial format (58-byte frames),
             fed in 64 KiB chunks, clean and with 1 % of frames corrupted.
2. offline : `--offline` frames, every one damaged by the twin's `corrupt_frame` (bytes flipped,
             deleted or inserted). Counts the corrupted candidates that CRC-16 alone accepts
             (false locks) and those the parser accepts (CRC and sequence check).
3. live    : the pty twin streams `--frames` frames at 2 kHz of simulated time on a ScaledClock
             `--speed` times faster than real time (10**6 frames = 500 s simulated), 1 % corrupted;
             the driver reads them in this process's main thread. Reports intact frames recovered,
             false accepts (decoded samples that differ from what was sampled), frames/s and the
             reader thread's CPU time.
"""

import sys
from pathlib import Path

# run as a script, this file's folder is sys.path[0] and its name would shadow pyserial's `serial`
sys.path[0] = str(Path(__file__).resolve().parents[1])

import argparse
import json
import time

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from drivers.clock import ScaledClock
from drivers.profile import SerialImuProfile
from drivers.serial_imu import SerialImu
from drivers.twins.serial import OVERFLOW, SENT, SerialTwin, corrupt_frame
from drivers.wire.binary import BinaryFrameParser, encode_frames
from drivers.wire.crc import CRCS

PROFILE = SerialImuProfile.load("imu12_serial")
FMT, CHANNELS = PROFILE.serial.frame, PROFILE.imu.channels


def source(times):
    """Full-range int32 counts, a known function of the sampling time."""
    n = np.round(np.asarray(times) * 1e6).astype(np.int64)
    return (n[:, None] * 2654435761 + np.arange(12) * 40503) % 2**32 - 2**31


def frames(seq) -> bytes:
    return encode_frames(FMT, seq, seq * 500, source(seq / 2000.0))


def corrupted(data: bytes, size: int, fraction: float, rng) -> bytes:
    """`data` with `fraction` of its frames damaged by corrupt_frame."""
    out, hit = [], rng.random(len(data) // size) < fraction
    for i in np.flatnonzero(hit):
        out.append((i, corrupt_frame(data[i * size : (i + 1) * size], rng)))
    pieces, start = [], 0
    for i, damaged in out:
        pieces += [data[start : i * size], damaged]
        start = (i + 1) * size
    return b"".join(pieces + [data[start:]])


def parse_all(data: bytes):
    parser = BinaryFrameParser(FMT, CHANNELS)
    t = time.perf_counter()
    blocks = [parser.decode(data[i : i + 65536], 0.0).block for i in range(0, len(data), 65536)]
    blocks.append(parser.decode(b"", 0.0, final=True).block)
    return blocks, time.perf_counter() - t, parser.stats


def bench_parser(n: int, rng) -> dict:
    data = frames(np.arange(n))
    blocks, clean_s, _ = parse_all(data)
    assert sum(map(len, blocks)) == n
    _, noisy_s, _ = parse_all(corrupted(data, len(data) // n, 0.01, rng))
    return {"frames": n, "frames_per_s": n / clean_s, "frames_per_s_1pct_corrupted": n / noisy_s}


def false_accepts(blocks, time_of=lambda seq: seq / 2000.0) -> int:
    """Decoded samples whose counts differ from what was sampled for their sequence number."""
    bad = 0
    for block in blocks:
        if len(block):
            bad += int(np.count_nonzero(np.any(block.counts != source(time_of(block.seq)), axis=1)))
    return bad


def bench_offline(n: int, rng) -> dict:
    """Every frame corrupted: false locks of CRC-16 alone versus the parser."""
    seq = np.arange(n)
    clean = frames(seq)
    size = len(clean) // n
    data = np.frombuffer(corrupted(clean, size, 1.0, rng), np.uint8)
    # CRC-16 alone: every sync-word position whose CRC matches
    starts = np.flatnonzero((data[:-1] == FMT.sync[0]) & (data[1:] == FMT.sync[1]))
    starts = starts[starts + size <= len(data)]
    rows = sliding_window_view(data, size)[starts]
    records = rows.view(PROFILE_DTYPE).reshape(-1)
    ok = CRCS[FMT.crc].rows(rows[:, len(FMT.sync) : size - 2]) == records["crc"]
    truth = source(records["seq"][ok] / 2000.0)  # a CRC-valid candidate is true only if it is
    crc_alone_false = int(np.count_nonzero(np.any(records["counts"][ok] != truth, axis=1)))
    blocks, _, stats = parse_all(data.tobytes())
    return {"corrupted_frames": n, "sync_candidates": len(starts),
            "crc16_alone_false_accepts": crc_alone_false,
            "parser_accepted": int(sum(map(len, blocks))),
            "parser_false_accepts": false_accepts(blocks),
            "crc_failures": stats.crc_failures}


def bench_live(n: int, speed: float, corrupt: float, seed: int) -> dict:
    clock = ScaledClock(speed=speed)
    twin = SerialTwin(PROFILE, source, clock=clock, corrupt=corrupt, seed=seed, max_lag=5.0)
    imu = SerialImu(twin.port, PROFILE, clock=clock)
    got, bad = [], 0
    with twin, imu:
        wall0, cpu0, last = time.perf_counter(), time.thread_time(), -1
        while last < n - 1:
            block = imu.read_block(timeout=5.0)
            if block is None:
                raise RuntimeError("the twin stopped streaming")
            bad += false_accepts([block], twin.time_of)
            got.append(block.seq)
            last = int(block.seq[-1])
        wall, cpu = time.perf_counter() - wall0, time.thread_time() - cpu0
    seq = np.concatenate(got)
    sent, fate = twin.log()
    span = (sent >= seq[0]) & (sent <= seq[-1])
    intact = sent[span & (fate == SENT)]
    return {
        "frames": int(seq[-1] - seq[0] + 1), "rate_hz": PROFILE.imu.rate_hz, "clock_speed": speed,
        "corrupted_fraction": corrupt, "intact_sent": len(intact),
        "intact_recovered": int(np.isin(intact, seq).sum()), "decoded": len(seq),
        "false_accepts": bad, "twin_overflow_frames": int(np.count_nonzero(fate[span] == OVERFLOW)),
        "wall_s": wall, "frames_per_s": len(seq) / wall, "reader_cpu_s": cpu,
        "reader_cpu_fraction": cpu / wall, "reader_cpu_us_per_frame": 1e6 * cpu / len(seq),
        "stats": vars(imu.stats),
    }


PROFILE_DTYPE = BinaryFrameParser(FMT, CHANNELS).dtype


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=1_000_000, help="live frames (default 10**6)")
    parser.add_argument("--offline", type=int, default=1_000_000, help="offline corrupted frames")
    parser.add_argument("--parser-frames", type=int, default=500_000)
    parser.add_argument("--speed", type=float, default=25.0,
                        help="ScaledClock speed of the live run")
    parser.add_argument("--corrupt", type=float, default=0.01)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    result = {"parser": bench_parser(args.parser_frames, rng),
              "offline": bench_offline(args.offline, rng),
              "live": bench_live(args.frames, args.speed, args.corrupt, args.seed)}
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        for section, figures in result.items():
            print(f"[{section}]")
            for key, value in figures.items():
                print(f"  {key:32s} {value:.6g}" if isinstance(value, float)
                      else f"  {key:32s} {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
