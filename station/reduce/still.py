"""A recorded still-pose session (right-angle iron, free static) -> the mean readings of its poses.

The reduction does not trust the live polling of the protocol (`station.protocols.still`): it
detects the still intervals once on the whole recording (`station.reduce.stillness.detect_still`,
one noise level for the session) and averages, for each completed pose, the first `hold` seconds of
the interval that overlaps its recorded window most. `up_direction` tells where "up" is in the unit
frame from a pose's readings (the live protocols use it too).
"""

import dataclasses
from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError
from station.reduce.stillness import StillOptions, detect_still
from station.reduce.timeline import sample_times, segment_breaks
from station.solve.constraints import Constraints

ACCELEROMETER, GYRO = "m/s^2", "rad/s"


def up_direction(z, a_nominal, bias_guess=None) -> np.ndarray:
    """(P, 3) unit up directions in the unit frame from readings z (m, P): nominal least squares."""
    z = np.asarray(z, float)
    a = np.asarray(a_nominal, float)
    if bias_guess is not None:
        z = z - np.asarray(bias_guess, float).reshape(-1, 1)
    v = np.linalg.lstsq(a.T, z, rcond=None)[0].T
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@dataclass(frozen=True)
class StillReadings:
    """Averaged readings of the completed still poses of a session (SI units).

    M, sigma : (m, P) means and their standard errors; windows : (P, 2) clock seconds of the
    first and last sample averaged; mountings : (P,) mounting index (0 without mountings);
    detection : the still intervals detected on the whole recording (every pose found and every
    candidate rejected, `station.reduce.stillness.StillIntervals`) and their sample times
    (`times`, (K,) clock seconds), None when not kept.
    """

    M: np.ndarray
    sigma: np.ndarray
    windows: np.ndarray
    mountings: np.ndarray
    detection: object = None
    times: np.ndarray | None = None

    def take(self, keep):
        """The readings of the poses `keep` (column indices), in that order."""
        keep = list(keep)
        return dataclasses.replace(self, M=self.M[:, keep], sigma=self.sigma[:, keep],
                                   windows=self.windows[keep], mountings=self.mountings[keep])

    def sensors(self, rows):
        """The readings of the sensors `rows` (row indices), in that order."""
        rows = list(rows)
        return dataclasses.replace(self, M=self.M[rows], sigma=self.sigma[rows])

    def constraints(self) -> Constraints | None:
        """Inner-product constraints between the poses: None, equal magnitudes only."""
        return None


def pose_windows(events) -> tuple[np.ndarray, np.ndarray]:
    """((P, 2) still windows in clock seconds, (P,) mountings) of the completed poses; a pose
    recorded again (after a motion, or refused) keeps its last window."""
    poses: dict = {}
    for e in events:
        if e.position is None or e.kind not in ("position_start", "static_start", "static_end",
                                                "position_done"):
            continue
        if e.kind == "position_start":
            poses[e.position] = {"mounting": e.detail.get("mounting", 0)}
        pose = poses.setdefault(e.position, {})
        pose[e.kind] = e.time
        if e.kind == "static_end":
            pose["window"] = _window(e.detail.get("window", [pose.get("static_start"), e.time]))
    done = [p for _, p in sorted(poses.items())
            if all(k in p for k in ("static_start", "window", "position_done"))]
    windows = np.array([p["window"] for p in done]).reshape(-1, 2)
    return windows, np.array([int(p.get("mounting", 0)) for p in done], dtype=np.int64)


def _window(value) -> list:
    """A [start, stop] pair of finite clock seconds from an (untrusted) event detail."""
    w = np.asarray(value, dtype=object)
    if w.shape != (2,) or not all(isinstance(x, (int, float)) and np.isfinite(x) for x in w) \
            or not w[0] < w[1]:
        raise CalibrationInputError(f"a static_end event holds the window {value!r}.",
                                    "The session file is damaged or not from a still-pose "
                                    "protocol.")
    return [float(w[0]), float(w[1])]


def still_readings(session, stream: str = "imu", trim: float = 0.0,
                   still: StillOptions | None = None, **detector) -> StillReadings:
    """The completed still poses of a session (`station.session.Session`).

    Sample instants are worked out per segment of the stream (`station.reduce.timeline`: a
    reconnection or a resumed session starts one). The still intervals are detected once on the
    whole recording (`station.reduce.stillness.detect_still`, one noise level for the session;
    options: `detector`, default the protocol's settings in the metadata), so the result does not
    depend on when the live protocol polled.
    With the protocol's events, each completed pose averages the first `hold` seconds of the
    interval that overlaps its recorded window most; without them (an imported recording) every
    interval is a pose, all in one mounting. `trim` seconds (rounded to whole samples) are left
    out at both ends of every averaged window. `still`: the user's detector settings
    (`StillOptions`; channels None: every channel of the stream decides, as in the live protocol).
    """
    data, events = session.stream(stream), session.events()
    if len(data.seq) < 3:
        raise CalibrationInputError(f"{session.path}: the stream {stream!r} holds "
                                    f"{len(data.seq)} samples.",
                                    "Record or import the recording again: still poses need "
                                    "seconds of samples.")
    rate = data.spec.rate_hz
    t = sample_times(data.seq, data.host_time, rate, segment_breaks(events))
    known = np.isfinite(t)  # a resumed session's burst of samples taken before the resume: none
    t, z = t[known], data.to_si()[known]
    settings = session.metadata.get("settings", {})
    options = {k: settings[k] for k in ("window", "enter", "leave", "min_still", "rest_length")
               if isinstance(settings.get(k), (int, float))}
    x, acc, gyro = _detection_samples(session, stream, z, still, known)
    if still is not None:
        options.update(still.detector(rate, acc, gyro))
    still = detect_still(x, rate, **{**options, **detector})
    windows, mountings = pose_windows(events)
    spans = still.intervals
    if len(windows):
        first, last = t[spans[:, 0]], t[spans[:, 1] - 1]
        overlap = (np.minimum(last[None], windows[:, 1:]) - np.maximum(first[None], windows[:, :1]))
        best = np.argmax(overlap, axis=1)
        lost = np.flatnonzero(overlap[np.arange(len(windows)), best] <= 0)
        if len(lost):
            raise CalibrationInputError(
                f"pose(s) {(lost + 1).tolist()} of {session.path} are not still in the whole "
                "recording.", "Check the detector settings, or record those poses again.")
        hold = np.round((windows[:, 1] - windows[:, 0]) * rate).astype(np.int64)
        spans = np.column_stack([spans[best, 0], np.minimum(spans[best, 1],
                                                            spans[best, 0] + hold)])
    else:
        mountings = np.zeros(len(spans), np.int64)
    if not len(spans):
        raise CalibrationInputError(f"the session {session.path} has no still pose.",
                                    "Record the unit in still poses, each still for seconds.")
    spans = _trimmed(spans, trim, rate, session.path)
    M = np.array([z[a:b].mean(axis=0) for a, b in spans]).T
    sigma = np.array([z[a:b].std(axis=0, ddof=1) / np.sqrt(b - a) for a, b in spans]).T
    return StillReadings(M, sigma, np.column_stack([t[spans[:, 0]], t[spans[:, 1] - 1]]),
                         mountings, still, t)


def _detection_samples(session, stream: str, z: np.ndarray, still, known: np.ndarray) -> tuple:
    """(samples the detector sees, their accelerometer columns, their gyro columns): the stream's
    SI samples z (its samples `known`, those with a sampling instant); with `--still-channels
    acc+gyro` and no gyro in the stream, the one other stream in rad/s on the same samples (an
    imported recording keeps its gyro in a stream of its own)."""
    units = session.specs[stream].units
    acc = np.flatnonzero([u == ACCELEROMETER for u in units])
    gyro = np.flatnonzero([u == GYRO for u in units])
    if still is None or still.channels != "acc+gyro" or len(gyro):
        return z, acc, gyro
    others = [n for n, s in session.specs.items() if n != stream and GYRO in s.units]
    if len(others) != 1:
        raise CalibrationInputError(
            f"{session.path}: --still-channels acc+gyro needs the gyro, but the streams in "
            f"{GYRO} are {others or 'none'}.", "Use --still-channels acc, or import one gyro "
            "stream.")
    data, other = session.stream(stream), session.stream(others[0])
    if not np.array_equal(data.seq, other.seq):
        raise CalibrationInputError(
            f"{session.path}: the gyro stream {others[0]!r} is not on the samples of {stream!r}.",
            "Import the accelerometer and gyro on one time base, or use --still-channels acc.")
    g = other.to_si()[known][:, [u == GYRO for u in other.spec.units]]
    return np.hstack([z, g]), acc, z.shape[1] + np.arange(g.shape[1])


def _trimmed(spans, trim: float, rate: float, path):
    """Sample spans (P, 2) with round(trim x rate) samples cut at both ends; 2 samples must stay."""
    if not (np.isfinite(trim) and trim >= 0):
        raise CalibrationInputError(f"trim {trim!r} s is not a duration.",
                                    "Give the seconds to leave out as a number >= 0.")
    cut = round(trim * rate)
    spans = spans + np.array([cut, -cut])
    short = np.flatnonzero(spans[:, 1] - spans[:, 0] < 2)
    if len(short):
        raise CalibrationInputError(
            f"trimming {trim:g} s at both ends leaves pose(s) {(short + 1).tolist()} of {path} "
            "fewer than 2 samples.", "Trim less than half of the shortest still window.")
    return spans
