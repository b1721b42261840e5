"""Comparison of calibration results for the tests."""

import dataclasses

import numpy as np

from station.solve.calibrate import CalibrationResult


def assert_same(result, calibration, rtol: float = 0.0):
    """Every field of two CalibrationResults equal: bit-identical by default, or within `rtol` of
    each field's largest entry (results stored by another numpy/LAPACK build differ in the last
    bits of the solver's floating-point sums, never more; the ML's iteration count may then
    differ, its stopping test on a converged fit being decided at that level)."""
    for field in dataclasses.fields(CalibrationResult):
        a, b = getattr(result, field.name), getattr(calibration, field.name)
        if rtol and field.name == "iterations":
            continue
        if isinstance(a, np.ndarray):
            if rtol:
                scale = np.max(np.abs(b)) if b.size else 0.0
                np.testing.assert_allclose(a, b, rtol=rtol, atol=rtol * scale, err_msg=field.name)
            else:
                assert np.array_equal(a, b), field.name
        elif rtol and isinstance(a, float):
            assert a == b or abs(a - b) <= rtol * abs(b), field.name
        else:
            assert a == b, field.name
