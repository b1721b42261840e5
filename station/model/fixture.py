"""A mounting fixture a technician can set by hand: a cube with lettered faces, and optionally a
45-degree wedge, and the unit orientations it reaches, each with its words.

The unit is screwed into a cube whose faces carry the letters A-F; face A carries an arrow
painted from its centre toward face C, so the cube cannot be set mirrored by mistake. The cube's
own frame (x, y, z) has its faces' outward normals

    A = +x   B = -x   C = +y   D = -y   E = +z   F = -z

and `mounting` (3 x 3, cube frame -> unit frame; the identity when the unit's axes are the
cube's) says how the unit sits in it.

The bench frame (the table frame of the rotary protocol, docs/conventions.md) has z up (the
rotary table's axis, or against gravity), x toward the front (the technician) and y = z x x (to
the technician's right as they face the bench). A pose is said as

    "face F down, face A toward the front"             (flat on the table: 6 x 4 = 24 poses)
    "on the wedge: face F on the slope, face A toward the front"   (24 more)

The wedge's slope rises away from the technician at `wedge_deg` (45 degrees by default): the face
named rests on the slope and the front face looks down the slope. Flat, the up direction in the
cube frame is -n(down); on the wedge it is -cos(t) n(down) - sin(t) n(front), a direction between
two faces (an edge diagonal at 45 degrees).

`Pose.orientation` is the bench frame -> unit frame rotation (its columns are the bench's x, y,
z in the unit frame; the third is the unit-frame direction that points up), as
`station.acquire.operator.Instruction` takes it.
"""

from dataclasses import dataclass, field

import numpy as np

from station.errors import InputError

FACES = {"A": (1, 0, 0), "B": (-1, 0, 0), "C": (0, 1, 0), "D": (0, -1, 0), "E": (0, 0, 1),
         "F": (0, 0, -1)}
"""Outward normal of each lettered face in the cube's frame."""


@dataclass(frozen=True)
class Pose:
    """One way to set the cube: its words and the bench -> unit rotation it gives."""

    words: str
    down: str  # the face on the table (flat) or on the wedge's slope
    front: str  # the face toward the technician
    wedge: bool
    orientation: np.ndarray  # (3, 3) bench frame -> unit frame
    cube: np.ndarray  # (3, 3) bench frame -> cube frame

    @property
    def up(self) -> np.ndarray:
        """The unit-frame direction that points up (the table axis, or against gravity)."""
        return self.orientation[:, 2]


@dataclass(frozen=True)
class Fixture:
    """A lettered cube (with the unit in it as `mounting`), optionally with a wedge."""

    mounting: np.ndarray = field(default_factory=lambda: np.eye(3))  # cube -> unit frame
    wedge: bool = False
    wedge_deg: float = 45.0

    def __post_init__(self):
        r = np.asarray(self.mounting, float)
        if r.shape != (3, 3) or not np.allclose(r.T @ r, np.eye(3), atol=1e-6) \
                or np.linalg.det(r) < 0:
            raise InputError("the fixture's mounting must be a 3 x 3 rotation (cube frame -> unit "
                             "frame, rows of the unit's x, y, z in the cube's axes); give "
                             "orthonormal rows with determinant +1")
        if not 0 < self.wedge_deg < 90:
            raise InputError(f"the wedge angle must be between 0 and 90 degrees, got "
                             f"{self.wedge_deg!r}")
        object.__setattr__(self, "mounting", r)

    def poses(self) -> list:
        """Every pose the fixture reaches: the 24 flat ones, then (with a wedge) the 24 on it."""
        return [self.pose(down, front, wedge)
                for wedge in ((False, True) if self.wedge else (False,))
                for down in FACES for front in FACES
                if _perpendicular(down, front)]

    def pose(self, down: str, front: str, wedge: bool = False) -> Pose:
        """The pose with face `down` on the table (or the wedge's slope), face `front` toward the
        technician."""
        if down not in FACES or front not in FACES or not _perpendicular(down, front):
            raise InputError(f"no cube pose has face {down!r} down and face {front!r} toward the "
                             f"front: name two neighbouring faces of {', '.join(FACES)}")
        n_down, n_front = np.array(FACES[down], float), np.array(FACES[front], float)
        t = np.radians(self.wedge_deg) if wedge else 0.0
        up = -np.cos(t) * n_down - np.sin(t) * n_front
        ahead = np.cos(t) * n_front - np.sin(t) * n_down  # the bench's x in the cube frame
        cube = np.column_stack([ahead, np.cross(up, ahead), up])
        words = (f"on the wedge: face {down} on the slope, face {front} toward the front"
                 if wedge else f"face {down} down, face {front} toward the front")
        return Pose(words, down, front, wedge, self.mounting @ cube, cube)

    def reachable_up(self) -> tuple[np.ndarray, list]:
        """(k, 3) distinct unit-frame up directions and, for each, the first pose giving it: a
        rotary stimulus or gravity sees only the up direction, not the turn about it."""
        ups, first = [], []
        for pose in self.poses():
            if not any(np.allclose(pose.up, u, atol=1e-9) for u in ups):
                ups.append(pose.up)
                first.append(pose)
        return np.array(ups), first


def _perpendicular(a: str, b: str) -> bool:
    return int(np.dot(FACES[a], FACES[b])) == 0


def picture(pose: Pose) -> str:
    """An ASCII picture of the cube as the technician sees it from the front: the front face's
    letter in the middle, the up face above it, the down face under the table line (the wedge
    drawn when used)."""
    up_face = _face_along(pose, 2)
    right_face = _face_along(pose, 1)
    table = "/" * 13 if pose.wedge else "=" * 13
    slope = "   (on the wedge, slope rising away from you)" if pose.wedge else ""
    return "\n".join([
        f"      top: {up_face}",
        "     +-----+",
        f"     |  {pose.front}  |  right: {right_face}",
        "     +-----+",
        f"  {table}  down: {pose.down}{slope}",
    ])


def _face_along(pose: Pose, column: int) -> str:
    """The face whose outward normal is nearest the bench axis `column` (1: right, 2: up), or
    the two between which it points ("D/F" on the wedge)."""
    direction = pose.cube[:, column]
    dots = {face: float(np.dot(normal, direction)) for face, normal in FACES.items()}
    best = max(dots.values())
    return "/".join(face for face, dot in dots.items() if dot > best - 1e-9)
