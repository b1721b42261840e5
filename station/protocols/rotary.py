"""The rotary-table protocol for gyros (Rupniewski Section IV) and its Eq. (18) reduction.

Per position j the technician mounts the unit so that a suggested unit-frame direction u_j points
up the table axis; then the station, through the table driver and the recorder:

    mount -> still -> static -> spin_up -> settle -> rotating -> stop -> rest -> mount (j + 1) ...

- still:    the table must stand still for `rest` s;
- static:   the static window (`static` s) gives the bias b'_j; then `guard` s of margin;
- spin_up:  command the rate c and start;
- settle:   wait until the table says "at rate" and the measured rate stays within `tolerance`
            for `steady` s;
- rotating: the rotating window, until the table angle has swept `revolutions` whole turns plus a
            quarter turn of margin (the reduction cuts it to whole turns, and the time of each
            table reading is uncertain by the Modbus latency); the measured rate must stay within
            `tolerance` all along; then `guard` s of margin;
- stop, rest: stop the table and wait until it stands still.

Before each table command that ends a window (spin-up after the static window, stop after the
rotating one) the protocol waits until the recorder holds every sample taken up to then
(`Recorder.drain`): a busy host delays samples, and a sample taken after the command must never be
counted in the window before it. It waits again before `position_done`, so that a completed
position's spin-down and rest are in the file too (the diagnosis compares them; without it the
last position's tail was lost when the recorder stopped).

Every state change happens in one place (`RotaryProtocol.run`). Two faults are recovered from, at
most `retries` times per position, and the position is recorded again without re-mounting the unit
(`restart`: a new `position_start`, so the windows recorded before the fault are discarded):
- the IMU is lost (unplugged): `fault` event, table stopped, the operator is asked to reconnect
  the cable, `resume` event, the recorder reopens the port;
- the table does not answer (Modbus timeout): the driver and the protocol command a stop, a
  `pause` event is recorded and the operator is asked whether to go on; 'yes' records `resume`
  and goes on, 'no' ends the run with `SessionPaused` (the file is complete up to the last
  `position_done`; `station resume` continues it).
A fault after the rotating window, once its samples are all in the file (IMU lost), or while the
table comes to rest (table silent), does not record the position again: it is completed
(`position_done` with detail `interrupted`; the table's rest is watched without the IMU, or not at
all when the table is silent) and the next position follows. A fixture, or a technician who saw the
table finish its turns, re-mounts the unit then.
Any other exception - a table fault, a silent IMU, the operator aborting, Ctrl-C - stops the
table at once and records an `abort` event, so the session file stays consistent (complete
positions end with `position_done`; `run(first=...)` continues after the last one).

Each captured position is checked, once the table rests and every sample is in, when the protocol
reads a copy of the stream (`run(..., tap=StreamTap)`, as `continue_session` does): the samples
found and due in the static and rotating windows through the reduction's own checks (spikes, a
stuck channel), and the static noise against the median of the earlier accepted positions' static
windows (`station.reduce.window_quality`), on the gyro channels. Redo, do not warn
(`station.protocols.redo`): a flagged position - or one whose table moved during the static window
or left its rate while rotating - is not completed: the table is stopped and the position recorded
again at once from its rest (a new `position_start`, detail `redo`, `flags`), up to the settings'
`redo_limit` times, then the session stops with `RedoLimitError`. An accepted position is
confirmed to the operator with its quality and completed (`position_done`).

On a two-axis table (`phis`, `spins`; `station.model.two_axis`, docs/protocols.md "Two-axis
sessions") the mount step sets the position axis to phi_j and the rate axis spins, as above, for the
first len(phis) positions; the `spins` positions after them spin the POSITION axis itself (its rate
mode, `RotaryTable.spin_position`) at the session's rate with alternating sign and the rate axis at
rest: the stimulus is then +-rate times c, the position axis in the unit frame, off the cone of the
others, without which Eq. (7)'s g is not determined. Everything else is the same, with the position
axis' rate, at-rate bit and angle in place of the table's: `rotate_start`/`rotate_end` record the
position angle and the instant it was read (detail `axis: "position"`), from which the reduction
cuts whole revolutions of the position axis; `stop` stops both axes.

The recorded session is reduced offline by `station.reduce.rotary` (Eq. 18).
"""

import logging
from dataclasses import asdict, dataclass

import numpy as np

from drivers.errors import CanBusError, SerialPortError, TableError
from drivers.rotary_table import TableTimeout, not_stopped
from station import limits
from station.acquire import interrupts
from station.acquire.operator import Instruction
from station.acquire.recorder import PlateRecorder, Recorder, RecordingError
from station.acquire.watching import Unwatched
from station.errors import FlaggedWindow, InputError, OperatorAbort, ProtocolError, SessionPaused
from station.files.jsonable import jsonable
from station.model.two_axis import position_angles, spin_axes, spin_signs
from station.protocols.planned import fixture_instruction, rotary_plan, two_axis_plan
from station.protocols.redo import REDO_LIMIT, Redo, check_redo_limit, window_flags
from station.protocols.still import StillSettings, StreamTap
from station.reduce.rotary import gyro_columns
from station.reduce.window_quality import describe, window_quality
from station.session.units import recorded_units

AGAINST = "the earlier static windows"
"""What a static window's noise is compared with, in the confirmations and flags."""
BOUND_READS = 5
"""Table reads at each bound of a rotating window, the one with the shortest round trip kept."""

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class RotarySettings:
    """Rates in rad/s, durations in seconds of the session clock.

    rate        : commanded table rate c (the magnitude of the stimulus)
    revolutions : whole table turns in each rotating window
    static      : length of the static window
    rest        : how long the table must stand still before the static window
    guard       : margin between the end of a window and the next table command
    steady      : how long the measured rate must stay within `tolerance` before recording
    tolerance   : accepted |measured rate - c| while rotating
    poll        : time between two table reads
    timeout     : longest wait for the table to reach rest or the rate
    stale       : longest silence of the IMU before the session is aborted
    retries     : how often one position may be recorded again after a lost IMU or table
    redo_limit  : how often one position may be recorded again after a flagged window
                  (`station.protocols.redo`)
    """

    rate: float = 1.0
    revolutions: int = 2
    static: float = 10.0
    rest: float = 1.0
    guard: float = 1.0
    steady: float = 1.0
    tolerance: float = 0.005
    poll: float = 0.25
    timeout: float = 60.0
    stale: float = 10.0
    retries: int = 3
    redo_limit: int = REDO_LIMIT

    def __post_init__(self):
        """Refuse settings no bench runs (`SETTING_LIMITS`), naming the setting and its range."""
        rate = limits.number(self.rate, "rotary setting rate", -MAX_RATE, MAX_RATE)
        if rate == 0:
            raise InputError("rotary setting rate = 0: the table rate must be a non-zero number "
                             "of rad/s")
        limits.whole(self.revolutions, "rotary setting revolutions", 1, MAX_REVOLUTIONS)
        limits.whole(self.retries, "rotary setting retries", 0, MAX_RETRIES)
        check_redo_limit(self.redo_limit)
        for name, high in SETTING_LIMITS.items():
            limits.positive(getattr(self, name), f"rotary setting {name}", high)


MAX_RATE, MAX_REVOLUTIONS, MAX_RETRIES, MAX_POSITIONS = 50.0, 1000, 100, 10000
"""Largest |table rate| (rad/s), revolutions per window, retries and positions of a session."""
SETTING_LIMITS = {"static": 3600.0, "rest": 3600.0, "guard": 3600.0, "steady": 3600.0,
                  "tolerance": 10.0, "poll": 60.0, "timeout": 3600.0, "stale": 3600.0}
"""Largest value of each duration (s) and of the rate tolerance (rad/s): beyond, a session would
wait for hours (each also must be positive)."""


def _numbers(value, field: str) -> np.ndarray:
    """A recorded list of numbers as a float array; InputError naming `field` otherwise."""
    try:
        return np.asarray(value, float)
    except (TypeError, ValueError):
        raise InputError(f"{field} = {str(value)[:40]}: give a list of numbers") from None


def suggested_axes(n: int) -> np.ndarray:
    """(n, 3) well-spread unit directions (Fibonacci sphere): the table axis in the unit frame.

    Directions spread evenly over the sphere keep the readings matrix well conditioned for any
    sensor layout (the PCA of Algorithm 2 needs v_j spanning R^3 in all directions).
    """
    if n < 1:
        raise InputError(f"number of positions must be positive, got {n}")
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + np.sqrt(5)) * i
    r = np.sqrt(1 - z**2)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def mounting(axis) -> np.ndarray:
    """A rotation table frame -> unit frame whose third column (the table axis) is `axis`."""
    z = np.asarray(axis, float)
    z = z / np.linalg.norm(z)
    helper = np.eye(3)[0] if abs(z[0]) < 0.9 else np.eye(3)[1]
    x = helper - (helper @ z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def instruction(position: int, n: int, axis) -> Instruction:
    """The technician's instruction for mounting position `position` (0-based) of n."""
    words = ", ".join(f"{name} {value:+.3f}" for name, value in zip("xyz", axis, strict=True))
    return Instruction(f"position {position + 1}/{n}: mount the unit so that its direction "
                       f"({words}) points up the table axis", mounting(axis))


class RotaryProtocol:
    """Runs the rotary protocol with a table driver and an operator into a running Recorder.

    table    : `drivers.rotary_table.RotaryTable` (connected) or anything with its methods
    operator : `station.acquire.operator` ConsoleOperator or SimulatedTechnician
    clock    : the session clock (shared with the devices)
    axes     : (n, 3) table-axis directions in the unit frame; default `suggested_axes(20)`
    fixture_poses : instead of axes, the poses of a mounting fixture, {"words", "picture",
               "orientation"} each (`station.protocols.planned.FixturePlan.instructions`)
    phis     : on a two-axis table, the position-axis angle (rad) of each of the first
               len(phis) positions: the mount step commands it (`table.set_position`) instead of
               asking the operator; `axes` are then the rate axis in the unit frame there
               (`station.model.two_axis`)
    spins    : on a two-axis table, the positions after them that spin the position axis
               (`spin_signs` times the rate; `axes`: +-c there); len(axes) = len(phis) + spins
    """

    def __init__(self, table, operator, clock, settings: RotarySettings | None = None, axes=None,
                 fixture_poses=None, phis=None, spins: int = 0):
        self.table = table
        self.recorder = None
        self.operator = operator
        self.clock = clock
        self.settings = settings or RotarySettings()
        self.fixture_poses = fixture_poses
        if fixture_poses:
            axes = [np.asarray(p["orientation"], float)[:, 2] for p in fixture_poses]
        self.axes = suggested_axes(20) if axes is None else np.asarray(axes, float)
        if self.axes.ndim != 2 or self.axes.shape[1] != 3 or len(self.axes) == 0:
            raise InputError(f"axes must be (n, 3) directions, got shape {self.axes.shape}")
        self.phis = None if phis is None else np.asarray(phis, float)
        if isinstance(spins, bool) or not isinstance(spins, int) or spins < 0 \
                or (spins and self.phis is None):
            raise InputError(f"spins must be a whole number >= 0, with phis; got {spins!r}")
        self.spins = spins
        if self.phis is not None and (self.phis.shape != (len(self.axes) - spins,)
                                      or not np.all(np.isfinite(self.phis))):
            raise InputError(f"phis must be one finite angle per position on the cone "
                             f"({len(self.axes) - spins}), got shape {self.phis.shape}")
        self.position = 0
        self.state = "mount"
        self._handlers = {"mount": self._mount, "still": self._still, "static": self._static,
                          "spin_up": self._spin_up, "settle": self._settle,
                          "rotating": self._rotating, "stop": self._stop, "rest": self._rest,
                          "restart": self._restart}
        self._again = {}  # position -> times recorded again after a fault

    def metadata(self) -> dict:
        """What a session file should record about this protocol run."""
        fixture = {"fixture_poses": self.fixture_poses} if self.fixture_poses else {}
        if self.phis is not None:
            fixture["phis"] = self.phis.tolist()
            fixture["spins"] = self.spins
        return {"protocol": "rotary", "settings": asdict(self.settings),
                "axes": self.axes.tolist(), **fixture}

    @classmethod
    def from_metadata(cls, metadata: dict, table, operator, clock) -> "RotaryProtocol":
        """The protocol a session file recorded (`metadata()` of the original run)."""
        if metadata.get("protocol") != "rotary":
            raise InputError(f"the session was recorded with protocol "
                             f"{metadata.get('protocol')!r}, not 'rotary'")
        try:
            settings = RotarySettings(**metadata["settings"])
            axes = _numbers(metadata["axes"], "axes")
            if axes.ndim != 2 or not 1 <= len(axes) <= MAX_POSITIONS or axes.shape[1] != 3 \
                    or not np.all(np.linalg.norm(axes, axis=1) > 0):
                raise InputError(f"axes: give 1 to {MAX_POSITIONS} non-zero directions of 3 "
                                 f"numbers each (got shape {axes.shape})")
            phis = metadata.get("phis")
            phis = None if phis is None else _numbers(phis, "phis")
            spins = limits.whole(metadata.get("spins", 0), "spins", 0, MAX_POSITIONS)
            poses = metadata.get("fixture_poses")
            if poses is not None:
                poses = [{"words": str(p["words"]), "picture": str(p["picture"]),
                          "orientation": np.asarray(p["orientation"], float).reshape(3, 3).tolist()}
                         for p in poses]
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"the session's rotary settings or axes are unusable ({exc}); "
                             "it was not written by this station") from None
        return cls(table, operator, clock, settings, axes, poses, phis, spins)

    def instruction(self, j: int) -> Instruction:
        """The technician's instruction for mounting position j: the fixture pose's words and
        picture, or the direction to point up the table axis."""
        if self.fixture_poses:
            return fixture_instruction(j, len(self.axes), self.fixture_poses[j])
        return instruction(j, len(self.axes), self.axes[j])

    def run(self, recorder, first: int = 0, tap: StreamTap | dict | None = None) -> None:
        """Run positions first..n-1 into `recorder` (a started `station.acquire.recorder.Recorder`);
        the table is stopped whatever happens. `tap`: the StreamTap the recorder reads, or
        {stream: StreamTap} of every unit on a plate (`PlateRecorder`), for the quality of each
        captured position (None: confirmations without it)."""
        if not 0 <= first < len(self.axes):
            raise InputError(f"first position {first} is outside 0..{len(self.axes) - 1}")
        self.recorder, self.position, self.state = recorder, first, "mount"
        self.taps = {} if tap is None else tap if isinstance(tap, dict) else \
            {recorder.stream: tap}
        self._windows, self._static_noise = {}, {stream: [] for stream in self.taps}
        self.redo = Redo(self.settings.redo_limit)
        self._rotated = None  # (position, clock time) of the last rotating window's end
        try:
            while self.state != "done":
                try:  # the one place where the state changes
                    self.state = self._handlers[self.state]()
                    log.debug("position %d: %s", self.position + 1, self.state)
                except RecordingError as exc:
                    if not isinstance(exc.__cause__, ConnectionError):
                        raise
                    self.state = self._reconnect(exc)
                except TableTimeout as exc:
                    self.state = self._pause(exc)
                except FlaggedWindow as exc:
                    self.state = self._redo([exc.flag])
        except SessionPaused:
            raise  # table stopped and `pause` recorded already
        except BaseException as exc:
            with interrupts.handling(exc) as cause:
                log.warning("position %d aborted in state %s: %r", self.position + 1, self.state,
                            exc)
                self._abort(cause)
            if cause is exc:
                raise
            raise cause from exc

    # -- states: each does its work and returns the next state -----------------------------------

    def _mount(self) -> str:
        """Mount the unit at the position: the operator does it, or the table's motorised
        fixture (its `mount` register) or its position axis when it has one; a table timeout
        pauses the session."""
        j = self.position
        detail = {"axis": self.axes[j].tolist()}
        if self._spun(j):
            self.operator.prompt(f"position {j + 1}/{len(self.axes)}: the position axis spins "
                                 "(the rate axis at rest)")
            detail["spin"] = "position"
        elif self.phis is None and self.table.map.fixture:
            self.operator.prompt(f"{self.instruction(j).text} (the fixture mounts it)")
            self.table.mount(j + 1)
            detail["mount"] = j + 1
        elif self.phis is None:
            self.operator.wait(self.instruction(j))
        else:
            self.operator.prompt(f"position {j + 1}/{len(self.axes)}: position axis to "
                                 f"{np.degrees(self.phis[j]):.2f} deg")
            self.table.set_position(float(self.phis[j]))
            detail["phi"] = float(self.phis[j])
        self.recorder.event("position_start", j, detail)
        return "still"

    def _spun(self, j: int) -> bool:
        """Does position j spin the position axis (two-axis sessions' last `spins` positions)?"""
        return self.spins > 0 and j >= len(self.phis)

    def _rate(self) -> float:
        """The commanded rate of the axis that spins at this position (rad/s, signed)."""
        j = self.position
        return self.settings.rate * (spin_signs(self.spins)[j - len(self.phis)]
                                     if self._spun(j) else 1.0)

    def motion(self, reading) -> tuple:
        """(rate, angle, at rate) of the axis that spins at this position."""
        if self._spun(self.position):
            return reading.position_rate, reading.position, reading.position_at_rate
        return reading.rate, reading.angle, reading.at_rate

    def _still(self) -> str:
        self._until(lambda r: r.resting, self.settings.rest, "the table to stand still")
        return "static"

    def _static(self) -> str:
        s, j = self.settings, self.position
        self.operator.prompt(f"position {j + 1}: static window ({s.static:g} s)")
        start = self.recorder.event("static_start", j)
        self._hold(s.static, lambda r: r.resting, "the table moved during the static window")
        self._windows["static"] = (start, self.recorder.event("static_end", j))
        self._hold(s.guard, lambda r: r.resting, "the table moved during the static window")
        self.recorder.drain(self.clock.now(), s.stale)
        return "spin_up"

    def _spin_up(self) -> str:
        if self._spun(self.position):
            self.table.spin_position(self._rate(), timeout=self.settings.timeout)
        else:
            self.table.set_rate(self.settings.rate)
            self.table.start()
        return "settle"

    def _settle(self) -> str:
        s = self.settings
        self._until(lambda r: self.motion(r)[2] and self._on_rate(r), s.steady,
                    f"the table to reach {self._rate():g} rad/s")
        return "rotating"

    def _rotating(self) -> str:
        s, j = self.settings, self.position
        self.operator.prompt(f"position {j + 1}: rotating window ({s.revolutions} turns)")
        start = self._bound()
        begun = self.recorder.event("rotate_start", j, self._angle_detail(start), start.time)
        sweep = 2 * np.pi * (s.revolutions + 0.25)
        deadline = self.clock.now() + sweep / abs(s.rate) + s.timeout
        reading = start
        while abs(self.motion(reading)[1] - self.motion(start)[1]) < sweep:
            self.clock.sleep(s.poll)
            reading = self._poll()
            if not self._on_rate(reading):
                raise FlaggedWindow(f"the table's rate {self.motion(reading)[0]:.4f} rad/s left "
                                    f"{self._rate():g} +- {s.tolerance:g} rad/s in the rotating "
                                    "window")
            if self.clock.now() > deadline:
                swept = abs(self.motion(reading)[1] - self.motion(start)[1])
                raise ProtocolError(f"the table angle did not advance as commanded (swept "
                                    f"{swept:.2f} rad in the rotating window); check the table's "
                                    "encoder")
        bound = self._bound()
        end = self.recorder.event("rotate_end", j, self._angle_detail(bound), bound.time)
        self._windows["rotating"] = (begun, end)
        self._rotated = (j, end)
        self._hold(s.guard, self._on_rate, "the table's rate changed after the rotating window")
        self.recorder.drain(self.clock.now(), s.stale)
        return "stop"

    def _stop(self) -> str:
        self.table.stop()
        return "rest"

    def _rest(self) -> str:
        """The table at rest and every sample in: the position's windows checked
        (`_captured`); a flagged one is recorded again (`_redo`), else the position is done."""
        self._to_rest()
        words, flags = self._captured()
        if flags:
            return self._redo(flags)
        self.recorder.event("position_done", self.position)
        self.operator.prompt(f"position {self.position + 1}/{len(self.axes)} captured" + words)
        self.position += 1
        return "mount" if self.position < len(self.axes) else "done"

    def _to_rest(self, imu: bool = True) -> None:
        """Wait until the table rests and its spin-down and rest are in the file (imu False: the
        IMU is lost, the table alone is watched)."""
        self._until(lambda r: r.resting, self.settings.rest, "the table to stop", imu)
        if imu:
            self.recorder.drain(self.clock.now(), self.settings.stale)

    def _done(self, detail: dict | None = None, imu: bool = True) -> None:
        """The table at rest (`_to_rest`): record `position_done`."""
        self._to_rest(imu)
        self.recorder.event("position_done", self.position, detail)

    def _angle_detail(self, reading) -> dict:
        """A rotating window's bound: the table's angle, or on a spin of the position axis its
        angle and the instant it was read (the reduction interpolates between the two bounds:
        the file's table states are the rate axis')."""
        if self._spun(self.position):
            return {"angle": reading.position, "axis": "position", "time": reading.time,
                    "round_trip": reading.round_trip}
        return {"angle": reading.angle}

    def _windows_in(self) -> bool:
        """The position's rotating window has ended and every sample up to its end is in the
        file: the position is complete whatever happens to the IMU now."""
        return (self._rotated is not None and self._rotated[0] == self.position
                and self.recorder.sampled_until() >= self._rotated[1])

    def _captured(self) -> tuple[str, list]:
        """(": static ...; rotating ..." (`station.reduce.window_quality.describe`), the flags
        (`station.protocols.redo.window_flags`)) of the position just captured, each unit's words
        on their own line (named) and its flags named when there are several; ("", []) without a
        tap. The static noise of an accepted position becomes a reference for the next ones."""
        named = len(self.taps) > 1
        words, flags, noise = [], [], {}
        for stream, tap in self.taps.items():
            qualities = self._unit_quality(stream, tap)
            unit = self.recorder.writer.specs[stream].units[0]
            text = "; ".join(f"{name} {describe(q, unit, AGAINST)}"
                             for name, q in qualities.items())
            name = self.recorder.names[stream] if named else ""
            words.append(f"\n  {name}: {text}" if named else f": {text}")
            flags += [f"{name}: {f}" if named else f
                      for f in window_flags(qualities, AGAINST)]
            noise[stream] = qualities["static"].noise
        if not flags:
            for stream, n in noise.items():
                self._static_noise[stream].append(n)
        return "".join(words), flags

    def _unit_quality(self, stream: str, tap) -> dict:
        """{"static": WindowQuality, "rotating": ...} of one unit's stream and its StreamTap, its
        gyro channels (a temperature channel is not calibrated, `gyro_columns`). The static noise
        is compared with the median of the unit's earlier accepted positions' (it at rest), out of
        line beyond the stillness detector's `enter`; the tap then forgets the position's
        samples."""
        t, z = tap.samples(self._windows["static"][0])
        keep = gyro_columns(self.recorder.writer.specs[stream].units)
        earlier = self._static_noise[stream]
        reference = np.median(earlier, axis=0) if earlier else None
        qualities = {name: window_quality(t, z[:, keep], window, tap.rate_hz, tap.lsb[keep],
                                          reference if name == "static" else None,
                                          StillSettings.enter, name, self.position)
                     for name, window in self._windows.items()}
        tap.forget(self.clock.now())
        return qualities

    def _restart(self) -> str:
        self.operator.prompt(f"position {self.position + 1}: recording it again (leave the unit "
                             "mounted)")
        return self._start_again({"again": True})

    def _redo(self, flags: list) -> str:
        """A window of this position was flagged (`flags`): stop the table and record the position
        again from its rest, without re-mounting (`station.protocols.redo`); RedoLimitError past
        the profile's redo_limit."""
        self._rotated = None  # the flagged attempt is not completed, whatever happens next
        self.table.stop()
        detail = self.redo.attempt(self.position, flags)
        self.operator.prompt(self.redo.words(self.position, flags) + "; leave the unit mounted")
        return self._start_again(detail)

    def _start_again(self, detail: dict) -> str:
        """Record a new `position_start` of this position with `detail` (the windows before it
        are superseded): the position is recorded again from its rest."""
        j = self.position
        again = {"spin": "position"} if self._spun(j) else {}
        self.recorder.event("position_start", j, {"axis": self.axes[j].tolist(), **detail,
                                                  **again})
        return "still"

    # -- faults: each returns the state to go on with ----------------------------------------------

    def _reconnect(self, exc: RecordingError) -> str:
        """The IMU was lost: stop the table, have the cable reconnected, record the position
        again (its windows so far are discarded; every sample recorded stays in the file) - or,
        when its windows were all in, complete it once the table rests and go on with the next."""
        j = self.position
        self._stop_table(exc)
        unit = getattr(exc, "unit", None)  # one of several units on the table: which
        lost = f"the IMU of {unit}" if unit else "the IMU"
        self.recorder.event("fault", j, {"device": "imu", "state": self.state,
                                         "error": f"{type(exc).__name__}: {exc}",
                                         **({"unit": unit} if unit else {})})
        then = self._completed() if self._windows_in() else "restart"
        if then == "restart":
            self._count_again(exc)
        elif then == "done":
            return then  # nothing left to record: the session is complete without the IMU
        for attempt in range(1, self.settings.retries + 2):
            cause = f"{lost} was lost during position {j + 1} ({exc.__cause__})"
            self._ask(cause, lambda c=cause: self.operator.wait(Instruction(
                f"{c}; the table was stopped. Reconnect the IMU's cable without moving the unit, "
                "then confirm")))
            self.recorder.event("resume", j, {"after": "imu lost", "attempt": attempt})
            try:
                self.recorder.reconnect()
                return then
            except ConnectionError as again:
                self.operator.prompt(f"the IMU is still missing: {again}")
        raise ProtocolError(f"{lost} did not come back after {self.settings.retries + 1} "
                            "reconnections; check its power and cable, then resume the "
                            "session") from exc

    def _pause(self, exc: TableTimeout) -> str:
        """The table does not answer: stop it, pause, and go on only if the operator says so.
        A timeout of the table's watchdog heartbeat, delivered from its thread
        (`station.acquire.watchdog.fed`), is handled here once: it is not raised again."""
        interrupts.withdraw(exc)
        j = self.position
        stopped = self._stop_table(exc)
        self.recorder.event("pause", j, {"state": self.state, "table_stopped": stopped,
                                         "error": f"{type(exc).__name__}: {exc}"})
        # at rest the windows were drained and the stop commanded: the position is complete
        then = self._completed(imu=None) if self.state == "rest" else "restart"
        message = (f"the rotary table stopped answering during position {j + 1} ({exc}). "
                   + ("It was commanded to stop" if stopped else
                      "It could not be commanded to stop: STOP IT BY HAND") +
                   "; the session is paused and everything recorded so far is kept.")
        if not self._ask(message, lambda: self.operator.confirm(
                f"{message} Go on once the table answers again?")):
            raise SessionPaused(f"{message} Check the table's cable and power, then run "
                                "`station resume SESSION` to continue.") from exc
        if then == "restart":
            self._count_again(exc)
        self.recorder.event("resume", j, {"after": "table timeout"})
        return then

    @staticmethod
    def _ask(cause: str, question):
        """The operator's answer to `question()`, asked after a device fault described by
        `cause`; when the operator's input is closed (OperatorAbort), the abort says the device's
        cause first, then that nobody could answer."""
        try:
            return question()
        except OperatorAbort as abort:
            raise OperatorAbort(f"{cause.rstrip('. ')}; then {abort}") from abort

    def _completed(self, imu: bool | None = False) -> str:
        """Record `position_done` for a position whose windows are all in the file (imu False:
        the IMU is lost, once the table rests; None: the table does not answer either, at once:
        it was commanded to stop) and go on with the next: its state."""
        if imu is None:
            self.recorder.event("position_done", self.position, {"interrupted": True})
        else:
            self._done({"interrupted": True}, imu)
        self.position += 1
        return "mount" if self.position < len(self.axes) else "done"

    def _count_again(self, exc: BaseException) -> None:
        """ProtocolError once position j has been recorded again `retries` times."""
        j = self.position
        self._again[j] = self._again.get(j, 0) + 1
        if self._again[j] > self.settings.retries:
            raise ProtocolError(f"position {j + 1} failed {self._again[j]} times (last: {exc}); "
                                "fix the bench, then resume the session") from exc

    def _stop_table(self, exc: BaseException) -> bool:
        """Command the table to stop; False if it does not answer. `exc.table_stopped` says which,
        and a note on `exc` tells the operator to stop the table by hand (once)."""
        try:
            self.table.stop()
        except Exception as stop_error:  # noqa: BLE001 - the original error goes on
            if getattr(exc, "table_stopped", None) is not False:
                not_stopped(exc, stop_error)
            return False
        if getattr(exc, "table_stopped", None) is False:
            exc.add_note("a later stop command got through: the table was stopped")
        exc.table_stopped = True
        return True

    def _failed_devices(self, exc: BaseException) -> list:
        """The devices that failed, in words ("rotary table at host:port", "IMU on
        /dev/ttyUSB0"): the table if `exc` or its cause is a table error or no stop got through,
        the IMU if `exc`, its cause or the IMU reader's own failure is a lost link."""
        devices = []
        causes = [exc, exc.__cause__, self.recorder.error]
        if (any(isinstance(e, TableError) for e in causes)
                or getattr(exc, "table_stopped", None) is False):
            devices.append(getattr(self.table, "where", "rotary table"))
        unit = next((f" of {e.unit}" for e in causes if hasattr(e, "unit")), "")
        for e in causes:
            if isinstance(e, SerialPortError | CanBusError):
                devices.append(f"IMU{unit} on {getattr(e, 'port', None) or e.channel}")
                break
        return devices

    # -- helpers ---------------------------------------------------------------------------------

    def _on_rate(self, reading) -> bool:
        return abs(self.motion(reading)[0] - self._rate()) < self.settings.tolerance

    def _poll(self, imu: bool = True):
        """Check the IMU stream (unless `imu` is False), read the table and keep its state (stamped
        by the driver at the middle of the request: the table answered somewhere in between)."""
        if imu:
            self.recorder.check(self.settings.stale)
        reading = self.table.state()
        self.recorder.table(reading)
        if reading.fault:
            raise ProtocolError("the table reports a fault; clear it on the table's controller "
                                "and record the position again")
        return reading

    def _bound(self):
        """A rotating window's bound: the table read `BOUND_READS` times, the reading with the
        shortest round trip kept. Its time is the most certain (the rule of the least delay, as
        NTP's): a spin of the position axis is cut from its two bounds alone, and on a busy host
        one late reply misplaces the cut by the rate times half its round trip. The window's event
        is stamped with this reading's time, not when it is recorded: the reads after it (and a
        busy host) would otherwise put the bound seconds of a fast clock after the angle it
        records, and cut the window short of the turns it swept."""
        return min((self._poll() for _ in range(BOUND_READS)), key=lambda r: r.round_trip)

    def _until(self, condition, hold: float, what: str, imu: bool = True) -> None:
        """Poll until `condition(reading)` has held for `hold` s; ProtocolError after `timeout`."""
        s = self.settings
        deadline = self.clock.now() + s.timeout
        since = None
        while True:
            reading = self._poll(imu)
            now = self.clock.now()
            since = (now if since is None else since) if condition(reading) else None
            if since is not None and now - since >= hold:
                return
            if now > deadline:
                raise ProtocolError(f"timed out after {s.timeout:g} s waiting for {what} "
                                    f"(last state: rate {reading.rate:.4f} rad/s, moving "
                                    f"{reading.moving}, at rate {reading.at_rate})")
            self.clock.sleep(s.poll)

    def _hold(self, duration: float, condition, problem: str) -> None:
        """Poll for `duration` s; FlaggedWindow(problem) if `condition(reading)` fails once (the
        position is recorded again)."""
        end = self.clock.now() + duration
        while True:
            if not condition(self._poll()):
                raise FlaggedWindow(problem)
            if self.clock.now() >= end:
                return
            self.clock.sleep(min(self.settings.poll, max(0.0, end - self.clock.now())))

    def _abort(self, exc: BaseException) -> None:
        """Stop the table first, complete a position whose rotating window had ended, then record
        why the session ended: the state, the devices that failed, whether the table was stopped
        and the error with its notes (what the operator was told); failures become notes."""
        stopped = self._stop_table(exc)
        if self._rotated is not None and self._rotated[0] == self.position:
            self._complete(exc)
        devices = self._failed_devices(exc)
        if any(d not in str(exc) for d in devices):
            exc.add_note(f"lost: {' and '.join(devices)}")
        words = "; ".join([str(exc), *getattr(exc, "__notes__", ())])
        try:
            self.recorder.event("abort", self.position, {
                "state": self.state, "devices": devices, "table_stopped": stopped,
                "error": f"{type(exc).__name__}: {words}"})
        except Exception as record_error:  # noqa: BLE001
            exc.add_note(f"and the abort could not be recorded in the session ({record_error})")


    def _complete(self, exc: BaseException) -> None:
        """The position's windows are all recorded: let the table come to rest and record
        `position_done`, so that a resume goes on with the next position, as a fixture or a
        technician who saw the table finish its turns does."""
        try:
            lost = self.recorder.error is not None
            if lost and not self._windows_in():
                raise RecordingError("the IMU was lost before the rotating window was all in")
            self._done({"interrupted": True}, imu=not lost)
        except Exception as failed:  # noqa: BLE001 - the position is then recorded again
            exc.add_note(f"position {self.position + 1} is recorded again on resume: {failed}")


def continue_session(writer, metadata: dict, imu, table, operator, clock, view=None,
                     others: dict | None = None) -> int:
    """Run the rotary protocol recorded in `metadata` into `writer` (`SessionWriter.create`d or
    `.resume`d), from the position after the last completed one; returns that first position
    (len(axes) when nothing was left to record). `view`: a `station.acquire.live_view.LiveView` to
    show. `others`: {stream: opened driver} of the other units on the table's plate (metadata
    `units`, `station.session.units`), recorded beside `imu` by one `PlateRecorder`.

    The IMU link's counters (CRC failures, gaps, ...) are recorded at the end as a `note` event
    with a `link` detail (and with several units, its `stream`), for the report."""
    view = view or Unwatched()
    protocol = view.follow(
        RotaryProtocol.from_metadata(metadata, table, view.observe_operator(operator), clock))
    last = writer.last_completed_position
    first = 0 if last is None else last + 1
    if first < len(protocol.axes):
        names = unit_names(metadata, writer) if others else {}
        taps = {stream: StreamTap(view.observe_imu(device, name=names.get(stream, "")),
                                  writer.specs[stream].rate_hz,
                                  writer.specs[stream].counts_per_unit)
                for stream, device in {"imu": imu, **(others or {})}.items()}
        recorder = (PlateRecorder(writer, taps, names, clock=clock)
                    if others else Recorder(writer, taps["imu"], clock=clock))
        with recorder, view.show():
            try:
                protocol.run(view.observe_recorder(recorder), first, taps)
            finally:
                for stream, device in {"imu": imu, **(others or {})}.items():
                    stats = getattr(device, "stats", None)
                    if stats is not None:
                        recorder.event("note", None, {"text": "link statistics",
                                                      "link": _counters(stats),
                                                      **({"stream": stream} if others else {})})
    return first


def unit_names(metadata: dict, writer) -> dict:
    """{stream: "unit <serial> (stream <name>)"} of a session with several units."""
    units = recorded_units(metadata, writer.specs, writer.path)
    return {u.stream: f"unit {u.unit_serial} (stream {u.stream})" for u in units}


def record_session(bench, imu, table, out, operator, clock, spec, metadata: dict,
                   view=None, others: dict | None = None) -> None:
    """`station record`'s rotary session (`station.protocols.KINDS` acquire): the protocol with
    the bench profile's settings at `suggested_axes(bench.positions)`; on a two-axis table
    (`bench.spins` > 0) at `position_angles(bench.positions)` of the position axis then
    `bench.spins` spins of it, set by the table itself, or with a [plan] (`bench.plan`) at the
    planned angles and spins (`station.protocols.planned.two_axis_plan`); or, when the profile
    describes a fixture, at the planned fixture poses (`station.protocols.planned`); a plan's
    expected eps is told before the session. Run with the opened `imu` and `table` drivers into
    the new session file `out` (stream `spec`, `metadata` with the table's register map added to
    its device profiles); `view` a LiveView to show, or None. `others`: {stream: opened driver}
    of the bench's other units on the plate (`bench.units`), each with its own stream."""
    from drivers.profile import load_profile
    from station.session import SessionWriter, StreamSpec

    plan = None
    if bench.fixture is not None:
        plan = rotary_plan(bench.fixture, bench.settings, bench.positions)
        protocol = RotaryProtocol(table, operator, clock, bench.settings,
                                  fixture_poses=plan.instructions())
    elif bench.plan is not None:
        plan = two_axis_plan(bench.plan, bench.settings, bench.positions)
        protocol = RotaryProtocol(table, operator, clock, bench.settings, plan.axes(),
                                  phis=plan.phis, spins=plan.spins)
    else:
        phis = position_angles(bench.positions) if bench.spins else None
        axes = spin_axes(phis, bench.spins) if bench.spins else suggested_axes(bench.positions)
        protocol = RotaryProtocol(table, operator, clock, bench.settings, axes, phis=phis,
                                  spins=bench.spins)
    metadata = {**protocol.metadata(), **metadata}
    if plan is not None:
        operator.prompt(plan.prompt())
        metadata["plan"] = {"expected_eps": plan.eps, "reading_sigma": plan.sigma}
    metadata["profiles"]["table"] = load_profile(bench.table_source).tables
    streams = {"imu": spec, **{u.stream: StreamSpec.from_profile(u.imu.imu)
                               for u in bench.units if u.stream in (others or {})}}
    with SessionWriter.create(out, metadata, streams, clock=clock) as writer:
        continue_session(writer, metadata, imu, table, operator, clock, view, others)


def _counters(stats) -> dict:
    """The numeric counters of a link's statistics, as JSON (station.files.jsonable)."""
    return jsonable({k: v for k, v in vars(stats).items()
                     if isinstance(v, int | float | np.integer | np.floating)})
