"""Start values (a, v, b) for the maximum-likelihood fit, in order of preference.

An algebraic closed form is the best start, but it can fail where the likelihood has a perfectly
good maximum: the general quadric through few noisy poses is a hyperboloid, the factorization of
an array needs more poses than unknowns of its metric upgrade (Hwangbo & Kanade Eq. 29: 9 magnitude
constraints for p = 4). `station.calibrate` then tries the next start:

- "closed form"             the method's own: PCA (Rupniewski Algorithm 2), the ellipsoid, or the
                            factorization (Hwangbo & Kanade);
- "axis-aligned ellipsoid"  a triad with biases: the quadric without cross terms (no misalignment);
- "nominal layout"          a = the given nominal layout, b = the mid-range of each sensor;
- "principal axes"          a = the readings' principal directions (scaled to the stimulus), b =
                            the mid-range: crude, but it exists for any readings.

Each returns (a0 (d, m), v0 (d, n), b0 (m,) or None); a failure raises CalibrationInputError (or
numpy's LinAlgError for a singular system).
"""

import numpy as np

from station.errors import CalibrationInputError
from station.model import measurement

FALLBACKS = ("axis-aligned ellipsoid", "nominal layout", "principal axes")


def closed_form(method, readings, known_bias, estimate_bias, constraints, c, d):
    """Start values (a, v, b) from the chosen closed-form method (validated by `check_method`)."""
    if method == "pca":
        from station.solve.pca import pca_calibration

        z = readings if known_bias is None else readings - known_bias[:, None]
        a, v = pca_calibration(z, c, d)
        return a, v, None
    if method == "ellipsoid":
        from station.solve.ellipsoid import ellipsoid_calibration

        return ellipsoid_calibration(readings, c)
    from station.solve.factorization import factorize

    m = readings.shape[0]
    if estimate_bias:  # jointly (p = d + 1) when m > d, else from opposite pairs (Eq. 14)
        fact = factorize(readings, constraints, magnitude=c, d=d, estimate_bias=m > d or None)
    else:  # readings unbiased, or biases known
        given = np.zeros(m) if known_bias is None else known_bias
        fact = factorize(readings, constraints, magnitude=c, d=d, bias=given, estimate_bias=False)
    return fact.a, fact.v, fact.bias


def check_method(method, readings, estimate_bias, d) -> None:
    """Refuse a closed form that cannot apply to these inputs (an option error, not a data one)."""
    if method == "pca" and estimate_bias:
        raise CalibrationInputError(
            "the PCA closed form needs unbiased readings.",
            "Subtract the static means first (Eq. 18), "
            'or use method="ellipsoid"/"factorization".',
        )
    if method == "ellipsoid" and readings.shape[0] != d:
        raise CalibrationInputError(
            f"the ellipsoid fit is for a triad (m = d = {d}), not m = {readings.shape[0]}.",
            'Use method="factorization" for redundant sensors.',
        )


def fallback(name, readings, known_bias, estimate_bias, c, d, nominal):
    """Start values (a, v, b) of the fallback start `name` (one of FALLBACKS)."""
    m = readings.shape[0]
    if name == "axis-aligned ellipsoid":
        if not (estimate_bias and m == d):
            raise CalibrationInputError("the axis-aligned ellipsoid is for a triad with biases.",
                                        "Use another start.")
        from station.solve.ellipsoid import ellipsoid_calibration

        return ellipsoid_calibration(readings, c, axis_aligned=True)
    bias = _mid_range(readings) if estimate_bias else known_bias
    z = readings if bias is None else readings - bias[:, None]
    if name == "nominal layout":
        if nominal is None:
            raise CalibrationInputError("no nominal layout was given.", "Use another start.")
        a = np.asarray(nominal, float)
        if a.shape != (d, m):
            raise CalibrationInputError(f"the nominal layout has shape {a.shape}, not {(d, m)}.",
                                        "Give one nominal axis (column) per sensor.")
    else:
        a = principal_axes(z, c, d)
    v = measurement.fuse(a, z)
    return a, v * c / np.linalg.norm(v, axis=0), bias


def principal_axes(z: np.ndarray, c: float, d: int) -> np.ndarray:
    """a (d, m): the d leading left singular vectors of z (m, n), scaled so that |a^T v| matches
    the readings for |v| = c; of full rank d even when the readings span fewer dimensions."""
    u, s, _ = np.linalg.svd(z, full_matrices=False)
    if u.shape[1] < d:
        raise CalibrationInputError(
            f"{z.shape[1]} position(s) cannot span {d} dimensions.",
            "Record the unit in more orientations.")
    return np.linalg.norm(s) / (c * np.sqrt(z.shape[1])) * u[:, :d].T


def _mid_range(readings: np.ndarray) -> np.ndarray:
    """(m,) the middle of each sensor's range of readings: its bias if the poses are spread."""
    return (readings.max(axis=1) + readings.min(axis=1)) / 2
