"""IMU calibration station: the calibration core.

Public API (README, "Python API"): `calibrate` -> `CalibrationResult`, `crlb` (Cramer-Rao bound of a
in the canonical frame), `eps` (error metric of Eq. 19), `CalibrationInputError`, `StationError`.
The names are imported on first use (PEP 562), so `import station` (and `station --help`) loads no
numpy.
"""

import importlib

_PUBLIC = {
    "calibrate": "station.solve.calibrate",
    "CalibrationResult": "station.solve.calibrate",
    "crlb": "station.solve.uncertainty",
    "eps": "station.model.frames",
    "CalibrationInputError": "station.errors",
    "StationError": "station.errors",
}

__all__ = sorted(_PUBLIC)


def __getattr__(name):
    """The public name `name`, imported from its module on first use."""
    if name not in _PUBLIC:
        raise AttributeError(f"module 'station' has no attribute {name!r}")
    value = getattr(importlib.import_module(_PUBLIC[name]), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted({*globals(), *_PUBLIC})
