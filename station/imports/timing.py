"""The sample instants of an imported recording whose time column may be a host's clock.

A device stamps its samples on its own clock: the steps are all alike (a dropped sample doubles
one). A program on the receiving computer that stamps each line as it arrives writes the host's
clock instead: lines come in bunches (USB and serial buffering, the scheduler), so the steps
spread from a fraction of a millisecond to tens of them, and a host clock adjusted by NTP can
even step backwards. Such stamps misplace every sample by milliseconds, and their median step
is not the device's rate (bunched lines: many short steps, a few long ones): every
per-sqrt(Hz) noise figure would follow the wrong rate.

`timeline` tells them apart by the spread of the steps (JITTER, or any step that is not
forward) and then prefers, in order: the device's sample counter (`--index`; the rate stated,
`--fs`, or fitted to the host clock by least squares over the whole recording, which averages the
delays away), the stated rate alone (rows at `--fs`), else the stamps with the rate of their mean
step (not the median). What was done is said in the notes; regular stamps are kept as they are.
"""

from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError

JITTER = 0.2
"""Interquartile range of the time steps over their median above which the stamps are taken
for a host's clock (a device's own stamps: below 0.01; a host's stamping lines: about 1)."""

RATE_MISMATCH = 0.01
"""Relative difference between a stated rate and the one the stamps imply that is noted."""


@dataclass(frozen=True)
class Timeline:
    """Sample instants `t` (K,) s, sample numbers `seq` (K,) (None: the row numbers), the
    nominal `rate_hz`, and `notes` saying how they were obtained."""

    t: np.ndarray
    seq: np.ndarray | None
    rate_hz: float
    notes: list


def timeline(stamps, counter=None, fs: float | None = None, what: str = "") -> Timeline:
    """The `Timeline` of time stamps `stamps` (s), with the device's sample `counter` (integers,
    or None) and the stated rate `fs` (Hz, or None) when given (see the module docstring)."""
    t = np.asarray(stamps, float)
    if len(t) < 2 or not np.all(np.isfinite(t)):
        raise CalibrationInputError(f"{what}: fewer than 2 finite time stamps.",
                                    "Give a recording of at least 2 samples with time stamps.")
    seq = None if counter is None else _counter(counter, what)
    steps = np.diff(t)
    q1, median, q3 = np.percentile(steps, [25, 50, 75])
    backward = int(np.sum(steps <= 0))
    if not backward and q3 - q1 <= JITTER * median:
        rate = 1.0 / float(median) if fs is None else float(fs)
        return Timeline(t, seq, rate, _stated(t, seq, fs, what))
    said = (f"{what}: the time stamps look like a host's clock, not the device's: steps "
            f"{steps.min() * 1e3:.3g} .. {steps.max() * 1e3:.3g} ms (median "
            f"{median * 1e3:.3g} ms, interquartile range {(q3 - q1) * 1e3:.3g} ms, sd "
            f"{steps.std() * 1e3:.3g} ms{f', {backward} not forward' if backward else ''})")
    if seq is not None:
        return _on_counter(t, seq, fs, said)
    rows = np.arange(len(t))
    if fs is not None:
        start = float(np.mean(t - rows / fs))
        span, rows_span = float(t[-1] - t[0]), (len(t) - 1) / fs
        lost = int(round((span - rows_span) * fs))
        return Timeline(start + rows / fs, None, float(fs), [
            f"{said}; the rows placed at the stated {fs:g} Hz instead (the host clock spans "
            f"{span:.3f} s, the rows {rows_span:.3f} s"
            + (f": about {lost} samples lost, or a wrong --fs; the device's counter (--index) "
               "would place them" if abs(lost) >= 1 else "") + ")"])
    if backward:
        raise CalibrationInputError(
            f"{said}.", "Give the device's sample counter (--index COLUMN) or its rate "
            "(--fs HZ): the samples are then placed on the device's clock.")
    rate = (len(t) - 1) / float(t[-1] - t[0])
    return Timeline(t, None, rate, [
        f"{said}; kept as the sample instants, the rate {rate:.6g} Hz from their mean step (the "
        f"median says {1.0 / median:.6g} Hz); give the device's counter (--index COLUMN) or "
        "rate (--fs HZ) to place the samples on its clock"])


def _on_counter(t: np.ndarray, seq: np.ndarray, fs, said: str) -> Timeline:
    """The samples at their counter values on the device's clock: the stated rate, else the
    rate fitted to the host clock (least squares of t on seq)."""
    slope, start = np.polyfit(seq - seq[0], t, 1)
    rate = float(fs) if fs is not None else 1.0 / float(slope)
    if fs is not None:
        start = float(np.mean(t - (seq - seq[0]) / rate))
    how = "stated" if fs is not None else (f"fitted to the host clock over "
                                           f"{t[-1] - t[0]:.3f} s")
    return Timeline(start + (seq - seq[0]) / rate, seq, rate, [
        f"{said}; the samples placed by the counter column at {rate:.6g} Hz ({how}) instead"
        f"{_gaps(seq)}"])


def _stated(t: np.ndarray, seq, fs, what: str) -> list:
    """Notes on regular stamps: a stated rate they disagree with."""
    if fs is None:
        return []
    count = (seq[-1] - seq[0]) if seq is not None else len(t) - 1
    implied = count / float(t[-1] - t[0])
    if abs(implied - fs) <= RATE_MISMATCH * fs:
        return []
    return [f"{what}: the stated rate {fs:g} Hz differs from the time stamps' {implied:.6g} Hz "
            "by more than 1 %; the stamps are kept as the sample instants, the stated rate as "
            "the nominal one"]


def _counter(counter, what: str) -> np.ndarray:
    """The counter as int64, refused unless it increases at every sample."""
    seq = np.asarray(counter, np.int64)
    bad = np.flatnonzero(np.diff(seq) <= 0)
    if len(bad):
        raise CalibrationInputError(
            f"{what}: the counter does not increase after sample {int(bad[0]) + 1} "
            f"({int(seq[bad[0]])} -> {int(seq[bad[0] + 1])}; {len(bad)} such steps): it wrapped "
            "or the device restarted.", "Split the recording at the restart, or unwrap the "
            "counter before importing.")
    return seq


def _gaps(seq: np.ndarray) -> str:
    """", N samples missing (counter gaps)" when the counter skips, else ""."""
    missing = int(seq[-1] - seq[0] + 1 - len(seq))
    return f", {missing} samples missing (counter gaps)" if missing else ""
