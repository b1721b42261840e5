"""The sample instants of an imported recording whose time column may be a host's clock.

A device stamps its samples on its own clock: the steps are all alike (a dropped sample doubles
one). A program on the receiving computer that stamps each line as it arrives writes the host's
clock instead: lines come in bunches (USB and serial buffering, the scheduler), so the steps
spread from a fraction of a millisecond to tens of them, and a host clock adjusted by NTP can
even step backwards. Such stamps misplace every sample by milliseconds, and their median step
is not the device's rate (bunched lines: many short steps, a few long ones): every
per-sqrt(Hz) noise figure would follow the wrong rate.

`timeline` tells them apart by the spread of the steps (JITTER, or any step that is not
forward) and then prefers, in order: the device's sample counter (`--index`, unwrapped when it
wraps at 2^8, 2^16 or 2^32; the rate stated,
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

WRAPS = (1 << 8, 1 << 16, 1 << 32)
"""Where a device's sample counter (uint8, uint16, uint32) wraps to 0."""

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
    notes = []
    seq = None if counter is None else _counter(counter, what, notes)
    steps = np.diff(t)
    q1, median, q3 = np.percentile(steps, [25, 50, 75])
    backward = int(np.sum(steps <= 0))
    if not backward and q3 - q1 <= JITTER * median:
        rate = 1.0 / float(median) if fs is None else float(fs)
        return Timeline(t, seq, rate, notes + _stated(t, seq, fs, what))
    said = (f"{what}: the time stamps look like a host's clock, not the device's: steps "
            f"{steps.min() * 1e3:.3g} .. {steps.max() * 1e3:.3g} ms (median "
            f"{median * 1e3:.3g} ms, interquartile range {(q3 - q1) * 1e3:.3g} ms, sd "
            f"{steps.std() * 1e3:.3g} ms{f', {backward} not forward' if backward else ''})")
    if seq is not None:
        return _on_counter(t, seq, fs, said, notes)
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


def _on_counter(t: np.ndarray, seq: np.ndarray, fs, said: str, notes: list) -> Timeline:
    """The samples at their counter values on the device's clock: the stated rate, else the
    rate fitted to the host clock (least squares of t on seq); `notes` so far kept."""
    slope, start = np.polyfit(seq - seq[0], t, 1)
    rate = float(fs) if fs is not None else 1.0 / float(slope)
    if fs is not None:
        start = float(np.mean(t - (seq - seq[0]) / rate))
    how = "stated" if fs is not None else (f"fitted to the host clock over "
                                           f"{t[-1] - t[0]:.3f} s")
    return Timeline(start + (seq - seq[0]) / rate, seq, rate, [
        *notes, f"{said}; the samples placed by the counter column at {rate:.6g} Hz ({how}) "
        f"instead{_gaps(seq)}"])


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


def _counter(counter, what: str, notes: list) -> np.ndarray:
    """The counter as int64, unwrapped when it wraps at a power of two (WRAPS: a uint8, uint16
    or uint32 counter whose every backward step is, plus the modulus, no longer than its longest
    forward step; said in `notes`), refused unless it then increases at every sample (a
    restart)."""
    seq = np.asarray(counter, np.int64)
    steps = np.diff(seq)
    back = steps <= 0
    if back.any() and seq.min() >= 0:
        modulus = next((w for w in WRAPS if seq.max() < w), None)
        longest = max(int(steps[~back].max()) if (~back).any() else 1, 1)
        wrapped = steps[back] + (modulus or 0)
        if modulus is not None and np.all((wrapped > 0) & (wrapped <= longest)):
            seq = seq + modulus * np.concatenate([[0], np.cumsum(back)])
            notes.append(f"{what}: the counter wraps at {modulus} ({int(back.sum())} times): "
                         "unwrapped")
    bad = np.flatnonzero(np.diff(seq) <= 0)
    if len(bad):
        raise CalibrationInputError(
            f"{what}: the counter does not increase after sample {int(bad[0]) + 1} "
            f"({int(seq[bad[0]])} -> {int(seq[bad[0] + 1])}; {len(bad)} such steps): the "
            "device restarted, or the column is no sample counter.", "Split the recording at "
            "the restart, or give the device's sample counter as --index.")
    return seq


def _gaps(seq: np.ndarray) -> str:
    """", N samples missing (counter gaps)" when the counter skips, else ""."""
    missing = int(seq[-1] - seq[0] + 1 - len(seq))
    return f", {missing} samples missing (counter gaps)" if missing else ""
