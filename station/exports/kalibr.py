"""A Kalibr IMU configuration (imu.yaml) with its scale-misalignment intrinsics.

Kalibr (ethz-asl/kalibr; wiki "YAML formats", IMU configuration; read by
kalibr_common/ConfigReader.py `ImuParameters` with PyYAML) takes, in SI units:

    accelerometer_noise_density  m/s^2/sqrt(Hz)   white noise density (continuous time)
    accelerometer_random_walk    m/s^3/sqrt(Hz)   bias random walk
    gyroscope_noise_density      rad/s/sqrt(Hz)
    gyroscope_random_walk        rad/s^2/sqrt(Hz)
    update_rate                  Hz (Kalibr discretises: sigma = density * sqrt(update_rate))
    rostopic                     the IMU topic

each one number (> 0) for all three axes. Ours are per sensor (`NoiseFigures`: white N and random
walk K, in the same units); carried through the fusion to the axes (station.exports.imu.axis_noise:
sqrt(diag(F diag(N^2) F^T))) they differ per axis, and the file takes the largest axis (the
conservative choice: Kalibr's estimator then trusts no axis more than it should).

Intrinsics, the model `scale-misalignment` (kalibr_imu_camera_calibration/IccSensors.py,
`IccScaledMisalignedImu`): in the IMU frame i,

    raw_acc  = M_accel a_i + b_a                  (M_accel lower triangular)
    raw_gyro = M_gyro C_gyro_i w_i + A a_i + b_g  (M_gyro lower triangular, C_gyro_i a rotation)

written as Kalibr writes its results: `model`, `accelerometers: {M}`, `gyroscopes: {M, A,
C_gyro_i}`. Conversion from z = a^T v + b in our frame (both triads in one frame, Imu.common_frame):
QR of the accelerometer's a = Q U (U upper triangular, positive diagonal): frame i is our frame
turned by Q^T (a_i = Q^T v), M_accel = U^T. For the gyro, Q^T a_g = Q_g U_g: M_gyro = U_g^T,
C_gyro_i = Q_g^T. A = 0 (the calibration file has no g-sensitivity). The rotation from our frame
(the body b) to frame i goes in T_i_b (4 x 4, Kalibr's name for it); it is the identity in the
canonical frame of Eq. (19), which is Kalibr's accelerometer frame. Q or Q_g with determinant
-1 (a triad mirrored relative to the frame) has no rotation: refused. Kalibr estimates the biases
itself (random walks); ours at calibration time are in a comment.
"""

import re

import numpy as np

from station.errors import InputError
from station.exports.imu import Imu, Written, axis_noise, number, safe_comment, triad

MODEL = "scale-misalignment"
_TOPIC = re.compile(r"/?[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*\Z")


def kalibr(imu: Imu, rostopic: str = "/imu0", update_rate: float | None = None) -> Written:
    """The imu.yaml text; `update_rate` defaults to the noise figures' sample rate."""
    imu.need("Kalibr's imu.yaml", "accelerometer", "gyroscope")
    imu.common_frame("Kalibr's scale-misalignment model")
    acc, gyro = triad(imu.acc, "Kalibr"), triad(imu.gyro, "Kalibr")
    if not _TOPIC.match(rostopic):
        raise InputError(f"rostopic {rostopic!r} is not a ROS topic name (letters, digits, '_' "
                         "and '/' separators, e.g. /imu0)")
    noise = {f"{name}_{figure}": float(np.max(axis_noise(cal, field, "Kalibr")))
             for name, cal in (("accelerometer", acc), ("gyroscope", gyro))
             for figure, field in (("noise_density", "white"), ("random_walk", "random_walk"))}
    for key, value in noise.items():
        if not value > 0:
            raise InputError(f"Kalibr needs {key} > 0 but the noise figures give {value:g}; "
                             "measure the noise again on a longer static recording")
    rate = float(update_rate if update_rate is not None else acc.noise.rate_hz)
    if not (np.isfinite(rate) and rate > 0):
        raise InputError(f"update rate {rate!r} Hz must be a positive number; give --rate")
    q, m_accel = _lower(acc.a, "accelerometer")
    q_g, m_gyro = _lower(q.T @ gyro.a, "gyro (in the accelerometer's frame)")
    t_i_b = np.eye(4)
    t_i_b[:3, :3] = q.T
    lines = [
        "# Kalibr IMU configuration written by imu-station",
        f"# unit {safe_comment(acc.unit_serial)}: accelerometer calibrated "
        f"{safe_comment(acc.created)}, gyro {safe_comment(gyro.created)}, frame {acc.frame}",
        "# noise: the largest axis of each figure carried through the fusion (station noise)",
        f"# biases at calibration (Kalibr estimates them online): accelerometer "
        f"[{', '.join(number(x) for x in acc.bias)}] m/s^2, gyro "
        f"[{', '.join(number(x) for x in gyro.bias)}] rad/s",
        *(f"{key}: {number(value)}" for key, value in noise.items()),
        f"rostopic: {rostopic}",
        f"update_rate: {number(float(f'{rate:.9g}'))}",  # 100, not 100.00000000009095
        f"model: {MODEL}",
        f"T_i_b: {_matrix(t_i_b)}",
        "accelerometers:",
        f"  M: {_matrix(m_accel)}",
        "gyroscopes:",
        f"  M: {_matrix(m_gyro)}",
        f"  A: {_matrix(np.zeros((3, 3)))}",
        f"  C_gyro_i: {_matrix(q_g.T)}",
    ]
    axes = {name: axis_noise(cal, "white", "Kalibr") for name, cal in (("accelerometer", acc),
                                                                      ("gyroscope", gyro))}
    notes = tuple(f"Kalibr: {name} noise density per axis {', '.join(f'{x:.3g}' for x in v)}; "
                  f"the largest written" for name, v in axes.items())
    return Written("\n".join(lines) + "\n", notes + ("Kalibr: gyro g-sensitivity A written "
                                                     "as zeros: not calibrated",))


def _lower(a: np.ndarray, what: str) -> tuple:
    """(Q, L): a = Q L^T with Q a rotation and L lower triangular with a positive diagonal."""
    q, r = np.linalg.qr(a)
    signs = np.sign(np.diag(r))
    q, r = q * signs, signs[:, None] * r
    if np.linalg.det(q) < 0:
        raise InputError(f"the {what} triad is mirrored relative to the frame (its axes are "
                         "left-handed), which Kalibr's rotation cannot represent; check the "
                         "sensors' signs and order in the nominal layout")
    return q, r.T


def _matrix(x: np.ndarray) -> str:
    """A matrix as a YAML flow sequence of rows."""
    return "[" + ", ".join("[" + ", ".join(number(v) for v in row) + "]" for row in x) + "]"
