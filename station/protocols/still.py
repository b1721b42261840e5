"""Still poses held by hand: what the right-angle-iron and the free-static protocols share.

In both, the technician turns the unit (in an iron, or freely) and lets go; the station needs no key
press to know when a pose begins: it watches the stream (`StreamTap`) and finds each still pose
itself (`station.reduce.stillness.detect_still`: dispersion with hysteresis, a minimum still time, a
timeout). `PoseWatcher` does the watching for a protocol:

- `start(position, detail)`: record the pose's `position_start` (kept for a redo);
- `request()`  : a new pose was asked for: only a still interval that began after the last pose
                 (its window, or the start of a settled pose not held, e.g. the iron's
                 re-mounting) counts: the unit was moved since (before the first pose: after now).
                 A technician quicker than the host's prompt still has the pose taken;
- `settle(after)` : wait for such an interval (an open interval of at least `min_still`);
                 `timeout` s without one is a ProtocolError (`after` says what was asked);
- `hold(position)`: wait until the first `hold` s of it are recorded and still; records
                 `static_start` / `static_end` (detail `window`, clock seconds, so the averaging
                 window does not depend on when the host polled) and returns the window's mean
                 and its quality (`station.reduce.window_quality`: samples found / due, noise
                 against the detector's rest noise); a motion records a `note`, tells the
                 operator and returns None (settle again). Redo, do not warn
                 (`station.protocols.redo`): a flagged window (spikes, samples missing, not
                 still) is recorded again at once: a new `position_start` of the pose (detail
                 `redo`, `flags`), the technician asked to hold the unit still, the next `hold` s
                 taken; `RedoLimitError` past the settings' `redo_limit`.

The offline reduction (`station.reduce.still.still_readings`) does not trust the live polling.

A session that ended early (Ctrl-C, kill, a lost IMU) goes on with `continue_poses` (`station
resume`): the poses completed (`position_done`) are kept and the protocol asks for the others; the
protocol's `run(recorder, tap, done)` takes up its state from the completed poses' events.
"""

import threading
from dataclasses import dataclass

import numpy as np

from station import limits
from station.acquire import interrupts
from station.acquire.recorder import Recorder
from station.acquire.watching import Unwatched
from station.errors import InputError, ProtocolError
from station.model.constants import STANDARD_GRAVITY
from station.protocols.redo import REDO_LIMIT, Redo, check_redo_limit, window_flags
from station.reduce.stillness import detect_still
from station.reduce.timeline import sample_times
from station.reduce.window_quality import WindowQuality, describe, window_quality
from station.session import SessionWriter

SETTING_LIMITS = {"gravity": 100.0, "hold": 3600.0, "window": 3600.0, "min_still": 3600.0,
                  "rest_length": 3600.0, "lookback": 7200.0, "poll": 60.0, "timeout": 3600.0,
                  "stale": 3600.0}
"""Largest value of each still-pose setting (gravity in m/s^2, durations in s; each positive)."""


@dataclass(frozen=True)
class StillSettings:
    """Durations in clock seconds, gravity in m/s^2.

    gravity   : local gravity (the stimulus magnitude)
    hold      : length of each still window
    window, enter, leave, min_still, rest_length : stillness detector (station.reduce.stillness)
    lookback  : seconds of stream the detector looks at (enough for a rest stretch and a pose)
    poll, timeout, stale : time between checks, longest wait for a still pose, longest IMU silence
    redo_limit : how often one pose may be recorded again after a flagged window
                 (`station.protocols.redo`)
    """

    gravity: float = STANDARD_GRAVITY
    hold: float = 5.0
    window: float = 1.0
    enter: float = 4.0
    leave: float = 8.0
    min_still: float = 1.5
    rest_length: float = 2.0
    lookback: float = 30.0
    poll: float = 0.25
    timeout: float = 60.0
    stale: float = 10.0
    redo_limit: int = REDO_LIMIT

    def __post_init__(self):
        """Refuse settings no bench runs (`SETTING_LIMITS`), naming the setting and its range."""
        check_redo_limit(self.redo_limit)
        for name, high in SETTING_LIMITS.items():
            limits.positive(getattr(self, name), f"setting {name}", high)
        for name in ("enter", "leave"):
            limits.number(getattr(self, name), f"setting {name}", 0.0, 1e6)
        if self.lookback < self.rest_length + self.hold + 2 * self.window:
            raise InputError("lookback must hold a rest stretch, a window and a still pose")


class StreamTap:
    """An IMU driver whose blocks pass on to the recorder while a copy stays for the protocol."""

    def __init__(self, imu, rate_hz: float, counts_per_unit):
        self.imu = imu
        self.rate_hz = float(rate_hz)
        self.lsb = 1.0 / np.asarray(counts_per_unit, float)
        self._blocks = []
        self._lock = threading.Lock()

    def open(self) -> "StreamTap":
        """Reopen the IMU driver after it was lost (`Recorder.reconnect`)."""
        self.imu.open()
        return self

    def backlog(self):
        """The driver's data on its way (`drivers.serial_imu.SerialImu.backlog`); 0 if it cannot
        tell."""
        backlog = getattr(self.imu, "backlog", None)
        return backlog() if backlog is not None else 0

    def read_block(self, timeout: float = 0.0):
        block = self.imu.read_block(timeout=timeout)
        if block is not None and len(block):
            with self._lock:
                self._blocks.append(block)
        return block

    def forget(self, before: float) -> None:
        """Drop the blocks received before clock time `before` (a long session's samples need
        not stay in memory once their windows are confirmed)."""
        with self._lock:
            self._blocks = [b for b in self._blocks if b.host_time[-1] >= before]

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


class PoseWatcher:
    """Finds and holds the still poses of a running Recorder reading a `StreamTap` (see the module
    docstring); `operator` hears about motions during a hold."""

    def __init__(self, settings: StillSettings, clock, operator, recorder, tap: StreamTap,
                 channels=None):
        self.settings = settings
        self.clock = clock
        self.operator = operator
        self.recorder = recorder
        self.tap = tap
        self.channels = slice(None) if channels is None else np.asarray(channels)
        self._since = self._start = self._last = self._noise = None
        self.redo = Redo(settings.redo_limit, "pose")
        self._asked = {}  # the detail of the pose's position_start

    def start(self, position: int, detail: dict) -> None:
        """Record the `position_start` of pose `position` with `detail` (a redo repeats it)."""
        self._asked = dict(detail)
        self.recorder.event("position_start", position, detail)

    def request(self) -> None:
        """A new pose is asked for: still intervals that began before the last pose's window
        ended (before now, for the first pose) do not count."""
        self._since = self.clock.now() if self._last is None else self._last

    def settle(self, after: str) -> float:
        """Start time of the first still interval that counts for the request."""
        deadline = self.clock.now() + self.settings.timeout
        while (start := self._still_since()) is None:
            if self.clock.now() > deadline:
                raise ProtocolError(f"no still pose within {self.settings.timeout:g} s after "
                                    f"{after}; put the unit down, let go and record the session "
                                    "again")
            self.clock.sleep(self.settings.poll)
        # the next request needs a later interval (a detected start jitters by under a window)
        self._start, self._last = start, start + self.settings.window
        return start

    def hold(self, position: int) -> tuple[np.ndarray, WindowQuality] | None:
        """(mean reading (m,), quality of the `channels`) of the `hold` s window of the pose at
        `position` after `settle`, or None when the unit moved (the next still interval must begin
        after the motion). A flagged window is recorded again at once (the module docstring)."""
        while True:
            held = self._window(position)
            flags = [] if held is None else window_flags({"still": held[1]}, "the rest noise")
            if not flags:
                return held
            self.recorder.event("position_start", position,
                                {**self._asked, **self.redo.attempt(position, flags)})
            self.operator.prompt(self.redo.words(position, flags) + ": hold the unit still")
            self._start = self._last  # the next window follows the flagged one

    def _window(self, position: int) -> tuple[np.ndarray, WindowQuality] | None:
        """One `hold` s window of the pose from `_start` (`hold`)."""
        s = self.settings
        self.recorder.event("static_start", position, {"still_since": self._start})
        end = self._start + s.hold
        self.clock.sleep(end - self.clock.now())
        self.recorder.drain(end + s.window, s.stale)  # the detector sees up to w/2 before the last
        since = self._still_since(until=end + s.window)
        if since is None or since > self._start + s.window:  # a start jitters by a few samples
            self.operator.prompt(f"pose {position + 1}: the unit moved; let it rest")
            self.recorder.event("note", position, {"text": "moved during the still window"})
            self._since = self._start + s.window
            return None
        self.recorder.event("static_end", position, {"window": [self._start, end]})
        self._last = end
        t, z = self.tap.samples(self._start)
        quality = window_quality(t, z[:, self.channels], (self._start, end), self.tap.rate_hz,
                                 self.tap.lsb[self.channels], self._noise[self.channels],
                                 s.enter, "still", position)
        return z[t <= end].mean(axis=0), quality

    def confirm(self, words: str, quality: WindowQuality, unit: str) -> None:
        """Tell the operator a pose was captured: `words` ("pose 3/12 captured") and its
        quality."""
        self.operator.prompt(f"{words}: still {describe(quality, unit, 'the rest noise')}")

    def _still_since(self, until: float | None = None) -> float | None:
        """Start time of the still interval going on now (at clock time `until`: samples a busy
        host received late, taken after it, e.g. the next turn, are not looked at), if it began
        after `_since`."""
        s = self.settings
        self.recorder.check(s.stale)
        end = self.clock.now() if until is None else until
        t, z = self.tap.samples(end - s.lookback)
        if until is not None:
            keep = t <= until
            t, z = t[keep], z[keep]
        if len(t) < (s.rest_length + 2 * s.window) * self.tap.rate_hz:
            return None
        still = detect_still(z, self.tap.rate_hz, rest_length=s.rest_length, window=s.window,
                             enter=s.enter, leave=s.leave, min_still=s.min_still,
                             timeout=s.timeout)
        if not len(still.intervals):
            return None
        start, stop = still.intervals[-1]
        self._noise = still.noise
        h = round(s.window * self.tap.rate_hz / 2)  # half the detector's window
        if stop < len(t) - h - 1 or start <= h or t[start] < self._since:
            return None  # over, begun before the samples looked at, or before the request
        return float(t[start])


def run_states(protocol, recorder, first: str) -> None:
    """Run `protocol`'s state handlers from `first` until "done" (the one place where its state
    changes); an error is recorded as an `abort` event and raised."""
    protocol.state = first
    try:
        while protocol.state != "done":
            protocol.state = protocol.handlers[protocol.state]()
    except BaseException as exc:
        with interrupts.handling(exc) as cause:
            try:
                recorder.event("abort", protocol.position, {
                    "state": protocol.state, "error": f"{type(cause).__name__}: {cause}"})
            except Exception as record_error:  # noqa: BLE001
                cause.add_note(f"and the abort could not be recorded ({record_error})")
        if cause is exc:
            raise
        raise cause from exc


def record_poses(protocol, imu, spec, clock, path, metadata: dict, view=None) -> None:
    """Run a still-pose `protocol` on the opened `imu` driver (stream `spec`) into the new session
    file `path` with `metadata`; the file keeps every sample and event whatever happens. `view`:
    who watches (`station.acquire.watching`), or None."""
    with SessionWriter.create(path, metadata, {"imu": spec}, clock=clock) as writer:
        _run_poses(protocol, writer, imu, clock, [], view)


def continue_poses(protocol, writer, imu, clock, view=None) -> int:
    """Run a still-pose `protocol` into `writer` (`SessionWriter.resume`d) from the first pose not
    completed, on the opened `imu` driver; returns that pose (`settings.poses` when none was
    left). The completed poses must be 0, 1, ... in order, as the protocols record them. `view`:
    who watches (`station.acquire.watching`), or None."""
    done = [e for e in writer.events() if e.kind == "position_done"]
    if [e.position for e in done] != list(range(len(done))):
        raise InputError(f"{writer.path}: the completed poses are not 0, 1, ... in order; the "
                         "session was not recorded by this station's still-pose protocols")
    if len(done) < protocol.settings.poses:
        _run_poses(protocol, writer, imu, clock, done, view)
    return len(done)


def _run_poses(protocol, writer, imu, clock, done: list, view=None) -> None:
    """Run `protocol` after the completed poses `done` (their `position_done` events) with a
    recorder reading `imu` into `writer`, watched by `view` (None: `Unwatched`)."""
    view = view or Unwatched()
    spec = writer.specs["imu"]
    tap = StreamTap(view.observe_imu(imu), spec.rate_hz, spec.counts_per_unit)
    with Recorder(writer, tap, clock=clock) as recorder:
        view.follow(protocol).run(view.observe_recorder(recorder), tap, done)


def recorded_ups(done: list) -> list:
    """The up directions (3,) the completed poses' `position_done` events record (untrusted
    input); InputError naming the pose if one is not a unit vector."""
    ups = []
    for e in done:
        try:
            u = np.asarray(e.detail.get("up"), dtype=float)
        except (TypeError, ValueError):
            u = np.zeros(0)
        if u.shape != (3,) or not abs(np.linalg.norm(u) - 1) < 1e-6:
            raise InputError(f"pose {e.position + 1} of the session records no up direction; "
                             "the session was not recorded by this station's still-pose "
                             "protocols")
        ups.append(u)
    return ups
