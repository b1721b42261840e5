"""A recorded session's static data -> each channel's Allan variance and IEEE 952 noise terms.

Where the unit was at rest: the static windows of the protocol's completed positions (the rotary
protocol's static windows, the still poses of iron and free-static sessions: `station.reduce.
still.pose_windows`); a session without protocol events (an imported recording, a long rest) has
its still intervals detected on the whole stream (`station.reduce.stillness.detect_still`, which
reads the stream once). Each window is read by row range (`station.reduce.windows.StreamWindows`),
converted to SI units, reduced to its Allan curve (`station.solve.noise.allan_curve`) and let go,
so only one window's samples are held at a time.

The windows are pooled, not the longest taken: at each tau the windows' Allan variances are
averaged weighted by their numbers of terms (`station.solve.noise.pooled`), which is the Allan
variance of all their second differences together; the short taus gain every window's data (the
white noise, N), the long taus come from the windows long enough to reach them (B, K). Windows
shorter than `station.solve.noise.MIN_SAMPLES` are left out.
"""

from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError
from station.reduce.still import pose_windows
from station.reduce.stillness import detect_still
from station.reduce.windows import StreamWindows
from station.solve.noise import MIN_SAMPLES, AllanCurve, NoiseFit, allan_curve, fit_noise, pooled


@dataclass(frozen=True)
class SessionNoise:
    """The noise of one stream of a session.

    stream, channels, units : the stream's name, channel names and SI units
    windows : (P, 2) clock seconds of the static windows analysed; source: where they came from
    curve, fit : the pooled Allan curve and the fitted terms (`station.solve.noise`)
    """

    stream: str
    channels: tuple
    units: tuple
    windows: np.ndarray
    source: str
    curve: AllanCurve
    fit: NoiseFit


def session_noise(session, stream: str = "imu", channels=None) -> SessionNoise:
    """The noise of `stream` of a session (`station.session.Session`) from its static
    data (module docstring); channels: the indices of the stream's channels to fit (default
    all: e.g. only the calibrated ones, so that another channel stuck at one value is no
    obstacle)."""
    if stream not in session.specs:
        raise CalibrationInputError(
            f"{session.path} has no stream {stream!r}.",
            f"Give one of its streams: {', '.join(sorted(session.specs))} (--stream).")
    windows = StreamWindows(session, stream, session.events())
    spec = windows.spec
    pick = np.arange(len(spec.channels)) if channels is None else np.asarray(channels, np.int64)
    scale = np.broadcast_to(np.asarray(spec.counts_per_unit, float), len(spec.channels))[pick]
    spans, source = pose_windows(session.events())[0], "static windows of the protocol"
    curves, kept, longest = [], [], 0
    if len(spans):
        for t0, t1 in spans:
            _, counts = windows.read(t0, t1)
            longest = max(longest, len(counts))
            if len(counts) >= MIN_SAMPLES:
                curves.append(allan_curve(counts[:, pick], spec.rate_hz, scale))
                kept.append((t0, t1))
    else:
        source = "still intervals detected in the stream"
        curves, kept, longest = _detected(windows, pick, scale)
    if not curves:
        raise CalibrationInputError(
            f"{session.path}: too little static data in stream {stream!r}: its longest static "
            f"stretch is {longest} samples ({longest / spec.rate_hz:.3g} s), the Allan variance "
            f"needs {MIN_SAMPLES} ({MIN_SAMPLES / spec.rate_hz:.3g} s at {spec.rate_hz:g} Hz).",
            "Record the unit at rest: the static windows of a protocol, or a long rest.")
    curve = pooled(curves)
    units = session.reading_units(stream)  # raw counts without their scale stay "counts"
    names, units = tuple(spec.channels[i] for i in pick), tuple(units[i] for i in pick)
    return SessionNoise(stream, names, units, np.array(kept, float).reshape(-1, 2), source, curve,
                        fit_noise(curve, names))


def _detected(windows: StreamWindows, pick: np.ndarray, scale: np.ndarray) -> tuple:
    """(curves, windows, samples of the longest) of the still intervals `detect_still` finds in
    the whole stream (a session without protocol events): the stream's samples with a sampling
    instant (too few for the detector: the longest is all of them), of the channels `pick`
    (indices into the stream's) whose counts per unit are `scale`."""
    index, counts = windows.read_rows([(0, len(windows.t))] if len(windows.t) else [])
    t = windows.t[index]
    known = np.isfinite(t)
    z, t = counts[known][:, pick], t[known]
    del counts
    if len(z) < MIN_SAMPLES:
        return [], [], len(z)
    spec = windows.spec
    still = detect_still(z, spec.rate_hz)  # any units: its thresholds are multiples of the noise
    spans = [(a, b) for a, b in still.intervals if b - a >= MIN_SAMPLES]
    return ([allan_curve(z[a:b], spec.rate_hz, scale) for a, b in spans],
            [(t[a], t[b - 1]) for a, b in spans],
            max((b - a for a, b in still.intervals), default=0))
