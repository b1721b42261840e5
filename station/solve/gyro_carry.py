"""Gyro calibration from free hand turns between still poses: the calibrated rate must carry gravity
from one pose to the next (Tedaldi, Pretto & Menegatti, ICRA 2014, the method of imu_tk).

Between two still poses the unit is turned by hand. Gravity measured by the (already calibrated)
accelerometer at the end of the first pose, carried through the turn by the calibrated gyro
(`station.solve.gyro_turns.carry_gravity`: C_{k+1} = C_k exp([omega_k / fs]_x), seen as C^T f),
must land on the gravity measured at the start of the next. The gyro's sensitivity `a` (3 x 3,
column i = gyro i's axis times its scale factor, in the accelerometer's frame; model z = a^T omega
+ b, docs/conventions.md) is the least-squares solution of those landings; the bias b is the mean
gyro reading over the still poses (the Earth's rate, 7e-5 rad/s, stays in it). Each turn gives
two independent equations (directions), so nine unknowns need at least five turns about axes
that span space; more turns average the accelerometer noise down.
"""

from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from station.errors import CalibrationInputError
from station.model import measurement
from station.solve import uncertainty
from station.solve.gyro_turns import angle_deg

MIN_TURN_DEG = 30.0
"""A motion between two poses counts as a turn when gravity moved by more than this."""
MAX_LANDING_DEG = 10.0
"""A calibration whose carried gravity misses by more than this (RMS over the turns) is refused:
the least squares stopped in a local minimum (a wrong start, axes not nominally the
accelerometer's, a gyro saturated by fast turns)."""


@dataclass(frozen=True)
class CarryCalibration:
    """A gyro triad calibrated by carrying gravity through the turns between still poses.

    a, a_sigma      : (3, 3) sensitivity (input units per rad/s) in the accelerometer's frame
    bias, bias_sigma : (3,) gyro bias (input units), the mean over the still poses, and its
                      standard error (0 when the bias was given)
    covariance      : (12, 12) joint covariance of (a row-major, then bias): the carry's
                      s^2 (J^T J)^-1, the bias's error propagated into a, and their correlation
    scale_factors, scale_factors_sigma : (3,) column norms of a and their 1-sigma
    axis_angles, axis_angles_sigma : (3, 3) angles between the gyro axes (rad) and their 1-sigma
    turns           : indices of the first pose of each turn used
    residual_sigma, dof : s, the scatter of a landing (unit gravity direction, per component)
                      estimated from the residuals, and its degrees of freedom (2 per turn - 9)
    errors_before_deg, errors_after_deg : (turns,) angle between carried and measured gravity
                      with the start `a0` and with the calibration
    """

    a: np.ndarray
    a_sigma: np.ndarray
    bias: np.ndarray
    bias_sigma: np.ndarray
    covariance: np.ndarray
    scale_factors: np.ndarray
    scale_factors_sigma: np.ndarray
    axis_angles: np.ndarray
    axis_angles_sigma: np.ndarray
    turns: np.ndarray
    residual_sigma: float
    dof: int
    errors_before_deg: np.ndarray
    errors_after_deg: np.ndarray

    def apply(self, z) -> np.ndarray:
        """Angular rates (3,) or (3, k), rad/s, accelerometer frame (measurement.fuse)."""
        return measurement.fuse(self.a, z, self.bias)


def calibrate_carry(gyro, fs: float, acc, intervals, *, a0=None, bias=None,
                    min_turn_deg: float = MIN_TURN_DEG) -> CarryCalibration:
    """Calibrate a gyro triad from a continuous hand recording.

    gyro      : (K, 3) gyro readings (e.g. rad/s by the nominal scale, or counts)
    fs        : sample rate, Hz
    acc       : (K, 3) calibrated specific force, the frame the result is given in
    intervals : (P, 2) still intervals [start, stop) in samples, in time order
    a0        : nominal sensitivity, the start (default: the common scale k I, the gyro axes
                nominally along the accelerometer's, that carries gravity best, `_start`; so
                readings in raw counts need no nominal scale)
    bias      : gyro bias (default the mean over the still intervals)
    """
    gyro, acc = (np.asarray(x, float) for x in (gyro, acc))
    intervals = np.asarray(intervals, int).reshape(-1, 2)
    if gyro.shape != acc.shape or gyro.ndim != 2 or gyro.shape[1] != 3:
        raise CalibrationInputError(f"gyro {gyro.shape} and accelerometer {acc.shape} samples "
                                    "differ.", "Give (samples, 3) arrays of one recording.")
    b = _still_mean(gyro, intervals) if bias is None else np.asarray(bias, float)
    turns = _turns(acc, intervals, min_turn_deg)
    if len(turns) < 5:
        raise CalibrationInputError(
            f"only {len(turns)} turns of more than {min_turn_deg:g} deg between still poses; "
            "the gyro's nine unknowns need at least five.",
            "Record more poses, turning the unit by hand between them.")
    motions = [(gyro[stop:start] - b, _direction(acc, first, stop), _direction(acc, start, last))
               for first, stop, start, last in turns[:, 1:]]
    a0 = _start(motions, fs) if a0 is None else np.asarray(a0, float)
    fit = least_squares(lambda p: _residuals(p.reshape(3, 3), motions, fs), a0.ravel(),
                        x_scale="jac")
    a = fit.x.reshape(3, 3)
    _check_landed(_errors(a, motions, fs))
    dof = max(2 * len(turns) - 9, 1)
    cov = _covariance(fit.jac, fit.fun, dof)
    sigma_b = _still_sigma(gyro, intervals) if bias is None else np.zeros(3)
    joint = _with_bias(cov, _bias_gain(a, motions, fs, fit.jac), sigma_b)
    scale_sigma, angles, angles_sigma = _invariants(a, joint[:9, :9])
    return CarryCalibration(
        a, np.sqrt(np.diag(joint)[:9]).reshape(3, 3), b, sigma_b, joint,
        np.linalg.norm(a, axis=0), scale_sigma, angles, angles_sigma, turns[:, 0],
        float(np.sqrt(fit.fun @ fit.fun / dof)), dof, _errors(a0, motions, fs),
        _errors(a, motions, fs))


def _start(motions, fs: float, octaves: float = 3.0, steps: int = 61) -> np.ndarray:
    """k I, the common scale that carries gravity best over a grid of 2^+-octaves (steps of 7 %)
    about k0 = the median ratio of a turn's integrated reading |sum (z - b)| / fs to the angle
    gravity turned by (equal for a turn about one axis perpendicular to gravity)."""
    ratios = [np.linalg.norm(rates.sum(axis=0)) / fs / np.radians(angle_deg(before, after))
              for rates, before, after in motions]
    grid = np.median(ratios) * 2.0 ** np.linspace(-octaves, octaves, steps)
    cost = [np.sum(_residuals(k * np.eye(3), motions, fs) ** 2) for k in grid]
    return grid[int(np.argmin(cost))] * np.eye(3)


def _check_landed(errors_deg) -> None:
    """Refuse a fit whose carried gravity still misses by more than MAX_LANDING_DEG RMS: a local
    minimum, far from the gyro's sensitivity."""
    rms = float(np.sqrt(np.mean(np.square(errors_deg))))
    if rms > MAX_LANDING_DEG:
        raise CalibrationInputError(
            f"the calibrated gyro carries gravity through the turns to {rms:.3g} deg RMS from "
            "where the accelerometer measures it (a hand turn carries it to within a degree): "
            "the fit found no sensitivity that explains the turns.",
            "Check that the gyro's axes are nominally along the accelerometer's, that the gyro "
            "is in rad/s (or raw counts) and on the accelerometer's samples, and that the turns "
            "stay within the gyro's range.")


def _still_mean(gyro, intervals) -> np.ndarray:
    """Mean reading over every still sample (the bias, Earth's rate included)."""
    rows = np.concatenate([np.arange(a, z) for a, z in intervals]) if len(intervals) else []
    if len(rows) == 0:
        raise CalibrationInputError("no still interval to take the gyro bias from.",
                                    "Give the still poses found in the recording.")
    return gyro[rows].mean(axis=0)


def _still_sigma(gyro, intervals) -> np.ndarray:
    """(3,) standard error of the still mean, from the scatter of every still interval about its
    own mean."""
    parts = [gyro[a:z] - gyro[a:z].mean(0) for a, z in intervals if z - a > 1]
    scatter = np.concatenate(parts)
    return scatter.std(axis=0) / np.sqrt(len(scatter))


def _bias_gain(a, motions, fs: float, jac) -> np.ndarray:
    """(9, 3) G = d a / d b = -(J^T J)^-1 J^T J_b, J_b the residuals' derivative in the bias
    (central differences): how an error of the bias moves the estimate of a (every turn alike)."""
    step = 1e-6
    cols = []
    for i in range(3):
        e = np.zeros(3)
        e[i] = step
        up = [(r - e, before, after) for r, before, after in motions]
        down = [(r + e, before, after) for r, before, after in motions]
        cols.append((_residuals(a, up, fs) - _residuals(a, down, fs)) / (2 * step))
    return -np.linalg.solve(jac.T @ jac, jac.T @ np.column_stack(cols))


def _with_bias(cov, gain, sigma_b) -> np.ndarray:
    """Joint covariance of (a row-major, b) for an estimated bias b of covariance S =
    diag(sigma_b^2), independent of the landings' noise: [[C + G S G^T, G S], [S G^T, S]]."""
    s = np.diag(np.asarray(sigma_b, float) ** 2)
    joint = np.block([[cov + gain @ s @ gain.T, gain @ s], [s @ gain.T, s]])
    return (joint + joint.T) / 2  # symmetric to rounding: inv(J^T J) is not exactly


def _invariants(a, cov) -> tuple:
    """(1-sigma of the scale factors, axis angles, their 1-sigma) of a from the covariance of a
    row-major, through the solver's blocks (`station.solve.uncertainty`, parameters
    theta = (a_1, a_2, a_3) sensor by sensor: a column-major)."""
    order = np.arange(9).reshape(3, 3).T.ravel()
    theta = cov[np.ix_(order, order)]
    scale_sigma, angle_sigma = uncertainty.axis_sigmas(theta, a)
    return scale_sigma, uncertainty.axis_angles(a), angle_sigma


def _turns(acc, intervals, min_turn_deg: float) -> np.ndarray:
    """(Q, 5) rows (index, first, stop, start, last) of consecutive still intervals between which
    gravity turned by more than min_turn_deg."""
    rows = []
    for i, ((first, stop), (start, last)) in enumerate(pairwise(intervals)):
        if angle_deg(acc[first:stop].mean(0), acc[start:last].mean(0)) > min_turn_deg:
            rows.append((i, first, stop, start, last))
    return np.array(rows, int).reshape(-1, 5)


def _direction(acc, a: int, z: int) -> np.ndarray:
    """Unit gravity direction of a still interval (its mean: the noise averages down)."""
    f = acc[a:z].mean(axis=0)
    return f / np.linalg.norm(f)


def _carried(a, rates_raw, fs: float, before) -> np.ndarray:
    """`before` carried through the turn by the rates fused with `a` (rows: (z - b) a^-1, Eq. 7
    for a square a)."""
    steps = Rotation.from_rotvec(rates_raw @ np.linalg.inv(a) / fs).as_matrix()
    return _chain(steps).T @ before


def _chain(steps: np.ndarray) -> np.ndarray:
    """The ordered product steps[0] @ steps[1] @ ... in log2(k) batched matrix products."""
    while len(steps) > 1:
        if len(steps) % 2:
            steps = np.concatenate([steps, np.eye(3)[None]])
        steps = steps[0::2] @ steps[1::2]
    return steps[0] if len(steps) else np.eye(3)


def _residuals(a, motions, fs: float) -> np.ndarray:
    return np.concatenate([_carried(a, rates, fs, before) - after
                           for rates, before, after in motions])


def _errors(a, motions, fs: float) -> np.ndarray:
    return np.array([angle_deg(_carried(a, rates, fs, before), after)
                     for rates, before, after in motions])


def _covariance(jac, residuals, dof: int) -> np.ndarray:
    """s^2 (J^T J)^-1, s^2 from the residuals with `dof` degrees of freedom (2 equations per turn:
    unit vectors)."""
    info = jac.T @ jac
    singular = np.linalg.svd(info, compute_uv=False)
    if singular[-1] <= singular[0] * 1e-12:
        raise CalibrationInputError(
            "the turns do not determine the gyro's sensitivity (they all turn about one axis).",
            "Turn the unit about at least two different axes between the poses.")
    return float(residuals @ residuals) / dof * np.linalg.inv(info)
