"""Synthetic calibration records for the record store's tests and bench/records.py: a 6-sensor
unit (gyro and accelerometer triads), each sensor's bias, scale factor and white-noise density with
their 1-sigma, in SI units. Not calibrations of anything: the store's behaviour, not the solver's,
is under test with them.

    python tests/recordmaker.py URL COUNT SEED   # a writer: COUNT records (0: until killed),
                                                 # "ready" on stdout after the first
"""

import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from station.records.record import Parameter, Record  # noqa: E402

SENSORS = ("gx", "gy", "gz", "ax", "ay", "az")
UNITS = {"g": ("rad/s", "rad/s sqrt(s)"), "a": ("m/s^2", "m/s^2 sqrt(s)")}
START = datetime(2026, 11, 2, 8, 0, tzinfo=UTC)


def when(k: int, step_minutes: float = 10.0) -> str:
    """The k-th calibration time from START, ISO 8601 UTC to the second."""
    t = START + timedelta(minutes=k * step_minutes)
    return t.isoformat(timespec="seconds").replace("+00:00", "Z")


def synthetic_record(rng: np.random.Generator, serial: str, created: str, model: str = "imu6",
                     bench: str = "bench1", session: str | None = None,
                     rate_error: float | None = None, verdict: str = "PASS") -> Record:
    """One record of 18 parameters (bias, scale_factor, noise_white per sensor) drawn from `rng`."""
    params = []
    for s in SENSORS:
        unit, density = UNITS[s[0]]
        scale = 0.005 if s[0] == "g" else 0.05
        params += [Parameter("bias", s, float(rng.normal(0, scale)), scale / 20, unit),
                   Parameter("scale_factor", s, float(1 + rng.normal(0, 0.002)), 1e-4, "1"),
                   Parameter("noise_white", s, float(abs(rng.normal(1e-4, 1e-5))), 3e-6, density)]
    return Record(unit_serial=serial, kind="session", created=created,
                  calibration_sha256=rng.bytes(32).hex(), parameters=tuple(params), model=model,
                  verdict=verdict, bench=bench, session_sha256=session,
                  table_rate_error=rate_error, chi2=float(rng.chisquare(200)), dof=200,
                  positions=20, method="pca+ml", station_version="0.1.0")


def write(url: str, count: int, seed: int) -> None:
    """Write `count` records (0: forever) to the store at `url`, one transaction each."""
    from station.records.store import open_store

    rng = np.random.default_rng(seed)
    with open_store(url) as store:
        k = 0
        while count == 0 or k < count:
            store.add(synthetic_record(rng, f"SN{seed}-{k % 50}", when(k), session=f"s{seed}-{k}"))
            if k == 0:
                print("ready", flush=True)
            k += 1


if __name__ == "__main__":
    write(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]))
