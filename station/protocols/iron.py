"""The right-angle-iron protocol for accelerometers (Hwangbo & Kanade) and its reduction.

The unit is fixed in a right-angle iron in one or more mountings; for each mounting the technician
stands the iron on its faces in turn. The station needs no key press: it watches the stream and
finds each still pose itself (`station.stillness.detect_still`: dispersion with hysteresis, a
minimum still time, a timeout), then recognises the face from the data.

    mount (new mounting) -> face -> settle -> hold -> face (next) ... -> mount ... -> done

- mount:  ask the technician to fix the unit in the iron in a new way (every `faces` poses) and
          wait until it is still again: that pose is not a requested face;
- face:   ask for the next face (the instruction's orientation is the iron's attitude, world ->
          iron frame, third column up);
- settle: wait for a still interval that started after the request (an open interval of at
          least the detector's `min_still`); `timeout` s without one is a ProtocolError;
- hold:   wait until the first `hold` s of the still interval are recorded and still (a motion
          sends the protocol back to settle); `static_end` records that window (detail `window`,
          clock seconds: the averaging window does not depend on when the host got round to
          polling); then the face is recognised and `position_done` recorded.

Face recognition (`recognise_faces`): the averaged reading z_j gives the up direction in the unit
frame through the nominal layout, u_j ~ (A A^T)^-1 A (z_j - b_guess); within a mounting the first
pose is face "+x", a later pose within `tolerance_deg` of (the opposite of) an earlier face is that
face (its opposite), one perpendicular to all earlier axes opens the next axis. Any consistent
labelling gives the same constraints (`station.constraints.from_faces`, Eq. 15: same face 1,
perpendicular 0, opposite -1, only within a mounting); the solver is `station.calibrate(M, g,
bias="estimate", constraints=...)` = Hwangbo & Kanade's factorization + maximum likelihood.
"""

import threading
from dataclasses import asdict, dataclass

import numpy as np

from station.calibrate import calibrate
from station.constraints import FACES, from_faces
from station.errors import CalibrationInputError
from station.operator import Instruction
from station.protocols.rotary import ProtocolError, mounting
from station.recorder import sample_times
from station.stillness import detect_still

FACE_UP = {f: (1.0 if f[0] == "-" else -1.0) * np.eye(3)[FACES.index(f) // 2] for f in FACES}
"""Up direction in the iron frame when the iron stands on face f (its outward normal points down)."""


@dataclass(frozen=True)
class IronSettings:
    """Durations in clock seconds, gravity in m/s^2.

    gravity   : local gravity (the stimulus magnitude)
    mountings : how many ways the unit is fixed in the iron
    faces     : the faces asked for in each mounting, in order
    hold      : length of each still window
    window, enter, leave, min_still, rest_length : stillness detector (station.stillness)
    lookback  : seconds of stream the detector looks at (enough for a rest stretch and a pose)
    tolerance_deg : face recognition tolerance
    poll, timeout, stale : time between checks, longest wait for a still pose, longest IMU silence
    """

    gravity: float = 9.80665
    mountings: int = 2
    faces: tuple = FACES
    hold: float = 5.0
    window: float = 1.0
    enter: float = 4.0
    leave: float = 8.0
    min_still: float = 1.5
    rest_length: float = 2.0
    lookback: float = 30.0
    tolerance_deg: float = 20.0
    poll: float = 0.25
    timeout: float = 60.0
    stale: float = 10.0

    def __post_init__(self):
        object.__setattr__(self, "faces", tuple(self.faces))
        unknown = [f for f in self.faces if f not in FACES]
        if unknown or not self.faces:
            raise ValueError(f"faces must be a non-empty list of {FACES}, got {self.faces!r}")
        if not (isinstance(self.mountings, int) and self.mountings >= 1):
            raise ValueError(f"mountings must be a whole number >= 1, got {self.mountings!r}")
        positive = ("gravity", "hold", "window", "min_still", "rest_length", "lookback",
                    "tolerance_deg", "poll", "timeout", "stale")
        bad = [n for n in positive if not getattr(self, n) > 0]
        if bad:
            raise ValueError(f"iron settings {bad} must be positive")
        if self.lookback < self.rest_length + self.hold + 2 * self.window:
            raise ValueError("lookback must hold a rest stretch, a window and a still pose")


class StreamTap:
    """An IMU driver whose blocks pass on to the recorder while a copy stays for the protocol."""

    def __init__(self, imu, rate_hz: float, counts_per_unit):
        self.imu = imu
        self.rate_hz = float(rate_hz)
        self.lsb = 1.0 / np.asarray(counts_per_unit, float)
        self._blocks = []
        self._lock = threading.Lock()

    def read_block(self, timeout: float = 0.0):
        block = self.imu.read_block(timeout=timeout)
        if block is not None and len(block):
            with self._lock:
                self._blocks.append(block)
        return block

    def samples(self, since: float = -np.inf):
        """(times (K,), readings (K, m) in SI units) of the samples taken at or after `since`."""
        with self._lock:
            blocks = list(self._blocks)
        if not blocks:
            return np.zeros(0), np.zeros((0, len(self.lsb)))
        seq = np.concatenate([b.seq for b in blocks])
        t = sample_times(seq, np.concatenate([b.host_time for b in blocks]), self.rate_hz)
        keep = t >= since
        counts = np.concatenate([b.counts for b in blocks])[keep]
        return t[keep], counts * self.lsb


def up_direction(z, a_nominal, bias_guess=None) -> np.ndarray:
    """(P, 3) unit up directions in the unit frame from readings z (m, P): nominal least squares."""
    z = np.asarray(z, float)
    a = np.asarray(a_nominal, float)
    if bias_guess is not None:
        z = z - np.asarray(bias_guess, float).reshape(-1, 1)
    v = np.linalg.lstsq(a.T, z, rcond=None)[0].T
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def recognise_faces(directions, mountings, tolerance_deg: float = 20.0) -> list:
    """Face labels of poses with up `directions` (P, 3), relative to the first pose of each mounting.

    Raises CalibrationInputError for a pose that is neither along nor perpendicular to the faces
    seen before in its mounting (the iron was not standing on a face).
    """
    directions = np.asarray(directions, float)
    mountings = list(mountings)
    near, perp = np.cos(np.radians(tolerance_deg)), np.sin(np.radians(tolerance_deg))
    axes: dict = {}
    labels = []
    for j, (u, k) in enumerate(zip(directions, mountings)):
        seen = axes.setdefault(k, [])
        cos = np.array([u @ a for a in seen])
        if len(cos) and np.max(np.abs(cos)) > near:
            i = int(np.argmax(np.abs(cos)))
            labels.append(("+" if cos[i] > 0 else "-") + "xyz"[i])
        elif len(seen) < 3 and np.all(np.abs(cos) < perp):
            seen.append(u)
            labels.append("+" + "xyz"[len(seen) - 1])
        else:
            angles = np.degrees(np.arccos(np.clip(np.abs(cos), 0, 1)))
            raise CalibrationInputError(
                f"pose {j + 1} (mounting {k}) is {np.round(angles, 1).tolist()} deg from the axes "
                f"of the faces before it: not on a face of the iron (tolerance {tolerance_deg} "
                "deg).", "Stand the iron squarely on one of its faces and record that pose again.")
    return labels


class IronProtocol:
    """Runs the iron protocol with an operator into a running Recorder reading a `StreamTap`.

    operator  : `station.operator` ConsoleOperator or a simulated technician
    clock     : the session clock (shared with the devices)
    a_nominal : (3, m) nominal layout of the unit (SI readings), for face recognition
    """

    def __init__(self, operator, clock, a_nominal, settings: IronSettings | None = None,
                 bias_guess=None):
        self.operator = operator
        self.clock = clock
        self.a_nominal = np.asarray(a_nominal, float)
        self.bias_guess = bias_guess
        self.settings = settings or IronSettings()
        self.recorder = self.tap = None
        self.position, self.state = 0, "mount"
        self.directions, self.labels = [], []
        self._since = self._start = None
        self._handlers = {"mount": self._mount, "face": self._face, "settle": self._settle,
                          "hold": self._hold}

    @property
    def poses(self) -> int:
        return self.settings.mountings * len(self.settings.faces)

    def metadata(self) -> dict:
        """What a session file should record about this protocol run."""
        return {"protocol": "iron", "settings": asdict(self.settings),
                "a_nominal": self.a_nominal.tolist(), "gravity": self.settings.gravity}

    def run(self, recorder, tap: StreamTap) -> None:
        """Record every pose into `recorder` (started, reading `tap`); an error is recorded as an
        `abort` event and raised."""
        self.recorder, self.tap, self.position, self.state = recorder, tap, 0, "mount"
        try:
            while self.state != "done":
                self.state = self._handlers[self.state]()  # the one place where the state changes
        except BaseException as exc:
            try:
                recorder.event("abort", self.position, {
                    "state": self.state, "error": f"{type(exc).__name__}: {exc}"})
            except Exception as record_error:  # noqa: BLE001
                exc.add_note(f"and the abort could not be recorded ({record_error})")
            raise

    # -- states ----------------------------------------------------------------------------------

    def _mount(self) -> str:
        k = self._mounting()
        self._since = self.clock.now()
        self.operator.wait(Instruction(f"mounting {k + 1}/{self.settings.mountings}: fix the unit "
                                       "in the iron in a way not used before and put it down"))
        self._await_still(f"re-mounting {k + 1}")  # the pose after it is not a requested face
        return "face"

    def _face(self) -> str:
        j, face = self.position, self.settings.faces[self.position % len(self.settings.faces)]
        self._since = self.clock.now()
        self.operator.wait(Instruction(f"pose {j + 1}/{self.poses}: stand the iron on its face "
                                       f"{face} and let go", mounting(FACE_UP[face])))
        self.recorder.event("position_start", j, {"mounting": self._mounting(), "face_asked": face})
        return "settle"

    def _settle(self) -> str:
        self._start = self._await_still(f"asking for pose {self.position + 1}")
        self.recorder.event("static_start", self.position, {"still_since": self._start})
        return "hold"

    def _hold(self) -> str:
        s, j = self.settings, self.position
        end = self._start + s.hold
        self.clock.sleep(end - self.clock.now())
        self.recorder.drain(end + s.window, s.stale)  # the detector sees up to w/2 before the last
        since = self._still_since()
        if since is None or since > self._start + s.window:  # a start jitters by a few samples
            self.operator.prompt(f"pose {j + 1}: the iron moved; let it rest")
            self.recorder.event("note", j, {"text": "moved during the still window"})
            self._since = self._start + s.window  # the next still interval begins after the motion
            return "settle"
        self.recorder.event("static_end", j, {"window": [self._start, end]})
        t, z = self.tap.samples(self._start)
        z = z[t <= end].mean(axis=0)
        u = up_direction(z[:, None], self.a_nominal, self.bias_guess)[0]
        k = self._mounting()
        mine = [i for i in range(j) if self._mounting(i) == k]
        try:
            face = recognise_faces([*[self.directions[i] for i in mine], u], [k] * (len(mine) + 1),
                                   s.tolerance_deg)[-1]
        except CalibrationInputError as exc:
            self.operator.prompt(f"pose {j + 1}: {exc}")
            return "face"
        if face in [self.labels[i] for i in mine]:
            self.operator.prompt(f"pose {j + 1} repeats face {face} of this mounting")
        self.directions.append(u)
        self.labels.append(face)
        self.recorder.event("position_done", j, {"mounting": k, "face": face,
                                                 "up": u.tolist()})
        self.position += 1
        if self.position == self.poses:
            return "done"
        return "mount" if self.position % len(s.faces) == 0 else "face"

    # -- helpers ---------------------------------------------------------------------------------

    def _mounting(self, position: int | None = None) -> int:
        j = self.position if position is None else position
        return j // len(self.settings.faces)

    def _await_still(self, after: str) -> float:
        """Start time of the first still interval that begins after `_since`."""
        deadline = self.clock.now() + self.settings.timeout
        while (start := self._still_since()) is None:
            if self.clock.now() > deadline:
                raise ProtocolError(f"no still pose within {self.settings.timeout:g} s after "
                                    f"{after}; put the iron down, let go and record the session "
                                    "again")
            self.clock.sleep(self.settings.poll)
        return start

    def _still_since(self) -> float | None:
        """Start time of the still interval going on now, if it began after the last request."""
        s = self.settings
        self.recorder.check(s.stale)
        t, z = self.tap.samples(self.clock.now() - s.lookback)
        if len(t) < (s.rest_length + 2 * s.window) * self.tap.rate_hz:
            return None
        still = detect_still(z, self.tap.rate_hz, rest_length=s.rest_length, window=s.window,
                             enter=s.enter, leave=s.leave, min_still=s.min_still,
                             timeout=s.timeout)
        if not len(still.intervals):
            return None
        start, stop = still.intervals[-1]
        h = round(s.window * self.tap.rate_hz / 2)  # half the detector's window
        if stop < len(t) - h - 1 or start <= h or t[start] < self._since:
            return None  # over, begun before the samples looked at, or before the request
        return float(t[start])


# ------------------------------------------------------------------------------------ reduction


@dataclass(frozen=True)
class IronReadings:
    """Averaged readings of the still poses of an iron session (SI units).

    M, sigma : (m, P) means and their standard errors; windows : (P, 2) clock seconds of the
    first and last sample averaged;
    mountings : (P,) mounting index; faces : P face labels (recognised from the data).
    """

    M: np.ndarray
    sigma: np.ndarray
    windows: np.ndarray
    mountings: np.ndarray
    faces: list

    def constraints(self):
        """The inner-product constraints of the poses (Eq. 15)."""
        return from_faces(self.faces, self.mountings)


def pose_windows(events) -> tuple[np.ndarray, np.ndarray]:
    """((P, 2) still windows in clock seconds, (P,) mountings) of the completed poses; a pose
    recorded again after a motion keeps its last window."""
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
                                    "The session file is damaged or not from the iron protocol.")
    return [float(w[0]), float(w[1])]


def iron_readings(session, stream: str = "imu", a_nominal=None, bias_guess=None,
                  tolerance_deg: float = 20.0, **detector) -> IronReadings:
    """The still poses of an iron session (`station.session.Session`) and their faces.

    The still intervals are detected once on the whole recording (`station.stillness.
    detect_still`, one noise level for the session; options: `detector`, default the protocol's
    settings in the metadata), so the result does not depend on when the live protocol polled.
    With the protocol's events, each completed pose averages the first `hold` seconds of the
    interval that overlaps its recorded window most; without them (an imported recording) every
    interval is a pose, all in one mounting. `a_nominal` defaults to the metadata's (or the
    identity for a triad).
    """
    data = session.stream(stream)
    rate = data.spec.rate_hz
    t = sample_times(data.seq, data.host_time, rate)
    z = data.to_si()
    settings = session.metadata.get("settings", {})
    options = {k: settings[k] for k in ("window", "enter", "leave", "min_still", "rest_length")
               if isinstance(settings.get(k), (int, float))}
    still = detect_still(z, rate, **{**options, **detector})
    windows, mountings = pose_windows(session.events())
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
                                    "Record the iron on its faces, each pose still for seconds.")
    M = np.array([z[a:b].mean(axis=0) for a, b in spans]).T
    sigma = np.array([z[a:b].std(axis=0, ddof=1) / np.sqrt(b - a) for a, b in spans]).T
    if a_nominal is None:
        a_nominal = session.metadata.get("a_nominal", np.eye(3)[:, : M.shape[0]].tolist())
    faces = recognise_faces(up_direction(M, a_nominal, bias_guess), mountings, tolerance_deg)
    return IronReadings(M, sigma, np.column_stack([t[spans[:, 0]], t[spans[:, 1] - 1]]),
                        mountings, faces)


def calibrate_iron(readings: IronReadings, gravity: float, nominal=None):
    """`station.calibrate` with the faces' constraints and the biases estimated (Hwangbo & Kanade
    factorization, Eqs. 14-15 and 29, then maximum likelihood)."""
    return calibrate(readings.M, gravity, d=3, bias="estimate", constraints=readings.constraints(),
                     sigma=readings.sigma, nominal=nominal)
