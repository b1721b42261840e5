"""The free-static protocol for accelerometers (multi-position calibration, no fixture).

The technician turns the unit by hand into a sequence of poses and lets go; each pose needs only to
be still and different from the others, not exact: the station measures where "up" is. The poses
asked for are the unit's 6 faces, then its 8 corners, then its 12 edges (`GUIDED_POSES`), which
spread the stimulus directions over the whole sphere as the biases need. No key press is needed
between poses: the station finds each still pose itself (`station.protocols.still.PoseWatcher`).

    pose -> settle -> hold -> pose (next) ... -> done

- pose:   ask for the next pose (the instruction's orientation is an attitude whose third column
          is the unit-frame direction asked to point up);
- settle: wait for a still interval that began after the last pose's window;
- hold:   record the first `hold` s of it (a motion sends the protocol back to settle); the up
          direction u_j = the nominal least-squares direction of the accelerometers' mean. A pose
          within `separation_deg` of an earlier one adds almost nothing: the technician is told
          which and the same pose is asked for again; otherwise `position_done` (detail `up`).

Every accelerometer channel of the stream (unit m/s^2) is calibrated; other channels (gyros) help
the stillness detection (`station.reduce.static.static_readings` reduces the recording). The
solver (`station.solve.still.calibrate_still`) is
`station.calibrate(M, g, d=3, bias="estimate")`: the ellipsoid closed form for a triad, Hwangbo &
Kanade's joint-bias factorization for m > 3, then maximum likelihood with each mean's standard
error.
"""

import dataclasses
import itertools
from dataclasses import asdict, dataclass

import numpy as np

from station.acquire.operator import Instruction
from station.errors import CalibrationInputError, InputError
from station.protocols.planned import static_plan
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
from station.reduce.static import accelerometer_channels
from station.reduce.still import up_direction


def _guided_poses() -> list:
    """(name, unit-frame up direction, words) of the faces, corners and edges of the unit."""
    poses = []
    for k in (1, 3, 2):  # faces, corners, edges
        for axes in itertools.combinations(range(3), k):
            for signs in itertools.product((1, -1), repeat=k):
                up = np.zeros(3)
                up[list(axes)] = signs
                name = "".join(("+" if s > 0 else "-") + "xyz"[i]
                               for i, s in zip(axes, signs, strict=True))
                what = {1: f"lay the unit down with its {name} axis pointing up",
                        2: f"rest the unit on an edge: {name[:2]} and {name[2:]} pointing up "
                           "about equally (45 degrees), the third axis level",
                        3: f"stand the unit on a corner: {name[:2]}, {name[2:4]} and {name[4:]} "
                           "all pointing up about equally"}[k]
                poses.append((name, up / np.linalg.norm(up), what))
    return poses


GUIDED_POSES = _guided_poses()
"""The 26 poses the protocol asks for, in order: 6 faces, 8 corners, 12 edges."""


@dataclass(frozen=True)
class StaticSettings(StillSettings):
    """`StillSettings` (gravity, hold and the stillness detector) and:

    poses          : how many poses to record (12 .. 26: the first `poses` of `GUIDED_POSES`; a
                     triad with biases has 9 unknowns, and 9 poses determine them exactly, with
                     nothing left to check the fit and, with noise, a quadric that may not close)
    separation_deg : smallest angle between the up directions of two poses
    """

    poses: int = 18
    separation_deg: float = 15.0

    def __post_init__(self):
        super().__post_init__()
        if not (isinstance(self.poses, int) and 12 <= self.poses <= len(GUIDED_POSES)):
            raise InputError(f"poses must be a whole number from 12 (a triad's 9 unknowns and 3 to "
                             f"check the fit) to {len(GUIDED_POSES)}, got {self.poses!r}")
        if not 0 < self.separation_deg < 35:
            raise InputError("separation_deg must lie between 0 and 35 degrees (the guided poses "
                             f"are 35 degrees apart), got {self.separation_deg!r}")


class StaticProtocol:
    """Runs the free-static protocol with an operator into a running Recorder reading a
    `StreamTap`.

    operator  : `station.acquire.operator` ConsoleOperator or a simulated technician
    clock     : the session clock (shared with the devices)
    a_nominal : (3, m_acc) nominal layout of the accelerometers (SI readings), for the up direction
    units     : the stream's channel units (the accelerometers are the m/s^2 ones)
    poses     : (name, up, words) asked in order; default `GUIDED_POSES` (a fixture's plan:
                `station.protocols.planned.FixturePlan.guided`)
    """

    def __init__(self, operator, clock, a_nominal, units, settings: StaticSettings | None = None,
                 poses=None):
        self.operator = operator
        self.clock = clock
        self.a_nominal = np.asarray(a_nominal, float)
        self.channels = accelerometer_channels(units)
        if self.a_nominal.shape != (3, len(self.channels)):
            raise CalibrationInputError(
                f"the nominal layout has shape {self.a_nominal.shape} for "
                f"{len(self.channels)} accelerometer channels.",
                f"Give 3 rows and {len(self.channels)} columns, one per accelerometer.")
        self.settings = settings or StaticSettings()
        self.poses = GUIDED_POSES if poses is None else poses
        if len(self.poses) < self.settings.poses:
            raise InputError(f"{self.settings.poses} poses asked for, {len(self.poses)} given")
        self.recorder = self.watcher = None
        self.position, self.state = 0, "pose"
        self.directions = []
        self.handlers = {"pose": self._pose, "settle": self._settle, "hold": self._hold}

    def metadata(self) -> dict:
        """What a session file should record about this protocol run."""
        return {"protocol": "static", "settings": asdict(self.settings),
                "a_nominal": self.a_nominal.tolist(), "gravity": self.settings.gravity,
                "channels": self.channels.tolist()}

    @classmethod
    def from_metadata(cls, metadata: dict, operator, clock, units) -> "StaticProtocol":
        """The protocol a session file recorded (`metadata()` of the original run; `units` of its
        stream)."""
        try:
            settings = StaticSettings(**metadata["settings"])
            return cls(operator, clock, metadata["a_nominal"], units, settings,
                       _fixture_poses(metadata.get("fixture_poses")))
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise InputError(f"the session's static settings or layout are unusable ({exc}); it "
                             "was not written by this station") from None

    def run(self, recorder, tap: StreamTap, done=()) -> None:
        """Record every pose after the completed ones `done` (their `position_done` events, for
        a resumed session) into `recorder` (started, reading `tap`); an error is recorded as an
        `abort` event and raised."""
        self.recorder, self.position = recorder, len(done)
        self.directions = recorded_ups(done)
        self.watcher = PoseWatcher(self.settings, self.clock, self.operator, recorder, tap,
                                   self.channels)
        run_states(self, recorder, "pose")

    # -- states ----------------------------------------------------------------------------------

    def _pose(self) -> str:
        j = self.position
        name, up, words = self.poses[j]
        self.watcher.request()
        self.operator.wait(Instruction(f"pose {j + 1}/{self.settings.poses}: {words}, and let go",
                                       mounting(up)))
        self.watcher.start(j, {"pose_asked": name})
        return "settle"

    def _settle(self) -> str:
        self.watcher.settle(f"asking for pose {self.position + 1}")
        return "hold"

    def _hold(self) -> str:
        j = self.position
        held = self.watcher.hold(j)
        if held is None:
            return "settle"
        z, quality = held
        u = up_direction(z[self.channels, None], self.a_nominal)[0]
        if self.directions:
            angles = np.degrees(np.arccos(np.clip(np.array(self.directions) @ u, -1, 1)))
            i = int(np.argmin(angles))
            if angles[i] < self.settings.separation_deg:
                self.operator.prompt(
                    f"pose {j + 1} is {angles[i]:.0f} deg from pose {i + 1}; it adds little. "
                    f"Turn the unit further ({self.poses[j][2]}).")
                self.recorder.event("note", j, {"text": f"refused: {angles[i]:.1f} deg from "
                                                        f"pose {i + 1}"})
                return "pose"
        self.directions.append(u)
        self.recorder.event("position_done", j, {"up": u.tolist()})
        self.watcher.confirm(f"pose {j + 1}/{self.settings.poses} captured", quality, "m/s^2")
        self.position += 1
        return "done" if self.position == self.settings.poses else "pose"


def record_session(bench, imu, table, out, operator, clock, spec, metadata: dict,
                   view=None) -> None:
    """`station record`'s free-static session (`station.protocols.KINDS` acquire): the protocol with
    the bench profile's layout and settings, run with the opened `imu` driver (stream `spec`) into
    the new session file `out`; no table; `view` watches it (`station.acquire.watching`) or is
    None. With a fixture in the profile, the poses are its planned ones
    (`station.protocols.planned.static_plan`), the expected eps told first."""
    if bench.fixture is None:
        protocol = StaticProtocol(operator, clock, bench.layout, spec.units, bench.settings)
    else:
        plan = static_plan(bench.fixture, bench.settings)
        operator.prompt(plan.prompt())
        settings = dataclasses.replace(bench.settings, poses=len(plan.poses))
        protocol = StaticProtocol(operator, clock, bench.layout, spec.units, settings,
                                  plan.guided())
        metadata = {**metadata, "fixture_poses": plan.instructions(),
                    "plan": {"expected_eps": plan.eps, "reading_sigma": plan.sigma}}
    record_poses(protocol, imu, spec, clock, out, {**protocol.metadata(), **metadata},
                 view)


def _fixture_poses(steps) -> list | None:
    """The poses of a fixture's plan as a session records them (`fixture_poses`:
    `station.protocols.planned.FixturePlan.instructions`), as the protocol asks them (name, up,
    words; `FixturePlan.guided`); None for a session without a fixture."""
    if steps is None:
        return None
    return [(f"fixture pose {j + 1}", np.asarray(step["orientation"], float)[:, 2],
             f"set the cube {step['words']}") for j, step in enumerate(steps)]


def continue_session(writer, metadata: dict, imu, table, operator, clock, view=None) -> int:
    """`station resume`'s free-static session (`station.protocols.KINDS` resume): the protocol the
    session recorded, from its first pose not completed, with the opened `imu` driver into
    `writer` (`SessionWriter.resume`d), watched by `view`; returns that pose. No table."""
    protocol = StaticProtocol.from_metadata(metadata, operator, clock, writer.specs["imu"].units)
    return continue_poses(protocol, writer, imu, clock, view)
