"""Serial IMU link figures: parser speed, false locks, and live streams through the pty twin.

    .venv/bin/python bench/serial.py [--frames 1000000] [--speed 25] [--parts parser ...] [--json]

1. parser  : frames/s (CPU time) of BinaryFrameParser alone on every binary profile of PROFILES
             (imu12_serial, the current layout, beside the real formats), fed in 64 KiB chunks,
             clean and with 1 % of frames corrupted; beside the baseline of the same clean bytes
             viewed at once with numpy frombuffer, decoded and checked (its ratio: the parser's
             search, sequence check and bookkeeping).
2. offline : per binary profile, `--offline` frames, every one damaged by the twin's
             `corrupt_frame` (bytes flipped, deleted or inserted). Counts the corrupted candidates
             that the profile's check alone accepts (false locks of the check) and those the
             parser accepts (check, constants and sequence), and their rates per corrupted frame.
3. checks  : the same with the imu12_serial layout carrying each check of CHECKSUMS in turn
             (CRC-8/16/32 variants, byte sums, two's-complement sum, XOR, Fletcher-16).
4. ascii   : `--offline` $VNIMU sentences (vectornav_ascii), every one damaged: sentences whose
             `*hh` XOR still holds (check alone) and samples the parser returns that were never
             sent.
5. live    : the pty twin streams `--frames` imu12_serial frames at 2 kHz of simulated time on a
             ScaledClock `--speed` times faster than real time (10**6 frames = 500 s simulated),
             1 % corrupted; the driver reads them in this process's main thread. Reports intact
             frames recovered, false accepts (decoded samples that differ from what was sampled),
             frames/s and the reader thread's CPU time.
6. real_rate : each real format's twin at its device's own rate on the wall clock for
             `--live-seconds`, 1 % corrupted, through the serial driver.
"""

import sys
from pathlib import Path

# run as a script, this file's folder is sys.path[0] and its name would shadow pyserial's `serial`
sys.path[0] = str(Path(__file__).resolve().parents[1])

import argparse
import dataclasses
import json
import time

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from drivers.clock import ScaledClock, WallClock
from drivers.profile import SerialImuProfile
from drivers.samples import SampleBlock
from drivers.serial_imu import SerialImu
from drivers.twins.serial import OVERFLOW, SENT, SerialTwin, corrupt_frame
from drivers.wire.ascii import AsciiLineParser, encode_lines
from drivers.wire.binary import BinaryFrameParser, encode_frames
from drivers.wire.crc import CHECKSUMS

PROFILE = SerialImuProfile.load("imu12_serial")
FMT, CHANNELS = PROFILE.serial.frame, PROFILE.imu.channels
PROFILES = ("imu12_serial", "mimu4444", "xsens_mtdata2", "vectornav_binary")
REAL_RATE = ("mimu4444", "xsens_mtdata2", "vectornav_binary", "vectornav_ascii")
TARGETS = {"imu12_serial": 3e6, "xsens_mtdata2": 2e6}
"""Issue 35's acceptance: clean frames/s of the parser (64 KiB chunks, CPU time)."""
PARTS = ("parser", "offline", "checks", "ascii", "live", "real_rate")
SPANS = {"m/s^2": 1_500_000, "rad/s": 3_000_000, "T": 50_000, "K": 200}
"""Count ranges of the real formats' sources per unit: float32 carries every such count exactly."""


def source(times):
    """Full-range int32 counts, a known function of the sampling time."""
    n = np.round(np.asarray(times) * 1e6).astype(np.int64)
    return (n[:, None] * 2654435761 + np.arange(12) * 40503) % 2**32 - 2**31


def source_for(profile):
    """imu12_serial: `source`; other profiles: counts that are a known function of the sampling
    time (0.1 ms resolution) within ranges their fields carry exactly (int16 for the MIMU4444;
    SPANS for float fields; temperatures around 25 degrees C)."""
    if profile.imu.name == PROFILE.imu.name:
        return source
    binary = profile.serial.protocol == "binary" and not profile.serial.frame.fields
    span = np.array([30000 if binary else SPANS[u] for u in profile.imu.units], dtype=np.int64)
    base = np.array([29815 if u == "K" else 0 for u in profile.imu.units], dtype=np.int64)

    def counts(times):
        n = np.round(np.asarray(times) * 1e4).astype(np.int64)
        return base + (n[:, None] * 2654435761 + np.arange(len(span)) * 40503) % (2 * span + 1) \
            - span
    return counts


def encoded(profile, n: int) -> tuple:
    """(bytes, counts) of frames 0..n-1 of a binary profile at its rate."""
    fmt, imu = profile.serial.frame, profile.imu
    seq = np.arange(n)
    times = 1000.0 + seq / imu.rate_hz
    counts = source_for(profile)(times)
    ticks = (np.round(times / fmt.time_tick).astype(np.int64) if np.isfinite(fmt.time_tick)
             else seq)
    return encode_frames(fmt, seq, ticks, counts, imu.channels, imu.scale), counts


def corrupted(data: bytes, size: int, fraction: float, rng) -> tuple:
    """`data` with `fraction` of its frames damaged by corrupt_frame, and the offset of every
    frame in the result."""
    n = len(data) // size
    hit = rng.random(n) < fraction
    pieces, lengths, start = [], np.full(n, size), 0
    for i in np.flatnonzero(hit):
        damaged = corrupt_frame(data[i * size : (i + 1) * size], rng)
        pieces += [data[start : i * size], damaged]
        lengths[i] = len(damaged)
        start = (i + 1) * size
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    return b"".join(pieces + [data[start:]]), starts


def parser_of(profile) -> BinaryFrameParser:
    return BinaryFrameParser(profile.serial.frame, profile.imu.channels, profile.imu.scale)


def parse_all(profile, data: bytes):
    """The blocks, CPU seconds and stats of the parser fed `data` in 64 KiB chunks."""
    parser = parser_of(profile)
    t = time.process_time()
    blocks = [parser.decode(data[i : i + 65536], 0.0).block for i in range(0, len(data), 65536)]
    blocks.append(parser.decode(b"", 0.0, final=True).block)
    return blocks, time.process_time() - t, parser.stats


def frombuffer_seconds(profile, data: bytes, n: int) -> float:
    """CPU seconds of the baseline: the clean bytes viewed as n frames at once (numpy
    frombuffer), every field decoded and every check computed, nothing searched or kept."""
    parser = parser_of(profile)
    layout, start = parser.layout, parser.size - parser.crc.size
    t = time.process_time()
    rows = np.frombuffer(data, np.uint8).reshape(n, parser.size)
    records = rows.view(parser.dtype).reshape(-1)
    layout.seq(records), layout.ticks(records), layout.samples(records)
    first = 0 if profile.serial.frame.crc_covers_sync else len(profile.serial.frame.sync)
    assert np.all(parser.crc.rows(rows[:, first:start]) == records["crc"])
    return time.process_time() - t


def bench_parser(profile, n: int, rng, target=None) -> dict:
    """Frames/s of CPU time, clean and 1 % corrupted, beside the frombuffer baseline (the
    median of 3 interleaved pairs: a busy host slows both alike), and whether the clean figure
    meets `target` (frames/s) if given."""
    data, _ = encoded(profile, n)
    size = len(data) // n
    pairs = []
    for _ in range(3):
        blocks, clean_s, _ = parse_all(profile, data)
        assert sum(map(len, blocks)) == n
        pairs.append((clean_s, frombuffer_seconds(profile, data, n)))
    clean_s, base_s = sorted(pairs, key=lambda p: p[0] / p[1])[1]
    _, noisy_s, _ = parse_all(profile, corrupted(data, size, 0.01, rng)[0])
    figures = {"frame_bytes": size, "check": profile.serial.frame.crc, "frames": n,
               "frames_per_s": n / clean_s, "frames_per_s_1pct_corrupted": n / noisy_s,
               "mbytes_per_s": n * size / clean_s / 1e6,
               "frombuffer_frames_per_s": n / base_s, "parser_over_frombuffer": clean_s / base_s}
    if target:
        figures |= {"target_frames_per_s": target, "meets_target": n / clean_s >= target}
    return figures


def check_alone_false_accepts(profile, clean: bytes, data: bytes, starts, n: int) -> tuple:
    """(sync candidates, candidates whose check holds although their bytes are not the frame
    they claim to be): the false locks of the check without constants or sequence test."""
    parser = parser_of(profile)
    size, layout, check = parser.size, parser.layout, parser.crc
    buf = np.frombuffer(data, np.uint8)
    pos = parser._sync_positions(buf)
    pos = pos[pos + size <= len(buf)]
    rows = sliding_window_view(buf, size)[pos]
    records = rows.view(parser.dtype).reshape(-1)
    first = 0 if profile.serial.frame.crc_covers_sync else len(profile.serial.frame.sync)
    ok = check.rows(rows[:, first : size - check.size]) == records["crc"]
    clean_rows = np.frombuffer(clean, np.uint8).reshape(n, size)
    clean_seq = layout.seq(clean_rows.view(parser.dtype).reshape(-1))
    k = np.searchsorted(starts, pos[ok], side="right") - 1  # the frame each candidate lies in
    m = layout.seq_modulus
    j = k + (layout.seq(records[ok]) - clean_seq[k] + m // 2) % m - m // 2  # the one it claims
    inside = (j >= 0) & (j < n)
    same = np.zeros(len(j), bool)
    same[inside] = np.all(rows[ok][inside] == clean_rows[j[inside]], axis=1)
    return len(pos), int(np.count_nonzero(~same))


def parser_false_accepts(profile, blocks, counts) -> int:
    """Samples the parser returned that differ from the frame their sequence number names."""
    block = SampleBlock.concat([b for b in blocks if len(b)] or blocks[:1])
    if not len(block):
        return 0
    layout = parser_of(profile).layout
    first, _ = encoded(profile, 1)
    seq0 = layout.seq(np.frombuffer(first, np.uint8).view(parser_of(profile).dtype))[0]
    j = block.seq - seq0
    inside = (j >= 0) & (j < len(counts))
    bad = ~inside
    bad[inside] = np.any(block.counts[inside] != counts[j[inside]], axis=1)
    return int(np.count_nonzero(bad))


def bench_offline(profile, n: int, rng) -> dict:
    """Every frame corrupted: false locks of the check alone versus the parser."""
    clean, counts = encoded(profile, n)
    size = len(clean) // n
    data, starts = corrupted(clean, size, 1.0, rng)
    candidates, alone = check_alone_false_accepts(profile, clean, data, starts, n)
    blocks, _, stats = parse_all(profile, data)
    accepted = int(sum(map(len, blocks)))
    false = parser_false_accepts(profile, blocks, counts)
    return {"check": profile.serial.frame.crc, "corrupted_frames": n,
            "sync_candidates": candidates, "check_alone_false_accepts": alone,
            "check_alone_false_lock_rate": alone / n, "parser_accepted": accepted,
            "parser_false_accepts": false, "parser_false_lock_rate": false / n,
            "crc_failures": stats.crc_failures}


def with_check(name: str):
    """imu12_serial with its CRC replaced by check `name`."""
    return dataclasses.replace(PROFILE, serial=dataclasses.replace(
        PROFILE.serial, frame=dataclasses.replace(FMT, crc=name)))


def bench_ascii(n: int, rng) -> dict:
    """Every $VNIMU sentence corrupted: check alone versus the parser."""
    profile = SerialImuProfile.load("vectornav_ascii")
    fmt, imu = profile.serial.frame, profile.imu
    times = 1000.0 + np.arange(n) / imu.rate_hz
    counts = source_for(profile)(times)
    lines = encode_lines(fmt, times, counts, imu.channels).splitlines(keepends=True)
    sent = set(lines)
    damaged = [corrupt_frame(line, rng) for line in lines]
    data = b"".join(damaged)
    alone = 0
    for line in data.split(b"\n"):
        body, star, check = line.strip()[1:].rpartition(b"*")
        if star and len(check) == 2 and line.strip()[:1] == b"$" and line + b"\n" not in sent:
            xor = 0
            for byte in body:
                xor ^= byte
            alone += check.upper() == f"{xor:02X}".encode()
    parser = AsciiLineParser(fmt, imu.channels)
    block = SampleBlock.concat([parser.decode(data, 0.0).block,
                                parser.decode(b"", 0.0, final=True).block])
    weights = np.random.default_rng(0).integers(1, 2**62, len(imu.channels))
    false = int(np.count_nonzero(~np.isin(block.counts @ weights, counts @ weights)))
    return {"check": "xor8 (*hh)", "corrupted_lines": n, "check_alone_false_accepts": alone,
            "check_alone_false_lock_rate": alone / n, "parser_accepted": len(block),
            "parser_false_accepts": false, "parser_false_lock_rate": false / n,
            "bad_lines": parser.stats.bad_lines}


def bench_real_rate(name: str, seconds: float, corrupt: float, seed: int) -> dict:
    """The twin of profile `name` at the device's rate (wall clock) through the driver."""
    profile = SerialImuProfile.load(name)
    counts_of = source_for(profile)
    clock = WallClock()
    twin = SerialTwin(profile, counts_of, clock=clock, corrupt=corrupt, seed=seed)
    blocks = []
    with twin, SerialImu(twin.port, profile, clock=clock) as imu:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            block = imu.read_block(timeout=0.5)
            if block is not None:
                blocks.append(block)
    got = SampleBlock.concat(blocks)
    seq, fate = twin.log()
    weights = np.random.default_rng(0).integers(1, 2**62, len(profile.imu.channels))
    key_of_sent = counts_of(twin.time_of(seq)) @ weights
    order = np.argsort(key_of_sent)
    at = np.searchsorted(key_of_sent[order], got.counts @ weights).clip(0, len(seq) - 1)
    known = key_of_sent[order][at] == got.counts @ weights
    frames = seq[order][at][known]
    span = (seq > frames.min()) & (seq <= frames.max())
    intact = seq[span & (fate == SENT)]
    return {"rate_hz": profile.imu.rate_hz, "seconds": seconds, "corrupted_fraction": corrupt,
            "frames_sent": int(np.count_nonzero(span)), "intact_sent": len(intact),
            "intact_recovered": int(np.isin(intact, frames).sum()), "decoded": len(got),
            "false_accepts": int(np.count_nonzero(~known)),
            "twin_overflow_frames": int(np.count_nonzero(fate[span] == OVERFLOW)),
            "stats": vars(imu.stats)}


def false_accepts(blocks, time_of=lambda seq: seq / 2000.0) -> int:
    """Decoded samples whose counts differ from what was sampled for their sequence number."""
    bad = 0
    for block in blocks:
        if len(block):
            bad += int(np.count_nonzero(np.any(block.counts != source(time_of(block.seq)), axis=1)))
    return bad


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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=1_000_000, help="live frames (default 10**6)")
    parser.add_argument("--offline", type=int, default=1_000_000, help="offline corrupted frames")
    parser.add_argument("--parser-frames", type=int, default=500_000)
    parser.add_argument("--speed", type=float, default=25.0,
                        help="ScaledClock speed of the live run")
    parser.add_argument("--corrupt", type=float, default=0.01)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--live-seconds", type=float, default=20.0,
                        help="wall seconds of each real format's twin at its own rate")
    parser.add_argument("--skip-checks", action="store_true",
                        help="skip the per-check offline runs (15 x --offline frames)")
    parser.add_argument("--parts", nargs="+", choices=PARTS, default=list(PARTS),
                        help="the parts to run (default all)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    profiles = {name: SerialImuProfile.load(name) for name in PROFILES}
    parts = {
        "parser": lambda: {name: bench_parser(p, args.parser_frames, rng, TARGETS.get(name))
                           for name, p in profiles.items()},
        "offline": lambda: {name: bench_offline(p, args.offline, rng)
                            for name, p in profiles.items()},
        "checks": lambda: {} if args.skip_checks else {
            name: bench_offline(with_check(name), args.offline, rng) for name in CHECKSUMS},
        "ascii": lambda: bench_ascii(args.offline, rng),
        "live": lambda: bench_live(args.frames, args.speed, args.corrupt, args.seed),
        "real_rate": lambda: {name: bench_real_rate(name, args.live_seconds, args.corrupt,
                                                    args.seed) for name in REAL_RATE},
    }
    result = {name: parts[name]() for name in PARTS if name in args.parts}
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        show(result)
    return 0


def show(figures: dict, indent: str = "") -> None:
    """Print nested figures as indented `key value` lines."""
    for key, value in figures.items():
        if isinstance(value, dict):
            print(f"{indent}[{key}]")
            show(value, indent + "  ")
        else:
            print(f"{indent}{key:34s} {value:.6g}" if isinstance(value, float)
                  else f"{indent}{key:34s} {value}")


if __name__ == "__main__":
    sys.exit(main())
