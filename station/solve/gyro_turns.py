"""Gyro calibration from turns of a known angle (Hwangbo & Kanade Eq. 31), and its checks.

A turn of the right-angle iron about one of its faces rotates the unit by a known angle (2 pi for a
full turn). The bias-free gyro readings integrated over the turn are `w_j = a^T theta_j` (Eq. 31),
theta_j the turn's rotation vector: |theta_j| is the known angle (a magnitude constraint), and
turns about perpendicular faces are orthogonal (Eq. 15). The turns are thus "positions" of an iron
calibration whose stimulus is the rotation vector, solved as `station.calibrate` solves them with
the face constraints of `station.solve.constraints.from_faces` (in closed form: turns about the
three faces of one mounting are one rigid group, `station.solve.iron_faces`), the face label of a
turn naming the direction of its rotation vector in the iron frame ("-x": a turn about +x in the
negative sense).

Checks that the gyro frame is the accelerometer's:
- `mirrored`: the gyro triad has the opposite handedness of the accelerometer triad (a turn sense
  taken with the wrong sign for all three turns mirrors the gyro frame: det changes sign).
- `carry_gravity`: gravity measured before a face-to-face turn, carried through the turn by the
  calibrated gyro, must land on the gravity measured after it (an out-of-sample test: these motions
  are not used by the calibration).
"""

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from scipy.spatial.transform import Rotation

from station.errors import CalibrationInputError
from station.model import measurement
from station.solve.calibrate import CalibrationResult
from station.solve.constraints import FACES
from station.solve.iron_faces import FacesFit, fit_faces

AXES = "xyz"


@dataclass(frozen=True)
class TurnCalibration:
    """A gyro triad calibrated from turns; units are those of the input (e.g. counts per rad/s).

    solved : the turns' fit (`station.solve.iron_faces.FacesFit`).
    bias : (3,) gyro bias subtracted before integrating (input units).
    senses : face labels of the turns' rotation vectors, e.g. ("-x", "-y", "-z").
    integrals : (3, n) bias-free integrated readings of the turns (input units times seconds).
    """

    solved: FacesFit
    bias: np.ndarray
    senses: tuple[str, ...]
    integrals: np.ndarray

    @property
    def a(self) -> np.ndarray:
        """(3, 3) sensitivity in the iron frame (column i = gyro i's axis times its scale)."""
        return self.solved.a

    @property
    def fit(self) -> CalibrationResult:
        """The `station.calibrate` result (canonical frame, with the gauge-invariant
        uncertainties), made when first read."""
        return self.solved.result

    def apply(self, z) -> np.ndarray:
        """Angular rates (3,) or (3, k) in rad/s, iron frame, from gyro readings z (3,) or (3, k)
        (station.model.measurement.fuse)."""
        return measurement.fuse(self.a, z, self.bias)


def integrate(gyro, fs: float, bias) -> np.ndarray:
    """(3,) integral of gyro - bias over the samples gyro (k, 3), rectangle rule (sum / fs)."""
    gyro = np.asarray(gyro, float)
    if gyro.ndim != 2 or gyro.shape[1] != 3 or len(gyro) < 2:
        raise CalibrationInputError(
            f"gyro samples of a turn have shape {gyro.shape}.",
            "Give a (samples, 3) array per turn.",
        )
    return (gyro - np.asarray(bias, float)).sum(axis=0) / fs


def turn_senses(integrals, faces: Sequence[str]) -> tuple[str, ...]:
    """Face label of each turn's rotation vector, from its nominal gyro (gyro i along axis i).

    A turn on face "+x" or "-x" turns about the iron's x axis; its sense is the sign of the
    integrated reading of gyro x. This assumes the gyro triad's nominal axes are x, y, z in order;
    `carry_gravity` checks the outcome on motions the calibration did not use.
    """
    w = np.asarray(integrals, float)
    senses = []
    for j, face in enumerate(faces):
        if face not in FACES:
            raise CalibrationInputError(
                f"unknown face {face!r} of turn {j}.", f"Use one of {FACES}."
            )
        axis = AXES.index(face[1])
        senses.append(("+" if w[axis, j] > 0 else "-") + face[1])
    return tuple(senses)


def calibrate_turns(
    integrals, senses: Sequence[str], angle: float = 2 * np.pi, *, bias=None, sigma=None,
    general: bool = False,
) -> TurnCalibration:
    """Gyro calibration from turn integrals (3, n) of rotation vectors along `senses` (Eq. 31).

    angle  the known turn angle in radians (2 pi for a full turn).
    bias   the bias that was subtracted before integrating (kept with the result for `apply`).
    sigma  standard deviation of each integral (scalar, (3,) or (3, n)): with three turns there are
           as many unknowns as readings, so it cannot be estimated from the residuals; e.g. the
           gyro noise times sqrt(samples) / fs.
    general  solve by `station.calibrate`'s iterative ML instead of the closed form of
           `station.solve.iron_faces` (the same result).
    """
    w = np.asarray(integrals, float)
    if w.ndim != 2 or w.shape[0] != 3 or w.shape[1] != len(senses):
        raise CalibrationInputError(
            f"turn integrals have shape {w.shape} for {len(senses)} turn senses.",
            "Give a (3, turns) matrix and one sense (face label) per turn.",
        )
    if w.shape[1] < 3 or len({s[1] for s in senses}) < 3:
        raise CalibrationInputError(
            f"turns about axes {sorted({s[1] for s in senses})} do not span space.",
            "Turn the unit about three perpendicular faces (x, y and z).",
        )
    if sigma is None and w.shape[1] == 3:
        raise CalibrationInputError(
            "three turns leave no residual to estimate the noise from.",
            "Give sigma (gyro noise times sqrt(samples) / fs), or record more turns.",
        )
    solved = fit_faces(w, senses, angle, sigma=sigma, general=general)  # iron frame: the senses'
    b = np.zeros(3) if bias is None else np.asarray(bias, float)  # physical handedness
    return TurnCalibration(solved, b, tuple(senses), w)


def mirrored(a_acc, a_gyro) -> bool:
    """True if the gyro triad a_gyro (3, 3) has the other handedness than the accelerometer's.

    Both are sensitivity matrices (column = axis times scale) in one frame; a triad's handedness is
    the sign of its determinant. A mirrored gyro rotates everything the wrong way.
    """
    a_acc, a_gyro = (np.asarray(x, float) for x in (a_acc, a_gyro))
    if a_acc.shape != (3, 3) or a_gyro.shape != (3, 3):
        raise CalibrationInputError(
            f"triads of shape {a_acc.shape} and {a_gyro.shape}.", "Give two 3 x 3 sensitivities."
        )
    return bool(np.linalg.det(a_acc) * np.linalg.det(a_gyro) < 0)


def carry_gravity(rates, fs: float, f_start) -> np.ndarray:
    """Specific force f_start (3,), body frame, carried through the rotation of rates (k, 3) rad/s.

    Body attitude C (start <- now) follows C_{k+1} = C_k exp([omega_k / fs]_x); a vector fixed in
    the world is seen at the end as C^T f_start.
    """
    steps = Rotation.from_rotvec(np.asarray(rates, float) / fs).as_matrix()  # exp([w]_x)
    c = np.eye(3)
    for r in steps:
        c = c @ r
    return c.T @ np.asarray(f_start, float)


def gravity_carry_errors(
    acc, rates, fs: float, intervals, min_turn_deg: float = 30.0
) -> np.ndarray:
    """Out-of-sample gyro check over the face-to-face turns of a continuous recording.

    acc (K, 3) calibrated specific force and rates (K, 3) calibrated angular rate (rad/s), in one
    frame; intervals (P, 2) the still intervals [start, stop) in time order. For each pair of
    consecutive intervals whose mean gravity directions differ by more than min_turn_deg, the
    gravity of the first is carried through the motion between them (`carry_gravity`) and compared
    with the second's. Returns (Q, 3) rows (index of the first interval, turn angle measured by the
    accelerometer, error of the carried gravity), angles in degrees.
    """
    acc, rates = np.asarray(acc, float), np.asarray(rates, float)
    rows = []
    for i, ((first, stop), (start, last)) in enumerate(pairwise(np.asarray(intervals))):
        before = acc[first:stop].mean(axis=0)
        after = acc[start:last].mean(axis=0)
        turned = angle_deg(before, after)
        if turned > min_turn_deg:
            rows.append((i, turned, angle_deg(carry_gravity(rates[stop:start], fs, before), after)))
    return np.array(rows, float).reshape(-1, 3)


def angle_deg(u, v) -> float:
    """Angle between two vectors, degrees."""
    u, v = np.asarray(u, float), np.asarray(v, float)
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v)), u @ v)))
