"""The IMU samples of a flight-controller log (PX4 ULog: station/imports/ulog.py, ArduPilot
DataFlash: station/imports/dataflash.py) into a session file: one stream per sensor (`acc`
in m/s^2, `gyro` in rad/s), each sample at its own logged time stamp.

The logs hold float32 (or float64) numbers; the session holds integer counts. Each channel's
scale is a power of two, 2^k counts per SI unit, k the smallest that makes every value of the
channel an integer (while the counts stay below 2^53, exact in float64): the session's SI values
(counts / 2^k) are then the logged numbers bit for bit. A channel whose values cannot all be
exact within 2^53 counts (values spanning more than 53 binary orders of magnitude, or computed
ones such as vehicle_imu's delta / dt) is rounded to 2^-k, the largest error said in the notes.
Integer counts logged with a scale (the DataFlash batch sampler's int16 and its multiplier) are
kept as they are, with that scale.

Every log is untrusted input: a sensor with fewer than 2 samples, non-finite values, time stamps
that repeat with other values or go backwards are refused naming the file, the topic or message,
the instance and the first place; a message logged twice (same time stamp, same values) is
dropped and counted in the notes.
"""

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.samples import SampleBlock
from station.errors import CalibrationInputError
from station.imports.recordings import _Fixed, _log_notes, _sha256
from station.session import SessionWriter, StreamSpec

log = logging.getLogger(__name__)

EXACT_BITS = 53
"""Counts stay below 2^EXACT_BITS so that counts / 2^k is exact in float64."""

SPLIT_ADVICE = ("Export the part you need (pyulog's ulog2csv, pymavlink's mavlogdump.py "
                "--format csv) and import it with `station import csv`, or choose another "
                "--instance.")
"""What to do with a log whose sensor samples cannot be used as they are."""


@dataclass(frozen=True)
class Series:
    """One sensor's samples in a log: `time_us` (K,) time stamps in microseconds, `values`
    (K, 3) in the SI `unit` (m/s^2 or rad/s), `where` (e.g. "topic sensor_accel instance 1") for
    messages, `origin` (topic or message, instance, device id, temperature, ...) for the
    metadata; `scale`: the values are integer counts logged with this many per SI unit (kept as
    they are), None: numbers in the unit (stored exactly, `exact_counts`)."""

    time_us: np.ndarray
    values: np.ndarray
    unit: str
    where: str
    origin: dict
    scale: float | None = None


def write_session(out, path, fmt: str, series: dict, reader: str, notes: list, *,
                  unit_serial: str = "IMPORTED") -> Path:
    """A new session `out` with one stream per entry of `series` (name -> Series) read from the
    log `path` of format `fmt` ("ulog", "dataflash") by `reader` (library and version); the notes
    (how the log was read) kept in metadata `import.notes` and logged."""
    path = Path(path)
    notes = list(notes)
    specs, blocks, origin = {}, {}, {}
    for name, s in series.items():
        t_us, values = checked(path, s, notes)
        if s.scale is None:
            counts, scale = exact_counts(values, f"{path.name}: {s.where}", notes)
        else:
            counts, scale = values.astype(np.int64), s.scale
        seq, step = sample_numbers(t_us)
        specs[name] = StreamSpec([f"{name}{i + 1}" for i in range(values.shape[1])], s.unit,
                                 scale, 1e6 / step, "int64", f"imported-{fmt}")
        t = t_us * 1e-6
        blocks[name] = SampleBlock(counts, seq, t, t, specs[name].channels)
        origin[name] = s.origin
        device = f", device id {s.origin['device_id']}" if "device_id" in s.origin else ""
        notes.append(f"{path.name}: {name} from {s.where}{device} (read with {reader}): "
                     f"{len(t)} samples, {t[-1] - t[0]:.3f} s at {1e6 / step:.4f} Hz, "
                     f"{seq[-1] + 1 - len(t)} missing (logger gaps); own time stamps")
    sha = _sha256(path)
    metadata = {"protocol": "import", "unit_serial": unit_serial,
                "import": {"format": fmt, "reader": reader, "origin": origin,
                           "streams": {n: {"unit": s.unit, "raw_counts": False}
                                       for n, s in series.items()},
                           "sources": {n: {"path": str(path), "sha256": sha} for n in series},
                           "notes": notes}}
    _log_notes(notes)
    start = min(float(b.host_time[0]) for b in blocks.values())
    with SessionWriter.create(out, metadata, specs, clock=_Fixed(start)) as w:
        for name, block in blocks.items():
            w.append(name, block)
    return Path(out)


def summary(values: np.ndarray) -> dict:
    """First, min, mean and max of the finite values (a sensor's temperature, deg C), {} when
    none is finite."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if not len(v):
        return {}
    return {"first": float(v[0]), "min": float(v.min()), "mean": float(v.mean()),
            "max": float(v.max())}


def checked(path: Path, s: Series, notes: list) -> tuple:
    """(time stamps, values) of a sensor's samples: at least 2, finite, times strictly
    increasing once exact repeats (a message logged twice) are dropped (counted in `notes`)."""
    t, v = np.asarray(s.time_us, float), np.asarray(s.values, float)
    where = f"{path}: {s.where}"
    if v.ndim != 2 or len(t) != len(v):
        raise CalibrationInputError(f"{where}: {len(t)} time stamps for values of shape "
                                    f"{v.shape}.", SPLIT_ADVICE)
    if not np.all(np.isfinite(t)):
        raise CalibrationInputError(f"{where}: {int(np.sum(~np.isfinite(t)))} time stamps are "
                                    "NaN or infinite.", SPLIT_ADVICE)
    bad = ~np.all(np.isfinite(v), axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise CalibrationInputError(
            f"{where}: {int(bad.sum())} samples hold NaN or infinite values (the first at "
            f"{t[first] * 1e-6:.6f} s).", "The sensor failed or was not ready: " + SPLIT_ADVICE)
    repeat = np.concatenate([[False], (np.diff(t) == 0) & np.all(v[1:] == v[:-1], axis=1)])
    if repeat.any():
        notes.append(f"{path.name}: {s.where}: {int(repeat.sum())} samples logged twice (same "
                     "time stamp, same values) dropped")
        t, v = t[~repeat], v[~repeat]
    if len(t) < 2:
        raise CalibrationInputError(f"{where} holds {len(t)} sample(s).", "Choose a topic and "
                                    "instance with samples (--instance), or log the sensor.")
    steps = np.diff(t)
    if np.any(steps <= 0):
        first = int(np.flatnonzero(steps <= 0)[0])
        what = "repeats with other values" if steps[first] == 0 else "goes backwards"
        raise CalibrationInputError(
            f"{where}: the time stamp {what} after sample {first + 1} ({t[first] * 1e-6:.6f} s "
            f"-> {t[first + 1] * 1e-6:.6f} s; {int(np.sum(steps <= 0))} such steps): the "
            "sensor or the log restarted, or two sensors share the instance.", SPLIT_ADVICE)
    return t, v


def exact_counts(values: np.ndarray, where: str, notes: list) -> tuple:
    """(counts (K, c) int64, counts per unit (c,)): per channel 2^k, k the smallest that makes
    every value an integer below 2^EXACT_BITS (so counts / 2^k is the value bit for bit), else
    the largest k below that bound, the values rounded (the error in `notes`)."""
    counts, scales = np.empty(values.shape, np.int64), np.empty(values.shape[1])
    for j, v in enumerate(values.T):
        largest = float(np.max(np.abs(v)))
        top = EXACT_BITS - math.frexp(largest)[1] if largest > 0 else 0
        if top < 0:
            raise CalibrationInputError(f"{where}: channel {j + 1} holds {largest:g}, not a "
                                        "sensor reading.", SPLIT_ADVICE)
        k = min(_binary_places(v), top)
        scaled = np.ldexp(v, k)
        counts[:, j] = np.rint(scaled).astype(np.int64)
        error = float(np.max(np.abs(scaled - counts[:, j]))) * 2.0**-k
        if error > 0:
            notes.append(f"{where}: channel {j + 1} rounded to 2^-{k} (largest error {error:.3g})")
        scales[j] = 2.0**k
    return counts, scales


def _binary_places(v: np.ndarray) -> int:
    """The smallest k >= 0 for which every v * 2^k is an integer (finite float64 values)."""
    mantissa, exponent = np.frexp(v)
    m = np.ldexp(mantissa, 53).astype(np.int64)  # v = m 2^(exponent - 53), m an integer
    nonzero = m != 0
    if not nonzero.any():
        return 0
    m, exponent = m[nonzero], exponent[nonzero]
    zeros = np.log2((m & -m).astype(float)).astype(int)  # trailing zero bits of m
    return int(max(0, np.max(53 - exponent - zeros)))


def sample_numbers(t_us: np.ndarray) -> tuple:
    """(sample numbers (K,), nominal step in us) of increasing time stamps: the step is the mean
    of the steps within half a step of the median one; each step counts its length over that,
    rounded, at least 1. A logger's dropped samples are gaps in the numbers (as a device's
    sequence numbers), time stamp jitter below half a step is not, and no rounding error
    accumulates along the log."""
    steps = np.diff(t_us).astype(float)
    guess = float(np.median(steps))
    regular = np.rint(steps / guess) == 1
    step = float(np.mean(steps[regular])) if regular.any() else guess
    counts = np.maximum(1, np.rint(steps / step)).astype(np.int64)
    return np.concatenate([[0], np.cumsum(counts)]), step
