"""The calibration record store at a line's scale (issue 33): synthetic records of 200 units over
3 benches (tests/recordmaker.py: 6 sensors, 18 parameters each), written one transaction per
record as a station writes them, into SQLite (a file, WAL, synchronous=FULL) and PostgreSQL (a
throwaway cluster with fsync on, tests/pgserver.py; skipped without PostgreSQL). Prints the insert
rate, the time of a unit's history and of the fleet report over all records (targets: <= 1 s and
<= 10 s), and the store's size per record.

    .venv/bin/python -P bench/records.py [--records 100000] [--json]
"""

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from recordmaker import synthetic_record, when  # noqa: E402

from station.records.analysis import fleet, history  # noqa: E402
from station.records.query import Selection  # noqa: E402
from station.records.store import open_store  # noqa: E402

UNITS, BENCHES, PER_SESSION = 200, 3, 4  # units calibrated 4 to a session on a bench


def fill(store, n: int, seed: int = 1) -> float:
    """Write n records (one transaction each); seconds taken."""
    rng = np.random.default_rng(seed)
    start = time.perf_counter()
    for k in range(n):
        session = k // PER_SESSION
        store.add(synthetic_record(
            rng, f"SN{k % UNITS:04d}", when(k, 1.0), model=f"imu6-{k % 2}",
            bench=f"bench{session % BENCHES + 1}", session=f"session-{session}",
            rate_error=float(rng.normal(0, 1e-5))))
    return time.perf_counter() - start


def queries(store) -> dict:
    """Seconds of a unit's history (with its drift) and of the fleet report over every record."""
    start = time.perf_counter()
    h = history(store.history("SN0007"), "SN0007")
    history_s = time.perf_counter() - start
    start = time.perf_counter()
    report = fleet(store, Selection())
    return {"history_s": history_s, "history_records": len(h["calibrations"]),
            "fleet_s": time.perf_counter() - start, "fleet_records": report["records"]}


def sqlite_size(url: str, store) -> int:
    """Bytes of the SQLite file once its write-ahead log is checkpointed."""
    with store.transaction():
        pass
    store.connection.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    return Path(url.removeprefix("sqlite:///")).stat().st_size


def pg_size(store) -> int:
    """Bytes of the PostgreSQL database."""
    with store.transaction() as cur:
        cur.execute("SELECT pg_database_size(current_database())")
        return int(cur.fetchone()[0])


def measure(url: str, n: int, size) -> dict:
    """Fill a store, query it, size it."""
    with open_store(url) as store:
        empty = size(store)
        seconds = fill(store, n)
        figures = queries(store)
        full = size(store)
    return {"records": n, "insert_per_s": n / seconds, **figures,
            "bytes_per_record": (full - empty) / n}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=100_000)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        url = f"sqlite:///{Path(tmp) / 'station.db'}"
        out["sqlite"] = measure(url, args.records, lambda s: sqlite_size(url, s))
    if not args.json:
        say("sqlite", out["sqlite"])  # at once: the PostgreSQL run takes as long again
    from pgserver import binaries, start_cluster

    if binaries() is None:
        out["postgresql"] = "skipped: no PostgreSQL binaries"
    else:
        cluster = start_cluster(durable=True)
        try:
            out["postgresql"] = measure(cluster.new_database(), args.records, pg_size)
        finally:
            cluster.stop()
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        say("postgresql", out["postgresql"])


def say(backend: str, f) -> None:
    """One backend's figures in words."""
    if isinstance(f, str):
        print(f"{backend}: {f}", flush=True)
        return
    print(f"{backend}: {f['records']} records, {f['insert_per_s']:.0f} records/s inserted "
          f"(one transaction each); history of a unit ({f['history_records']} records) "
          f"{f['history_s']:.3f} s; fleet report over {f['fleet_records']} records "
          f"{f['fleet_s']:.2f} s; {f['bytes_per_record']:.0f} bytes per record", flush=True)


if __name__ == "__main__":
    main()
