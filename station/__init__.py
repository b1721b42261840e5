"""IMU calibration station: the calibration core.

Public API (README, "Python API"): `calibrate` -> `CalibrationResult`, `crlb` (Cramer-Rao bound of a in
the canonical frame), `eps` (error metric of Eq. 19), `CalibrationInputError`.
"""

from station.calibrate import CalibrationResult, calibrate
from station.errors import CalibrationInputError
from station.frames import eps
from station.uncertainty import crlb

__all__ = ["CalibrationInputError", "CalibrationResult", "calibrate", "crlb", "eps"]
