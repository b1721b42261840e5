"""IMU calibration station: the calibration core.

Public API (README, "Python API"): `calibrate` -> `CalibrationResult`, `crlb` (Cramer-Rao bound of a in
the canonical frame), `eps` (error metric of Eq. 19), `CalibrationInputError`.
"""

from station.solve.calibrate import CalibrationResult, calibrate
from station.errors import CalibrationInputError
from station.model.frames import eps
from station.solve.uncertainty import crlb

__all__ = ["CalibrationInputError", "CalibrationResult", "calibrate", "crlb", "eps"]
