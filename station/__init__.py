"""IMU calibration station: the calibration core.

Public API (see README): `calibrate`, `CalibrationResult`, `crlb`, `eps`.
"""

from station.frames import eps

__all__ = ["eps"]
