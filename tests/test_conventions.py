"""The conventions of docs/conventions.md, checked on the code."""

import numpy as np
import pytest
from layouts import A_MODEL, random_directions

import station
from station.model.frames import align_to, canonical_rotation, to_canonical


def rotation(rng, d):
    q, _ = np.linalg.qr(rng.standard_normal((d, d)))
    return q


def test_readings_are_sensors_by_positions_and_model_has_bias_after_projection():
    rng = np.random.default_rng(0)
    a = A_MODEL + 0.02 * rng.standard_normal(A_MODEL.shape)
    v = random_directions(rng, 3, 30, magnitude=2.0)
    b = rng.normal(0, 0.5, 12)
    readings = a.T @ v + b[:, None]  # z_i = a_i . v + b_i
    res = station.calibrate(readings, 2.0, bias=b, nominal=a, refine=False)
    assert res.a.shape == (3, 12) and res.v.shape == (3, 30) and res.residuals.shape == (12, 30)
    np.testing.assert_allclose(res.a, a, atol=1e-9)  # nominal frame = physical frame here
    # applying the calibration: v = (a a^T)^-1 a (z - b)
    np.testing.assert_allclose(res.apply(readings), v, atol=1e-9)
    np.testing.assert_allclose(res.apply(readings[:, 0]), v[:, 0], atol=1e-9)


def test_canonical_frame_is_upper_triangular_with_positive_diagonal():
    rng = np.random.default_rng(1)
    for d in (2, 3, 4):
        a = rng.standard_normal((d, d + 3))
        c = to_canonical(a)
        assert np.allclose(np.tril(c[:, :d], -1), 0, atol=1e-12)
        assert np.all(np.diag(c) > 0)
        h = canonical_rotation(a)
        np.testing.assert_allclose(h @ h.T, np.eye(d), atol=1e-12)


def test_eps_ignores_rotations_and_reflections_of_either_argument():
    rng = np.random.default_rng(2)
    a = rng.standard_normal((3, 8))
    r = rotation(rng, 3)
    mirror = np.diag([1.0, 1.0, -1.0])
    assert station.eps(a, r @ a) < 1e-12
    assert station.eps(mirror @ a, a) < 1e-12
    assert station.eps(a, a + 0.1) > 0.1


def test_nominal_alignment_resolves_handedness():
    rng = np.random.default_rng(3)
    a = A_MODEL + 0.01 * rng.standard_normal(A_MODEL.shape)
    mirrored = np.diag([1.0, -1.0, 1.0]) @ rotation(rng, 3) @ a
    r = align_to(mirrored, A_MODEL)
    assert np.linalg.det(r) < 0  # the reflection is undone
    assert np.linalg.norm(r @ mirrored - a) < 0.05  # within the layout's perturbation (0.01 each)


def test_unknown_magnitude_fixes_scale_factors_up_to_a_common_factor():
    rng = np.random.default_rng(4)
    a = A_MODEL * rng.uniform(0.5, 2.0, 12)
    v = random_directions(rng, 3, 25, magnitude=7.0)
    res = station.calibrate(a.T @ v, None)  # Remark 2
    assert not res.scale_known
    ratio = res.scale_factors / np.linalg.norm(a, axis=0)
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-9)
    assert abs(ratio[0] - 7.0) < 1e-8  # the common factor is the unknown magnitude


def test_measurement_model_has_one_orientation_instants_are_columns():
    """station.model.measurement: forward z = a^T v + b and fusion v = (a a^T)^-1 a (z - b) take
    and return one column per instant; a single instant is a 1-D vector; every apply delegates."""
    from station.model import measurement

    rng = np.random.default_rng(7)
    a = A_MODEL + 0.02 * rng.standard_normal(A_MODEL.shape)
    v = rng.standard_normal((3, 5))
    b = rng.normal(0, 0.5, 12)
    z = measurement.forward(a, v, b)
    np.testing.assert_allclose(z, a.T @ v + b[:, None], atol=1e-12)
    assert measurement.forward(a, v[:, 0], b).shape == (12,)
    np.testing.assert_allclose(measurement.fuse(a, z, b), v, atol=1e-12)
    np.testing.assert_allclose(measurement.fuse(a, z[:, 0], b), v[:, 0], atol=1e-12)
    np.testing.assert_allclose(measurement.fuse(a, a.T @ v), v, atol=1e-12)  # unbiased
    np.testing.assert_allclose(measurement.fusion_matrix(a) @ a.T, np.eye(3), atol=1e-12)
    with pytest.raises(ValueError, match="one column per instant"):
        measurement.fuse(a, z.T, b)  # rows of samples must be transposed by the caller
