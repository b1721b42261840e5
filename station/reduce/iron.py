"""A recorded right-angle-iron session (`station.protocols.iron`) -> its still poses and faces.

`recognise_faces` labels each pose's up direction with a face of the iron, relative to the first
pose of its mounting (the live protocol uses it too); the labels give the inner-product
constraints of Eq. (15) (`station.solve.constraints.from_faces`).
"""

import dataclasses
from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError
from station.reduce.still import StillReadings, still_readings, up_direction
from station.solve.constraints import from_faces

STAND_ON_A_FACE = "Stand the iron squarely on one of its faces and record that pose again."


def recognise_faces(directions, mountings, tolerance_deg: float = 20.0,
                    advice: str = STAND_ON_A_FACE) -> list:
    """Face labels of poses with up `directions` (P, 3), relative to the first pose of each
    mounting.

    Raises CalibrationInputError for a pose that is neither along nor perpendicular to the faces
    seen before in its mounting (the iron was not standing on a face), with `advice`.
    """
    directions = np.asarray(directions, float)
    mountings = list(mountings)
    near, perp = np.cos(np.radians(tolerance_deg)), np.sin(np.radians(tolerance_deg))
    axes: dict = {}
    labels = []
    for j, (u, k) in enumerate(zip(directions, mountings, strict=False)):
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
                "deg).", advice)
    return labels


@dataclass(frozen=True)
class IronReadings(StillReadings):
    """`StillReadings` of an iron session and the faces recognised from the data (P labels)."""

    faces: list = dataclasses.field(default_factory=list)

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
    """The still poses of an iron session (`station.session.Session`, `still_readings`) and
    their faces. `a_nominal` defaults to the metadata's (or the identity for a triad); `detector`
    (the stillness detector's options and `trim`) goes to `still_readings`."""
    still = still_readings(session, stream, **detector)
    if a_nominal is None:
        a_nominal = session.metadata.get("a_nominal", np.eye(3)[:, : still.M.shape[0]].tolist())
    return on_faces(still, a_nominal, bias_guess, tolerance_deg)


def on_faces(still: StillReadings, a_nominal, bias_guess=None, tolerance_deg: float = 20.0,
             advice: str = STAND_ON_A_FACE) -> IronReadings:
    """`still` with the face of each pose (`recognise_faces` of its up direction through
    `a_nominal`), so that the solver takes the right-angle constraints of Eq. (15); `advice` for
    a pose on no face."""
    faces = recognise_faces(up_direction(still.M, a_nominal, bias_guess), still.mountings,
                            tolerance_deg, advice)
    return IronReadings(**{f.name: getattr(still, f.name) for f in dataclasses.fields(still)},
                        faces=faces)
