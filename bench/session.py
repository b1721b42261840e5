"""Speed of the session file: append throughput, flush cost, read-back speed and size.

Records `--seconds` of a 12-channel int32 stream at `--rate` Hz, delivered as the drivers deliver it
(blocks of `--block` samples), plus one table state per block, through `SessionWriter` with the
default 1 s flush interval; then times explicit flushes of one second of buffered samples, event
flushes (an event with nothing else buffered), and reading the stream back with `Session`.
Targets: append far above real time (>= 100x the 2000 Hz stream), flush of 1 s of data well under
the 1 s interval. Prints a table, or one JSON object with --json.
"""

import argparse
import json
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from drivers.samples import SampleBlock
from station.session import Session, SessionWriter, StreamSpec

M = 12
STATE = SimpleNamespace(time=0.0, rate=1.0, angle=0.0, rate_setpoint=1.0, running=True, ready=True,
                        moving=True, at_rate=True, fault=False)


def blocks(rate: float, seconds: float, block: int, seed: int = 0):
    """The samples of `seconds` at `rate` Hz as SampleBlocks of `block` samples (made up front)."""
    rng = np.random.default_rng(seed)
    total = int(rate * seconds)
    counts = rng.integers(-(2**20), 2**20, size=(total, M))
    seq = np.arange(total, dtype=np.int64)
    t = seq / rate
    return [SampleBlock(counts[i:i + block], seq[i:i + block], t[i:i + block], t[i:i + block])
            for i in range(0, total, block)]


def new_writer(path, rate, flush_interval=1.0):
    spec = StreamSpec([f"g{i}" for i in range(M)], "rad/s", 1e6, rate)
    return SessionWriter.create(path, {"protocol": "bench", "unit_serial": "B1"}, {"imu": spec},
                                flush_interval=flush_interval, overwrite=True)


def append_throughput(path, rate, seconds, block) -> dict:
    """Samples per second through append (+ one table state per block), flushes included."""
    data = blocks(rate, seconds, block)
    w = new_writer(path, rate)
    t0 = time.perf_counter()
    for b in data:
        w.append("imu", b)
        w.append_table(STATE)
    w.close()
    elapsed = time.perf_counter() - t0
    samples = sum(len(b) for b in data)
    return {"samples": samples, "append_s": elapsed, "samples_per_s": samples / elapsed,
            "realtime_factor": samples / rate / elapsed,
            "mb_per_hour": Path(path).stat().st_size / seconds * 3600 / 1e6}


def flush_costs(path, rate, block, repeats) -> dict:
    """Seconds per flush of one second of buffered samples, and per event flush."""
    data = blocks(rate, 1.0, block)
    w = new_writer(path, rate, flush_interval=3600.0)
    data_s, event_s = [], []
    for _ in range(repeats):
        for b in data:
            w.append("imu", b)
        t0 = time.perf_counter()
        w.flush()
        t1 = time.perf_counter()
        w.event("note", None, {"text": "bench"})
        data_s.append(t1 - t0)
        event_s.append(time.perf_counter() - t1)
    w.close()
    return {"flush_1s_median_ms": 1e3 * float(np.median(data_s)),
            "flush_1s_max_ms": 1e3 * max(data_s),
            "event_flush_median_ms": 1e3 * float(np.median(event_s)),
            "event_flush_max_ms": 1e3 * max(event_s)}


def read_back(path) -> dict:
    """Seconds to open the file and read the whole stream."""
    t0 = time.perf_counter()
    with Session.open(path) as s:
        k = len(s.stream("imu").seq)
    elapsed = time.perf_counter() - t0
    return {"read_s": elapsed, "read_samples_per_s": k / elapsed}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rate", type=float, default=2000.0, help="sample rate, Hz")
    p.add_argument("--seconds", type=float, default=300.0, help="recorded duration, s")
    p.add_argument("--block", type=int, default=20, help="samples per driver block")
    p.add_argument("--repeats", type=int, default=20, help="flushes timed")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.h5"
        figures = {"rate_hz": args.rate, "channels": M, "block": args.block,
                   **append_throughput(path, args.rate, args.seconds, args.block),
                   **read_back(path),
                   **flush_costs(Path(tmp) / "flush.h5", args.rate, args.block, args.repeats)}
    if args.json:
        print(json.dumps(figures))
        return
    for key, value in figures.items():
        print(f"{key:24s} {value:12.4g}" if isinstance(value, float) else f"{key:24s} {value:12d}")


if __name__ == "__main__":
    main()
