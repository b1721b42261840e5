"""The right-angle-iron protocol for accelerometers (Hwangbo & Kanade).

The unit is fixed in a right-angle iron in one or more mountings; for each mounting the technician
stands the iron on its faces in turn. The station needs no key press: it watches the stream and
finds each still pose itself (`station.protocols.still.PoseWatcher`), then recognises the face
from the data.

    mount (new mounting) -> face -> settle -> hold -> face (next) ... -> mount ... -> done

- mount:  ask the technician to fix the unit in the iron in a new way (every `faces` poses) and
          wait until it is still again: that pose is not a requested face;
- face:   ask for the next face (the instruction's orientation is the iron's attitude, world ->
          iron frame, third column up);
- settle: wait for a still interval that started after the last pose (an open interval of at
          least the detector's `min_still`); `timeout` s without one is a ProtocolError;
- hold:   wait until the first `hold` s of the still interval are recorded and still (a motion
          sends the protocol back to settle); `static_end` records that window (detail `window`,
          clock seconds: the averaging window does not depend on when the host got round to
          polling); then the face is recognised and `position_done` recorded.

Face recognition (`station.reduce.iron.recognise_faces`, live and offline by
`station.reduce.iron.iron_readings`): the averaged reading z_j gives the up direction in the unit
frame through the nominal layout, u_j ~ (A A^T)^-1 A (z_j - b_guess); within a mounting the first
pose is face "+x", a later pose within `tolerance_deg` of (the opposite of) an earlier face is that
face (its opposite), one perpendicular to all earlier axes opens the next axis. Any consistent
labelling gives the same constraints (`station.solve.constraints.from_faces`, Eq. 15: same face 1,
perpendicular 0, opposite -1, only within a mounting); the solver is `station.calibrate(M, g,
bias="estimate", constraints=...)` = Hwangbo & Kanade's factorization + maximum likelihood.
"""

from dataclasses import asdict, dataclass

import numpy as np

from station import limits
from station.acquire.operator import Instruction
from station.errors import CalibrationInputError, InputError
from station.protocols.rotary import mounting
from station.protocols.still import (
    PoseWatcher,
    StillSettings,
    StreamTap,
    continue_poses,
    record_poses,
    recorded_ups,
    run_states,
)
from station.reduce.iron import recognise_faces
from station.reduce.still import up_direction
from station.solve.constraints import FACES

FACE_UP = {f: (1.0 if f[0] == "-" else -1.0) * np.eye(3)[FACES.index(f) // 2] for f in FACES}
"""Up direction in the iron frame when the iron stands on face f (its outward normal points
down)."""


@dataclass(frozen=True)
class IronSettings(StillSettings):
    """`StillSettings` (gravity, hold and the stillness detector) and:

    mountings : how many ways the unit is fixed in the iron
    faces     : the faces asked for in each mounting, in order
    tolerance_deg : face recognition tolerance
    """

    mountings: int = 2
    faces: tuple = FACES
    tolerance_deg: float = 20.0

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "faces", tuple(self.faces))
        unknown = [f for f in self.faces if f not in FACES]
        if unknown or not self.faces:
            raise InputError(f"faces must be a non-empty list of {FACES}, got {self.faces!r}")
        limits.whole(self.mountings, "mountings", 1, 100)
        limits.positive(self.tolerance_deg, "tolerance_deg", 90.0)

    @property
    def poses(self) -> int:
        """Poses recorded: the `faces` in each of the `mountings`."""
        return self.mountings * len(self.faces)


class IronProtocol:
    """Runs the iron protocol with an operator into a running Recorder reading a `StreamTap`.

    operator  : `station.acquire.operator` ConsoleOperator or a simulated technician
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
        self.recorder = self.watcher = None
        self.position, self.state = 0, "mount"
        self.directions, self.labels = [], []
        self.handlers = {"mount": self._mount, "face": self._face, "settle": self._settle,
                         "hold": self._hold}

    @property
    def poses(self) -> int:
        return self.settings.poses

    def metadata(self) -> dict:
        """What a session file should record about this protocol run."""
        return {"protocol": "iron", "settings": asdict(self.settings),
                "a_nominal": self.a_nominal.tolist(), "gravity": self.settings.gravity}

    @classmethod
    def from_metadata(cls, metadata: dict, operator, clock) -> "IronProtocol":
        """The protocol a session file recorded (`metadata()` of the original run)."""
        try:
            return cls(operator, clock, metadata["a_nominal"], IronSettings(**metadata["settings"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"the session's iron settings or layout are unusable ({exc}); it "
                             "was not written by this station") from None

    def run(self, recorder, tap: StreamTap, done=()) -> None:
        """Record every pose after the completed ones `done` (their `position_done` events, for
        a resumed session) into `recorder` (started, reading `tap`); an error is recorded as an
        `abort` event and raised. A session resumed within a mounting goes on with its next face:
        the unit must still be fixed in the iron as it was."""
        self.recorder, self.position = recorder, len(done)
        self.directions = recorded_ups(done)
        self.labels = [e.detail.get("face") for e in done]
        if self.labels and not set(self.labels) <= set(FACES):
            raise InputError("the session's completed poses record no iron faces; it was not "
                             "written by this station")
        self.watcher = PoseWatcher(self.settings, self.clock, self.operator, recorder, tap)
        first = "mount" if self.position % len(self.settings.faces) == 0 else "face"
        if first == "face":
            self.operator.prompt(f"mounting {self._mounting() + 1}/{self.settings.mountings} goes "
                                 "on: leave the unit fixed in the iron as it was")
        run_states(self, recorder, first)

    # -- states ----------------------------------------------------------------------------------

    def _mount(self) -> str:
        k = self._mounting()
        self.watcher.request()
        self.operator.wait(Instruction(f"mounting {k + 1}/{self.settings.mountings}: fix the unit "
                                       "in the iron in a way not used before and put it down"))
        self.watcher.settle(f"re-mounting {k + 1}")  # the pose after it is not a requested face
        return "face"

    def _face(self) -> str:
        j, face = self.position, self.settings.faces[self.position % len(self.settings.faces)]
        self.watcher.request()
        self.operator.wait(Instruction(f"pose {j + 1}/{self.poses}: stand the iron on its face "
                                       f"{face} and let go", mounting(FACE_UP[face])))
        self.watcher.start(j, {"mounting": self._mounting(), "face_asked": face})
        return "settle"

    def _settle(self) -> str:
        self.watcher.settle(f"asking for pose {self.position + 1}")
        return "hold"

    def _hold(self) -> str:
        s, j = self.settings, self.position
        held = self.watcher.hold(j)
        if held is None:
            return "settle"
        z, quality = held
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
        self.watcher.confirm(f"pose {j + 1}/{self.poses} captured (face {face})", quality, "m/s^2")
        self.position += 1
        if self.position == self.poses:
            return "done"
        return "mount" if self.position % len(s.faces) == 0 else "face"

    def _mounting(self, position: int | None = None) -> int:
        j = self.position if position is None else position
        return j // len(self.settings.faces)


def record_session(bench, imu, table, out, operator, clock, spec, metadata: dict,
                   view=None) -> None:
    """`station record`'s iron session (`station.protocols.KINDS` acquire): the protocol with
    the bench profile's layout and settings, run with the opened `imu` driver (stream `spec`) into
    the new session file `out`; no table; `view` watches it (`station.acquire.watching`) or is
    None."""
    protocol = IronProtocol(operator, clock, bench.layout, bench.settings)
    record_poses(protocol, imu, spec, clock, out, {**protocol.metadata(), **metadata},
                 view)


def continue_session(writer, metadata: dict, imu, table, operator, clock, view=None) -> int:
    """`station resume`'s iron session (`station.protocols.KINDS` resume): the protocol the session
    recorded, from its first pose not completed, with the opened `imu` driver into `writer`
    (`SessionWriter.resume`d), watched by `view`; returns that pose. No table."""
    return continue_poses(IronProtocol.from_metadata(metadata, operator, clock), writer, imu, clock,
                          view)
