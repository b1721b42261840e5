"""The right-angle-iron protocol for accelerometers (Hwangbo & Kanade) and its reduction.

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

Face recognition (`recognise_faces`): the averaged reading z_j gives the up direction in the unit
frame through the nominal layout, u_j ~ (A A^T)^-1 A (z_j - b_guess); within a mounting the first
pose is face "+x", a later pose within `tolerance_deg` of (the opposite of) an earlier face is that
face (its opposite), one perpendicular to all earlier axes opens the next axis. Any consistent
labelling gives the same constraints (`station.solve.constraints.from_faces`, Eq. 15: same face 1,
perpendicular 0, opposite -1, only within a mounting); the solver is `station.calibrate(M, g,
bias="estimate", constraints=...)` = Hwangbo & Kanade's factorization + maximum likelihood.
"""

import dataclasses
from dataclasses import asdict, dataclass

import numpy as np

from station.solve.constraints import FACES, from_faces
from station.errors import CalibrationInputError, InputError
from station.acquire.operator import Instruction
from station.protocols.rotary import mounting
from station.protocols.still import (
    PoseWatcher,
    StillReadings,
    StillSettings,
    StreamTap,
    run_states,
    still_readings,
    up_direction,
)

FACE_UP = {f: (1.0 if f[0] == "-" else -1.0) * np.eye(3)[FACES.index(f) // 2] for f in FACES}
"""Up direction in the iron frame when the iron stands on face f (its outward normal points down)."""


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
        if not (isinstance(self.mountings, int) and self.mountings >= 1):
            raise InputError(f"mountings must be a whole number >= 1, got {self.mountings!r}")
        if not self.tolerance_deg > 0:
            raise InputError("tolerance_deg must be positive")


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
        return self.settings.mountings * len(self.settings.faces)

    def metadata(self) -> dict:
        """What a session file should record about this protocol run."""
        return {"protocol": "iron", "settings": asdict(self.settings),
                "a_nominal": self.a_nominal.tolist(), "gravity": self.settings.gravity}

    def run(self, recorder, tap: StreamTap) -> None:
        """Record every pose into `recorder` (started, reading `tap`); an error is recorded as an
        `abort` event and raised."""
        self.recorder, self.position = recorder, 0
        self.watcher = PoseWatcher(self.settings, self.clock, self.operator, recorder, tap)
        run_states(self, recorder, "mount")

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
        self.recorder.event("position_start", j, {"mounting": self._mounting(), "face_asked": face})
        return "settle"

    def _settle(self) -> str:
        self.watcher.settle(f"asking for pose {self.position + 1}")
        return "hold"

    def _hold(self) -> str:
        s, j = self.settings, self.position
        z = self.watcher.hold(j)
        if z is None:
            return "settle"
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

    def _mounting(self, position: int | None = None) -> int:
        j = self.position if position is None else position
        return j // len(self.settings.faces)


# ------------------------------------------------------------------------------------ reduction


@dataclass(frozen=True)
class IronReadings(StillReadings):
    """`StillReadings` of an iron session and the faces recognised from the data (P labels)."""

    faces: list

    def take(self, keep):
        """The readings of the poses `keep` (column indices), in that order, with their faces: the
        constraints follow the subset."""
        keep = list(keep)
        return dataclasses.replace(super().take(keep), faces=[self.faces[k] for k in keep])

    def constraints(self):
        """The inner-product constraints of the poses (Eq. 15)."""
        return from_faces(self.faces, self.mountings)


def iron_readings(session, stream: str = "imu", a_nominal=None, bias_guess=None,
                  tolerance_deg: float = 20.0, **detector) -> IronReadings:
    """The still poses of an iron session (`station.files.session.Session`, `still_readings`) and their
    faces. `a_nominal` defaults to the metadata's (or the identity for a triad); `detector` (the
    stillness detector's options and `trim`) goes to `still_readings`."""
    still = still_readings(session, stream, **detector)
    if a_nominal is None:
        a_nominal = session.metadata.get("a_nominal", np.eye(3)[:, : still.M.shape[0]].tolist())
    faces = recognise_faces(up_direction(still.M, a_nominal, bias_guess), still.mountings,
                            tolerance_deg)
    return IronReadings(still.M, still.sigma, still.windows, still.mountings, faces)
