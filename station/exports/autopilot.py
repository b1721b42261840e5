"""ArduPilot and PX4 parameter files from an IMU's calibration (accelerometer and/or gyro).

Both autopilots correct each axis on its own, in the sensor's frame, before the board rotation:

- ArduPilot (libraries/AP_InertialSensor, AP_InertialSensor_Backend::_rotate_and_correct_accel
  and _gyro; the parameter documentation of INS_ACCOFFS_*, INS_ACCSCAL_* (range 0.8 to 1.2),
  INS_GYROFFS_*, units m/s^2 and rad/s):
      accel_k = (raw_k - INS_ACCOFFS_k) * INS_ACCSCAL_k,   gyro_k = raw_k - INS_GYROFFS_k
  instance 1 is INS_ACCOFFS_X, INS_ACCSCAL_X, INS_GYROFFS_X, ...; 2 and 3 are INS_ACC2OFFS_X,
  INS_ACC2SCAL_X, INS_GYR2OFFS_X, ... The file is
  the Mission Planner / MAVProxy parameter file: one `NAME,VALUE` per line, `#` comments
  (pymavlink's `mavparm.MAVParmDict.load`, which MAVProxy's `param load` uses, reads it).
- PX4 (src/lib/sensor_calibration/Accelerometer.hpp and Gyroscope.hpp `Correct`; parameters
  CAL_ACCn_XOFF / _XSCALE, CAL_GYROn_XOFF, in m/s^2 and rad/s, applied to the sensor whose
  device id is CAL_ACCn_ID / CAL_GYROn_ID):
      accel = R * ((raw - CAL_ACCn_OFF) .* CAL_ACCn_SCALE),   gyro = R * (raw - CAL_GYROn_OFF)
  The file is QGroundControl's parameter file (QGroundControl Dev Guide, "File Formats:
  Parameters"; PX4's own Tools/process_sensor_caldata.py writes the same): `#` comment lines,
  then one tab-separated row `Vehicle-Id Component-Id Name Value Type` per parameter, Type the
  MAVLink MAV_PARAM_TYPE (6 INT32, 9 REAL32); vehicle 1 (PX4's default MAV_SYS_ID), component 1
  (the autopilot).

Conversion (station/exports/imu.py `per_axis`): from z = a^T v + b, the offsets are b (in
the readings' SI units) and the accelerometer's scales 1 / a_kk; the autopilot then computes
v'_k = (z_k - b_k) / a_kk = v_k + (cross-axis terms), exact for a diagonal a. The gyro has no
scale parameter in either autopilot: its scale errors are dropped too. The worst case of the
dropped part at 1 g / 1 rad/s is stated in the summary and refused beyond 1 % unless --force.
The readings must be what the correction sees: ArduPilot rotates the chip's axes to the board's
(the driver's sensor orientation) before the offsets and scales and turns by AHRS_ORIENTATION
after them; PX4 turns by CAL_ACCn_ROT / SENS_BOARD_ROT after them. So record the unit with the
autopilot's own offsets 0, scales 1, board rotation none and temperature calibration off (or
from a sensor that reports before them), its x, y, z axes in that order, and solve it in a frame
tied to them (`nominal`, or the `canonical` frame of a triad whose first sensor is x).
Values are written as float32 (MAVLink parameters are REAL32), the shortest text that gives
back that float32.
"""

import numpy as np

from station.errors import InputError
from station.exports.imu import (
    Imu,
    Written,
    check_dropped,
    dropped_words,
    per_axis,
    safe_comment,
)

AXES = "XYZ"
ARDUPILOT_INSTANCES = (1, 2, 3)
PX4_INSTANCES = (0, 1, 2, 3)
ARDUPILOT_SCALE_RANGE = (0.8, 1.2)  # INS_ACCSCAL_* @Range
ARDUPILOT_OFFSET_MAX = 3.5  # m/s^2, INS_ACCOFFS_* @Range
MAV_PARAM_TYPE = {"int": 6, "float": 9}  # MAV_PARAM_TYPE_INT32, MAV_PARAM_TYPE_REAL32


def ardupilot(imu: Imu, instance: int = 1, force: bool = False) -> Written:
    """A Mission Planner / MAVProxy parameter file for ArduPilot's IMU `instance` (1 to 3)."""
    if instance not in ARDUPILOT_INSTANCES:
        raise InputError(f"ArduPilot instance {instance}: the INS_ parameters cover IMUs "
                         f"{ARDUPILOT_INSTANCES}; give --instance 1, 2 or 3")
    tag = "" if instance == 1 else str(instance)
    params, notes = [], []
    if imu.acc is not None:
        model = _model(imu.acc, "accelerometer", "ArduPilot", True, force, notes)
        low, high = ARDUPILOT_SCALE_RANGE
        if np.any(np.abs(model.offset) > ARDUPILOT_OFFSET_MAX) \
                or not np.all((low <= model.scale) & (model.scale <= high)):
            raise InputError(
                f"ArduPilot accepts accelerometer offsets within +-{ARDUPILOT_OFFSET_MAX} m/s^2 "
                f"and scales within {ARDUPILOT_SCALE_RANGE} (INS_ACCOFFS/INS_ACCSCAL ranges), but "
                f"these are {np.round(model.offset, 4).tolist()} and "
                f"{np.round(model.scale, 4).tolist()}; check that the readings were in m/s^2 "
                "(not g or counts) and the unit is the one on the autopilot")
        params += _axes(f"INS_ACC{tag}OFFS_{{}}", model.offset)
        params += _axes(f"INS_ACC{tag}SCAL_{{}}", model.scale)
    if imu.gyro is not None:
        model = _model(imu.gyro, "gyroscope", "ArduPilot", False, force, notes)
        gyro = "INS_GYROFFS" if instance == 1 else f"INS_GYR{tag}OFFS"  # the names differ
        params += _axes(gyro + "_{}", model.offset)
        notes.append("ArduPilot measures the gyro offsets again at every boot unless "
                     "INS_GYR_CAL is 0 (Never)")
    header = _header(imu, f"ArduPilot, IMU instance {instance}")
    lines = [f"# {line}" for line in header] + [f"{name},{_value(kind, value)}"
                                               for name, kind, value in params]
    return Written("\n".join(lines) + "\n", tuple(notes))


def px4(imu: Imu, instance: int = 0, acc_id: int | None = None, gyro_id: int | None = None,
        force: bool = False) -> Written:
    """A QGroundControl parameter file for PX4's calibration slot `instance` (0 to 3); PX4 uses
    a slot only for the sensor whose device id it names, so the ids are required."""
    if instance not in PX4_INSTANCES:
        raise InputError(f"PX4 instance {instance}: the CAL_ parameters have slots "
                         f"{PX4_INSTANCES}; give --instance 0 to 3")
    params, notes = [], []
    for cal, kind, short, device, option in ((imu.acc, "accelerometer", "ACC", acc_id,
                                              "--acc-id"),
                                             (imu.gyro, "gyroscope", "GYRO", gyro_id,
                                              "--gyro-id")):
        if cal is None:
            continue
        if device is None or not 0 < device < 2**31:
            raise InputError(
                f"PX4 applies CAL_{short}{instance}_* only to the {kind} whose device id is "
                f"CAL_{short}{instance}_ID; give it with {option} (a positive 32-bit integer: "
                f"the vehicle's CAL_{short}{instance}_ID, or `listener sensor_"
                f"{'accel' if short == 'ACC' else 'gyro'}` on its console)")
        model = _model(cal, kind, "PX4", short == "ACC", force, notes)
        prefix = f"CAL_{short}{instance}_"
        params.append((prefix + "ID", "int", device))
        params += _axes(prefix + "{}OFF", model.offset)
        if short == "ACC":
            params += _axes(prefix + "{}SCALE", model.scale)
    header = ["Onboard parameters for Vehicle 1",
              *_header(imu, f"PX4, calibration slot {instance}")]
    lines = [f"# {line}" for line in header] + ["# Vehicle-Id Component-Id Name Value Type"]
    lines += [f"1\t1\t{name}\t{_value(kind, value)}\t{MAV_PARAM_TYPE[kind]}"
              for name, kind, value in params]
    return Written("\n".join(lines) + "\n", tuple(notes))


def _model(cal, kind, format_name, with_scale, force, notes):
    """The per-axis model of one triad, checked against the limit; its note appended."""
    model = per_axis(cal, format_name, with_scale)
    check_dropped(model, kind, format_name, force)
    notes.append(dropped_words(model, kind))
    if cal.temperature is not None:  # ArduPilot's INS_TCAL / PX4's TC_* polynomials not written
        notes.append(f"{format_name}: the {kind}'s temperature model is not written (the "
                     "autopilot's own temperature calibration parameters are not exported); the "
                     f"values are those at T_REF = {cal.temperature.t_ref:.2f} K: `station "
                     "export --c-header` holds the whole model")
    return model


def _axes(pattern: str, values) -> list:
    """(name, "float", value) of the X, Y, Z parameters of `pattern` ("{}" = the axis)."""
    return [(pattern.format(k), "float", v) for k, v in zip(AXES, values, strict=True)]


def _header(imu: Imu, target: str) -> list:
    """Comment lines: what the file is for and where its numbers came from (no free text from
    the calibration files but the checked serial and dates, made safe)."""
    lines = [f"IMU calibration for {target}, written by imu-station"]
    for cal in (imu.acc, imu.gyro):
        if cal is not None:
            lines.append(f"{cal.units[0]} calibration of unit {safe_comment(cal.unit_serial)}, "
                         f"{safe_comment(cal.created)}, frame {cal.frame}")
    return lines



def _value(kind: str, value) -> str:
    """An INT32 as an integer, a REAL32 as the shortest text giving back its float32."""
    return str(int(value)) if kind == "int" else str(np.float32(value))
