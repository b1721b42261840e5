"""Inner-product constraints between positions (Hwangbo & Kanade, Eq. 15).

A constraint `(j, k, h)` states `v_j . v_k = h c^2` for the stimuli of positions j and k, c being
the known magnitude: `j == k, h = 1` is a magnitude constraint, `h = 0` two orthogonal stimuli,
`h = -1` two opposite ones (as when a right-angle iron is turned from one face to another).
"""

from collections.abc import Hashable, Sequence
from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError

FACES = ("+x", "-x", "+y", "-y", "+z", "-z")


@dataclass(frozen=True)
class Constraints:
    """Constraints `v_j . v_k = h c^2`: arrays `j`, `k` (int) and `h` (float), one entry each.

    The arrays are validated and made read-only on construction: indices are non-negative integers,
    `h` lies in [-1, 1], and a constraint of a position with itself (`j == k`) has `h > 0`.
    """

    j: np.ndarray
    k: np.ndarray
    h: np.ndarray

    def __post_init__(self):
        j, k, h = (np.atleast_1d(np.array(x)) for x in (self.j, self.k, self.h))
        if not (j.ndim == k.ndim == h.ndim == 1 and len(j) == len(k) == len(h)):
            raise CalibrationInputError(
                "Constraint arrays j, k, h must be one-dimensional and of equal length.",
                "Give one (j, k, h) entry per constraint.")
        if len(j) and not (_integral(j) and _integral(k)):
            raise CalibrationInputError("Constraint indices j, k must be integers.",
                                        "Give position indices (column numbers of the readings).")
        j, k = j.astype(np.int64), k.astype(np.int64)
        h = h.astype(float)
        if np.any(j < 0) or np.any(k < 0):
            raise CalibrationInputError("Constraint indices must be non-negative.",
                                        "Give position indices counted from 0.")
        if not np.all(np.isfinite(h)) or np.any(np.abs(h) > 1):
            raise CalibrationInputError(
                "Constraint values h must lie in [-1, 1] (v_j . v_k = h c^2 with |v| = c).",
                "Use 1 for the same direction, 0 for orthogonal, -1 for opposite stimuli.")
        if np.any(h[j == k] <= 0):
            raise CalibrationInputError(
                "A constraint of a position with itself (j == k) must have h > 0 (it is |v_j|^2).",
                "Use h = 1 for a magnitude constraint.")
        for name, value in (("j", j), ("k", k), ("h", h)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    def __len__(self) -> int:
        return len(self.h)

    def __add__(self, other: "Constraints") -> "Constraints":
        """Both lists of constraints, one after the other."""
        return Constraints(np.concatenate([self.j, other.j]), np.concatenate([self.k, other.k]),
                           np.concatenate([self.h, other.h]))

    def check_positions(self, n: int) -> None:
        """Raise CalibrationInputError unless every index refers to one of n positions."""
        if len(self) and max(self.j.max(), self.k.max()) >= n:
            bad = int(max(self.j.max(), self.k.max()))
            raise CalibrationInputError(
                f"A constraint refers to position {bad}, but the readings have only {n} positions.",
                "Build the constraints for the same positions (columns) as the readings.")

    def opposite_pairs(self) -> np.ndarray:
        """Pairs (j, k), j != k, declared opposite (h = -1), as a (pairs x 2) array (Eq. 14)."""
        mask = (self.h == -1) & (self.j != self.k)
        return np.column_stack([self.j[mask], self.k[mask]])

    def orthogonal(self) -> "Constraints":
        """Only the orthogonality constraints (h = 0), e.g. for gyros of unknown rotation rate."""
        mask = self.h == 0
        return Constraints(self.j[mask], self.k[mask], self.h[mask])


def _integral(x: np.ndarray) -> bool:
    """True if every entry of x is an integer value (of integer or float dtype)."""
    if np.issubdtype(x.dtype, np.integer):
        return True
    return np.issubdtype(x.dtype, np.floating) and bool(np.all(np.isfinite(x) & (x == np.round(x))))


def magnitude_constraints(n: int) -> Constraints:
    """Magnitude constraints |v_j| = c for each of n positions (j = k, h = 1)."""
    if n < 1:
        raise CalibrationInputError(f"Need at least one position, got n = {n}.",
                                    "Record the unit in several positions.")
    idx = np.arange(n)
    return Constraints(idx, idx, np.ones(n))


def face_directions(face_labels: Sequence[str]) -> np.ndarray:
    """(3, n) unit vectors of face labels in the iron's frame ("+x" -> e_x, "-z" -> -e_z)."""
    unknown = sorted({str(f) for f in face_labels if f not in FACES})
    if unknown:
        raise CalibrationInputError(f"Unknown face labels {unknown}.",
                                    f"Use one of {', '.join(FACES)} for each position.")
    index = [FACES.index(f) for f in face_labels]
    return _FACE_VECTORS[:, index]


_FACE_VECTORS = np.zeros((3, 6))
_FACE_VECTORS[[0, 0, 1, 1, 2, 2], range(6)] = [1.0, -1.0, 1.0, -1.0, 1.0, -1.0]
"""Columns: the unit vectors of FACES, in order."""


def from_faces(face_labels: Sequence[str],
               mounting_labels: Sequence[Hashable] | None = None) -> Constraints:
    """Constraints of a right-angle iron: one per pair of positions of the same mounting (Eq. 15).

    `face_labels[j]` is the face ("+x", "-x", "+y", "-y", "+z", "-z") the stimulus of position j
    points along, in the iron's frame; `mounting_labels[j]` names how the unit sat in the iron at
    position j (None: one mounting for all). Same face gives h = 1 (including j == k, the
    magnitude), perpendicular faces 0, opposite faces -1. Positions of different mountings are not
    related.
    """
    faces = list(face_labels)
    mountings = [0] * len(faces) if mounting_labels is None else list(mounting_labels)
    if len(mountings) != len(faces):
        raise CalibrationInputError(
            f"Got {len(faces)} face labels but {len(mountings)} mounting labels.",
            "Give one face label and one mounting label per position.")
    unknown = sorted({str(f) for f in faces if f not in FACES})
    if unknown:
        raise CalibrationInputError(f"Unknown face labels {unknown}.",
                                    f"Use one of {', '.join(FACES)} for each position.")
    if not faces:
        raise CalibrationInputError("No positions given.", "Record the unit on several faces.")
    axis = np.array([FACES.index(f) // 2 for f in faces])
    sign = np.array([1.0 if f[0] == "+" else -1.0 for f in faces])
    numbering: dict = {}
    mount = np.array([numbering.setdefault(label, len(numbering)) for label in mountings])
    j, k = np.triu_indices(len(faces))
    keep = mount[j] == mount[k]
    j, k = j[keep], k[keep]
    h = np.where(axis[j] == axis[k], sign[j] * sign[k], 0.0)
    return Constraints(j, k, h)
