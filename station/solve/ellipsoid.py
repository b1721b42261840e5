"""Closed-form start for a triad with unknown biases from arbitrary static orientations.

With m = d sensors, z_j = a^T v_j + b and |v_j| = c give (z_j - b)^T (a^T a)^-1 (z_j - b) = c^2: the
readings lie on an ellipsoid. An algebraic quadric fit (z^T Q z + l . z + k = 0, least squares on
the unit-norm coefficient vector) gives its centre b and shape; a Cholesky factor of the shape gives
a in the canonical upper-triangular frame of Eq. (19). Maximum likelihood (station/solve/ml.py) then
refines it. The axis-aligned variant drops the cross terms (z^T Q z with Q diagonal: no
misalignment, 2d + 1 coefficients), a start that exists when the general quadric is not closed,
e.g. from few or noisy poses.
"""

import numpy as np

from station.errors import CalibrationInputError
from station.model import measurement


def quadric_pairs(d: int, axis_aligned: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (rows, cols) of the quadratic monomials: all i <= k, or only the squares."""
    return (np.arange(d),) * 2 if axis_aligned else np.triu_indices(d)


def quadric_terms(z: np.ndarray, axis_aligned: bool = False) -> np.ndarray:
    """Monomials of a quadric in d variables per reading: (n, d(d+1)/2 + d + 1), or (n, 2d + 1)
    axis-aligned."""
    d, n = z.shape
    rows, cols = quadric_pairs(d, axis_aligned)
    return np.hstack([(z[rows] * z[cols]).T, z.T, np.ones((n, 1))])


def ellipsoid_calibration(readings, magnitude: float = 1.0, axis_aligned: bool = False):
    """Sensitivity a (d x d, canonical frame), stimuli v (d x n) and bias b (d,) of a triad.

    Readings are d x n static averages in arbitrary orientations (no opposite pairs needed).
    axis_aligned: fit an ellipsoid whose axes are the sensor axes (a diagonal: no misalignment).
    """
    z = np.asarray(readings, dtype=float)
    d, n = z.shape
    rows, cols = quadric_pairs(d, axis_aligned)
    unknowns = len(rows) + d + 1
    if n < unknowns - 1:
        raise CalibrationInputError(
            f"{n} static positions cannot fix the biases and the {d}x{d} shape of a triad "
            f"(an ellipsoid fit needs at least {unknowns - 1}).",
            f"Record {unknowns - 1 - n} more static positions in new orientations spread over "
            "the sphere, or give the biases.",
        )
    centre = z.mean(axis=1, keepdims=True)
    span = np.abs(z - centre).max()
    terms = quadric_terms((z - centre) / span, axis_aligned)  # centred, scaled for conditioning
    _, s, vt = np.linalg.svd(terms)  # full: with n = unknowns - 1 the null vector is vt[-1]
    s = np.r_[s, np.zeros(unknowns - len(s))]  # the spectrum over all `unknowns` coefficients
    if s[-2] <= 1e-10 * s[0]:
        raise CalibrationInputError(
            "the static orientations do not determine an ellipsoid (they lie on a plane or a "
            "cone, e.g. rotations about one axis only).",
            "Add orientations that tilt the unit about the other axes (up, down and sideways).",
        )
    coef = vt[-1]
    quad = np.zeros((d, d))
    quad[rows, cols] = coef[: len(rows)]
    quad = (quad + quad.T) / 2  # off-diagonal monomials carry the full coefficient
    lin, const = coef[len(rows) : len(rows) + d], coef[-1]
    centre_u = -np.linalg.solve(2 * quad, lin)
    level = centre_u @ quad @ centre_u - const
    shape = quad / level  # (u - u0)^T shape (u - u0) = 1 in scaled units
    lam = np.linalg.eigvalsh(shape)
    if lam.min() <= 0:
        raise CalibrationInputError(
            "the algebraic quadric through the readings is not a closed ellipsoid (too few or too "
            "noisy poses for this closed form, or readings of no constant magnitude).",
            "Check units and that the unit was static in each position; add positions spread "
            "over the sphere.",
        )
    bias = centre[:, 0] + span * centre_u
    # (z - b)^T shape (z - b) = span^2 and (z - b)^T (a^T a)^-1 (z - b) = c^2
    gram = np.linalg.inv(shape) * (span / magnitude) ** 2  # a^T a
    a = np.linalg.cholesky(gram).T  # upper triangular, positive diagonal
    v = measurement.fuse(a, z, bias)  # a square: a^-T (z - b)
    return a, v * magnitude / np.linalg.norm(v, axis=0), bias
