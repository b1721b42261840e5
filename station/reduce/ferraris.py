"""Six faces and three full turns (the Ferraris protocol of imucal) through the iron path.

A recording holds the unit still on its six faces (`x_p`: acc x measures +g, `x_a`: -g, ...) and
turning a full turn about x, y and z (`x_rot`, `y_rot`, `z_rot`, each on the face `<axis>_p`).

- `find_sections` finds the nine sections of a continuous recording: still intervals from
  `station.reduce.stillness.detect_still`, each labelled with the face its gravity points along; a
  turn is the motion between two still intervals on the same face whose integrated rate is large.
- `calibrate_ferraris`: the accelerometer from the six face means with the right-angle iron's
  constraints (`station.calibrate(M, g, bias="estimate", constraints=from_faces(...))`, Hwangbo &
  Kanade Eq. 15), the gyro from the three turns of known angle (Eq. 31, `station.solve.gyro_turns`),
  both expressed in the iron frame (face "+x" = +x), and a refusal if the two triads differ in
  handedness. Both are one rigid group of poses, whose maximum likelihood is linear: solved in
  closed form (`station.solve.iron_faces.fit_faces`: the estimates and their checks at once, the
  results with the analytic covariance when `accel` / `gyro.fit` are first read), the sections'
  sums one `np.add.reduceat` each (`section_sums`); `general=True` takes the iterative path
  instead.

See docs/realdata.md; `bench/peers.py` runs imucal on the same data.
"""

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from station.errors import CalibrationInputError
from station.limits import json_loads
from station.model import measurement
from station.reduce.stillness import StillIntervals, detect_still
from station.solve.calibrate import CalibrationResult
from station.solve.gyro_turns import (
    TurnCalibration,
    calibrate_turns,
    integrate,
    mirrored,
    turn_senses,
)
from station.solve.iron_faces import FacesFit, fit_faces

FACE_SECTIONS = {"x_p": "+x", "x_a": "-x", "y_p": "+y", "y_a": "-y", "z_p": "+z", "z_a": "-z"}
TURN_SECTIONS = {"x_rot": "x_p", "y_rot": "y_p", "z_rot": "z_p"}  # turn -> face it is done on
SECTIONS = tuple(FACE_SECTIONS) + tuple(TURN_SECTIONS)
FACES = tuple(FACE_SECTIONS.values())
TURN_FACES = [list(FACE_SECTIONS).index(face) for face in TURN_SECTIONS.values()]
"""Index among FACE_SECTIONS of the face each turn of TURN_SECTIONS is done on."""
COLUMNS = ("acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z")


@dataclass(frozen=True)
class Recording:
    """acc, gyro : (K, 3) samples; labels : (K,) section label of each sample, or None."""

    acc: np.ndarray
    gyro: np.ndarray
    labels: np.ndarray | None


@dataclass(frozen=True)
class FoundSections:
    """sections : label -> [start, stop) sample indices; still : the detected still intervals;
    faces : face label ("+x", ...) of each still interval, by its dominant accelerometer axis."""

    sections: dict
    still: StillIntervals
    faces: tuple[str, ...]


@dataclass(frozen=True)
class FerrarisCalibration:
    """Accelerometer and gyro of one IMU in the iron frame; units of the input readings.

    solved : the six face means' fit (`station.solve.iron_faces.FacesFit`).
    readings : (3, 6) face means, order x_p, x_a, y_p, y_a, z_p, z_a.
    gyro : the turn calibration (`gyro.a` in input units per rad/s, iron frame).
    """

    solved: FacesFit
    readings: np.ndarray
    gyro: TurnCalibration

    @property
    def a_acc(self) -> np.ndarray:
        """(3, 3) accelerometer sensitivity in the iron frame (input units per m/s^2)."""
        return self.solved.a

    @property
    def accel(self) -> CalibrationResult:
        """The `station.calibrate` result of the six face means (canonical frame, uncertainties),
        made when first read."""
        return self.solved.result

    def apply_acc(self, z) -> np.ndarray:
        """Specific force (3,) or (3, k), m/s^2, iron frame, from accelerometer readings z (3,)
        or (3, k) (station.model.measurement.fuse)."""
        return measurement.fuse(self.a_acc, z, self.solved.bias)


def read_recording(path) -> Recording:
    """An imucal CSV: columns acc_x..gyr_z (any order, extra columns ignored), optional `part`."""
    path = Path(path)
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    if not rows or not set(COLUMNS) <= set(rows[0]):
        raise CalibrationInputError(
            f"{path} has no header with the columns {', '.join(COLUMNS)}.",
            "Give an imucal CSV (header n_samples,gyr_x,...,acc_z or part,samples,acc_x,...).",
        )
    header = rows[0]
    body = [r for r in rows[1:] if r]
    try:
        x = np.array([[float(r[header.index(c)]) for c in COLUMNS] for r in body], dtype=float)
    except (ValueError, IndexError) as exc:
        raise CalibrationInputError(
            f"{path}: a row is not numeric ({exc}).", "Fix or drop it."
        ) from None
    if len(x) < 3 or not np.all(np.isfinite(x)):
        raise CalibrationInputError(
            f"{path} holds {len(x)} rows (finite: {bool(np.all(np.isfinite(x)))}).",
            "Give a recording of finite samples.",
        )
    labels = np.array([r[header.index("part")] for r in body]) if "part" in header else None
    return Recording(x[:, :3], x[:, 3:], labels)


def read_section_list(path) -> dict:
    """The hand-made section list of imucal's GUI: {label: {"start": i, "end": j}} as JSON."""
    path = Path(path)
    try:
        raw = json_loads(path.read_text(), str(path))
        sections = {k: (int(raw[k]["start"]), int(raw[k]["end"])) for k in SECTIONS}
    except (ValueError, KeyError, TypeError) as exc:
        raise CalibrationInputError(
            f"{path} is not a section list with {', '.join(SECTIONS)} ({exc!r}).",
            'Give JSON {"x_p": {"start": 540, "end": 1271}, ...}.',
        ) from None
    _check_sections(sections)
    return sections


def labelled_sections(labels) -> dict:
    """label -> [start, stop) of a pre-cut recording whose every row carries its section label."""
    labels = np.asarray(labels)
    sections = {}
    for name in SECTIONS:
        rows = np.flatnonzero(labels == name)
        if len(rows) == 0 or rows[-1] - rows[0] + 1 != len(rows):
            raise CalibrationInputError(
                f"section {name!r} is {'missing' if len(rows) == 0 else 'not one contiguous run'}.",
                "Label each of the nine sections as one run of rows.",
            )
        sections[name] = (int(rows[0]), int(rows[-1]) + 1)
    return sections


def _check_sections(sections: dict, k: int | None = None) -> None:
    for name, (start, stop) in sections.items():
        if not 0 <= start < stop or (k is not None and stop > k):
            raise CalibrationInputError(
                f"section {name!r} = [{start}, {stop}) is empty or outside the recording.",
                "Give start < end sample indices within the recording.",
            )


def face_of(acc_mean) -> str:
    """Face label of a still accelerometer mean: the sign and axis of its largest component."""
    axis = int(np.argmax(np.abs(acc_mean)))
    return ("+" if acc_mean[axis] > 0 else "-") + "xyz"[axis]


def find_sections(acc, gyro, fs: float, gyro_per_rad: float, angle: float = 2 * np.pi, **detector):
    """The nine Ferraris sections of a continuous recording (acc, gyro: (K, 3) each).

    gyro_per_rad  nominal gyro sensitivity (input units per rad/s, e.g. 180 / pi for deg/s): a
                  motion between two still intervals on one face is a turn when its integrated rate
                  exceeds half the turn angle.
    detector      options of `station.reduce.stillness.detect_still`.
    Faces are the longest still interval on each face before the first turn (the protocol puts
    the unit on its six faces first); `x_rot` is the turn on face +x, and so on.
    """
    acc, gyro = np.asarray(acc, float), np.asarray(gyro, float)
    still = detect_still(np.hstack([acc, gyro]), fs, **detector)
    faces = tuple(face_of(m) for m in still.mean[:, :3])
    sections = {}
    iv = still.intervals
    for i in range(len(iv) - 1):
        if faces[i] != faces[i + 1] or faces[i][0] != "+":
            continue
        bias = (
            still.mean[i, 3:] * still.lengths[i] + still.mean[i + 1, 3:] * still.lengths[i + 1]
        ) / (still.lengths[i] + still.lengths[i + 1])
        turned = np.linalg.norm(integrate(gyro[iv[i, 1] : iv[i + 1, 0]], fs, bias)) / gyro_per_rad
        name = f"{faces[i][1]}_rot"
        if turned > angle / 2 and name not in sections:
            sections[name] = (int(iv[i, 1]), int(iv[i + 1, 0]))
    first_turn = min((s for s, _ in sections.values()), default=len(acc))
    for name, face in FACE_SECTIONS.items():
        on_face = [j for j in range(len(iv)) if faces[j] == face and iv[j, 1] <= first_turn]
        if on_face:
            j = max(on_face, key=lambda j: still.lengths[j])
            sections[name] = (int(iv[j, 0]), int(iv[j, 1]))
    missing = [s for s in SECTIONS if s not in sections]
    if missing:
        raise CalibrationInputError(
            f"no section found for {', '.join(missing)} ({len(iv)} still intervals on faces "
            f"{', '.join(faces)}).",
            "Check gyro_per_rad and the protocol (six faces first, then a full turn about each "
            "axis with a rest on the face before and after it), or give the section list.",
        )
    return FoundSections({s: sections[s] for s in SECTIONS}, still, faces)


def section_overlap(found: dict, reference: dict) -> dict:
    """label -> (coverage, iou): share of the reference section inside the found one, and the
    intersection over union of the two."""
    out = {}
    for name, (r0, r1) in reference.items():
        f0, f1 = found[name]
        inter = max(0, min(f1, r1) - max(f0, r0))
        out[name] = (inter / (r1 - r0), inter / (max(f1, r1) - min(f0, r0)))
    return out


def calibrate_ferraris(acc, gyro, fs: float, sections: dict, g: float, angle: float = 2 * np.pi,
                       *, general: bool = False):
    """Accelerometer (six faces, iron constraints) and gyro (three turns, Eq. 31) calibration.

    acc, gyro  (K, 3) samples in any units (e.g. counts); sections label -> [start, stop).
    g          local gravity, m/s^2; angle  the turn angle, rad.
    general    solve both by `station.calibrate`'s iterative ML instead of the closed form of
               `station.solve.iron_faces` (the same result).
    The gyro bias is the gyro mean over the six faces; each turn's integral subtracts the mean of
    the face it is turned on (Eq. 18: rotating minus static). Raises CalibrationInputError if the
    gyro triad comes out mirrored relative to the accelerometer's.
    """
    acc, gyro = np.asarray(acc, float), np.asarray(gyro, float)
    _check_sections(sections, len(acc))
    bounds = np.array([sections[name] for name in SECTIONS])
    counts = bounds[:, 1] - bounds[:, 0]
    if counts[6:].min() < 2:
        raise CalibrationInputError(
            f"a turn section holds {counts[6:].min()} sample(s).", "Give each turn's samples.")
    acc_sums, gyro_sums, squares, shift = section_sums(bounds, acc, gyro)
    readings = (acc_sums / counts[:6, None]).T
    face_gyro = gyro_sums[:6] / counts[:6, None]
    solved = fit_faces(readings, FACES, g, bias="estimate", general=general)

    n = counts.astype(float)
    still = n[:6].sum()
    bias = gyro_sums[:6].sum(axis=0) / still
    # over each face: sum (gyro - its mean)^2 = sum (gyro - shift)^2 - n_f (mean - shift)^2
    spread = face_gyro - shift
    noise2 = (squares.sum(axis=0) - n[:6] @ (spread * spread)) / still
    w = (gyro_sums[6:] - n[6:, None] * face_gyro[TURN_FACES]).T / fs  # Eq. 18, summed
    sigma = np.sqrt(np.outer(noise2, n[6:])) / fs  # the noise times sqrt(samples) / fs
    senses = turn_senses(w, ["+x", "+y", "+z"])
    turn_cal = calibrate_turns(w, senses, angle, bias=bias, sigma=sigma, general=general)
    if mirrored(solved.a, turn_cal.a):
        raise CalibrationInputError(
            "the gyro triad comes out mirrored relative to the accelerometer triad.",
            "Check the gyro axes' signs and the turn senses.",
        )
    return FerrarisCalibration(solved, readings, turn_cal)


def section_sums(bounds: np.ndarray, acc: np.ndarray, gyro: np.ndarray):
    """(acc, gyro, squares, shift) summed over the sections (rows of bounds, the six faces
    first): acc (6, 3) over the faces, gyro (9, 3) over every section, squares (6, 3) the sum of
    (gyro - shift)^2 over the faces, shift the first face's first sample (still: the squares lose
    no digits). Each is one np.add.reduceat over the sections' boundaries (its even entries are
    the sections) on the span they need laid out as rows (`as_rows`)."""
    first, last = int(bounds[:, 0].min()), int(bounds[:, 1].max())
    faces = bounds[:6]
    start, stop = int(faces[:, 0].min()), int(faces[:, 1].max())
    rows = as_rows(gyro, first, last)
    gyro_sums = _reduce(rows, (bounds - first).ravel())
    shift = gyro[bounds[0, 0]]
    squares = rows[:, start - first: stop - first + 1]  # the faces' span and one column more
    squares -= shift[:, None]
    squares *= squares
    index = (faces - start).ravel()
    return _reduce(as_rows(acc, start, stop), index), gyro_sums, _reduce(squares, index), shift


def as_rows(x: np.ndarray, first: int, last: int) -> np.ndarray:
    """x[first:last] (K, c) laid out as rows (c, last - first + 1), contiguous, a zero column
    appended so that a section may end at `last` (np.add.reduceat takes no index past the end).
    Along a (K, c) column view reduceat is 3 x and a subtraction 20 x slower."""
    rows = np.zeros((x.shape[1], last - first + 1))
    rows[:, :-1] = x[first:last].T
    return rows


def _reduce(rows: np.ndarray, index: np.ndarray) -> np.ndarray:
    """(sections, c) sums of rows (c, k) over [index[2 j], index[2 j + 1]) for each section j."""
    return np.add.reduceat(rows, index, axis=1)[:, ::2].T
