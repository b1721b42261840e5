"""Comparison of calibration results for the tests."""

import dataclasses

import numpy as np

from station.calibrate import CalibrationResult


def assert_same(result, calibration):
    """Every field of two CalibrationResults bit-identical."""
    for field in dataclasses.fields(CalibrationResult):
        a, b = getattr(result, field.name), getattr(calibration, field.name)
        if isinstance(a, np.ndarray):
            assert np.array_equal(a, b), field.name
        else:
            assert a == b, field.name
