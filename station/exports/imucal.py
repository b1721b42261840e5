"""imucal's calibration JSON (mad-lab-fau/imucal, `FerrarisCalibrationInfo`, format version 2.0)
from an accelerometer and a gyro calibration in one frame.

imucal (imucal/ferraris_calibration_info.py, `calibrate`) corrects raw readings, one row per
sample, as

    acc = R_a^-1 K_a^-1 (raw_acc - b_a)
    gyr = R_g^-1 K_g^-1 (raw_gyr - K_ga acc - b_g)

K diagonal (scale), R with unit rows (the axes, not orthogonal), K_ga the gyro's acceleration
sensitivity. The file (imucal/calibration_info.py, `to_json_file`) is a JSON object with the
fields acc_unit, gyr_unit, from_acc_unit, from_gyr_unit, comment, K_a, R_a, b_a, K_g, R_g, K_ga,
b_g (matrices as nested lists), `cal_type` "Ferraris" and `_format_version` "2.0.0";
`imucal.management.load_calibration_info` reads it.

Conversion: for a triad F = (a a^T)^-1 a = a^-T, so imucal's R^-1 K^-1 = a^-T, i.e. K R = a^T:
K = diag(|a_i|) (scale factors), row i of R = a_i / |a_i| (sensor i's unit axis), b = our b,
K_ga = 0 (the calibration file has no g-sensitivity). Exact: imucal's calibrated vectors are
`Calibration.apply`'s, within float rounding. Units: readings and output in SI (from_acc_unit
"m/s^2", from_gyr_unit "rad/s", acc_unit "m/s^2", gyr_unit "rad/s"); imucal only compares
these labels with the ones its caller passes. Both triads must be in one frame
(`Imu.common_frame`).
"""

import json

import numpy as np

from station.exports.imu import Imu, Written, triad

FORMAT_VERSION = "2.0.0"
CAL_TYPE = "Ferraris"


def imucal(imu: Imu) -> Written:
    """The JSON text of a FerrarisCalibrationInfo."""
    imu.need("imucal", "accelerometer", "gyroscope")
    imu.common_frame("imucal")
    k_a, r_a = _scale_and_axes(triad(imu.acc, "imucal"))
    k_g, r_g = _scale_and_axes(triad(imu.gyro, "imucal"))
    doc = {
        "acc_unit": "m/s^2", "gyr_unit": "rad/s", "from_acc_unit": "m/s^2",
        "from_gyr_unit": "rad/s",
        "comment": (f"unit {imu.acc.unit_serial}: accelerometer calibrated {imu.acc.created}, "
                    f"gyro {imu.gyro.created}, frame {imu.acc.frame}; written by imu-station "
                    "(K R = a^T of z = a^T v + b, K_ga not calibrated)"),
        "K_a": k_a.tolist(), "R_a": r_a.tolist(), "b_a": np.asarray(imu.acc.bias).tolist(),
        "K_g": k_g.tolist(), "R_g": r_g.tolist(), "K_ga": np.zeros((3, 3)).tolist(),
        "b_g": np.asarray(imu.gyro.bias).tolist(),
        "cal_type": CAL_TYPE, "_format_version": FORMAT_VERSION,
    }
    return Written(json.dumps(doc, indent=4, allow_nan=False) + "\n",
                   ("imucal: K_ga (gyro g-sensitivity) written as zeros: not calibrated",))


def _scale_and_axes(cal) -> tuple:
    """(K, R) with K R = a^T: K = diag(|a_i|), row i of R = a_i / |a_i|."""
    scale = np.linalg.norm(cal.a, axis=0)
    return np.diag(scale), (cal.a / scale).T
