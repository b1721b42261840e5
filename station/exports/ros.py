"""ROS sensor_msgs/Imu covariances as a ROS 2 parameters file (YAML) a launch file can load.

sensor_msgs/msg/Imu (common_interfaces, Imu.msg) carries three covariance arrays, float64[9],
row-major about the x, y, z axes of the message's frame, in the message's units squared:
`orientation_covariance` (rad^2), `angular_velocity_covariance` ((rad/s)^2) and
`linear_acceleration_covariance` ((m/s^2)^2); "if you have no estimate for one of the data
elements ... set element 0 of the associated covariance matrix to -1". The file is a ROS 2
parameters file (the `/**` wildcard node name, then `ros__parameters`), loaded with
`Node(..., parameters=["imu_covariance.yaml"])`; the three names are the message fields, for the
driver node to copy into each message. YAML written in flow style with floats that carry a '.'
(YAML 1.1 readers take `1e-05` for a string).

Each covariance is that of one calibrated sample v = F (z - b): the sensors' white noise is
independent, with per-sample variance N_i^2 f (N the white-noise density in u sqrt(s), f the
sample rate: the band 0 to f/2), so cov(v) = F diag(N^2 f) F^T, the full 3 x 3 matrix. Not
included: the bias instability and random walk (slow drifts, not sample noise: a filter models
them as states) and the calibration's own uncertainty (Calibration.vector_covariance, it depends
on the reading). The orientation has no estimate (-1). A sensor type not given also gets -1.
"""

import numpy as np

from station.errors import InputError
from station.exports.imu import (
    Imu,
    Written,
    axis_noise,
    kind_of,
    noise_covariance,
    number,
    safe_comment,
    triad,
)

NO_ESTIMATE = np.array([-1.0] + [0.0] * 8)


def ros(imu: Imu, rate_hz: float | None = None) -> Written:
    """The parameters file; `rate_hz` (the rate the driver publishes) defaults to the noise
    figures' sample rate."""
    fields = {"orientation_covariance": NO_ESTIMATE}
    notes = []
    for key, cal in (("angular_velocity_covariance", imu.gyro),
                     ("linear_acceleration_covariance", imu.acc)):
        if cal is None:
            fields[key] = NO_ESTIMATE
            notes.append(f"ROS: no {key.split('_cov')[0].replace('_', ' ')} calibration given: "
                         f"{key}[0] = -1")
            continue
        triad(cal, "sensor_msgs/Imu")
        axis_noise(cal, "white", "sensor_msgs/Imu")  # refuses missing figures
        rate = float(rate_hz if rate_hz is not None else cal.noise.rate_hz)
        if not (np.isfinite(rate) and rate > 0):
            raise InputError(f"sample rate {rate!r} Hz must be a positive number; give --rate")
        cov = noise_covariance(cal, np.square(cal.noise.white) * rate)
        fields[key] = cov.ravel()
        notes.append(f"ROS: {kind_of(cal, 'calibration')} sample sigma per axis "
                     f"{', '.join(f'{x:.3g}' for x in np.sqrt(np.diag(cov)))} {cal.units[0]} "
                     f"at {rate:g} Hz")
    serials = sorted({cal.unit_serial for cal in (imu.acc, imu.gyro) if cal is not None})
    lines = ["# sensor_msgs/Imu covariances (row-major x, y, z; SI units squared) of unit "
             f"{safe_comment(serials[0])}, written by imu-station",
             "/**:", "  ros__parameters:"]
    lines += [f"    {key}: [{', '.join(number(x) for x in values)}]"
              for key, values in fields.items()]
    return Written("\n".join(lines) + "\n", tuple(notes))
