"""The solver refuses only what the data cannot determine (issue 14): small pose sets are solved
(closed form, or a fallback start when it fails), every leave-one-out fold equals maximum likelihood
started from the truth, and rank-deficient sets are refused naming the undetermined parameter."""

import numpy as np
import pytest
from posesim import G, mpu6050_triad, pose_means
from scipy.spatial.transform import Rotation

import station
from station.model.frames import to_canonical
from station.reduce.free_static import leave_one_out
from station.solve import ml

NAMES = ["acc_x", "acc_y", "acc_z"]


def spread_poses(n: int, rng) -> np.ndarray:
    """(3, n) directions of a Fibonacci sphere, randomly turned: n poses spread over the sphere."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    v = np.stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z])
    return Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix() @ v


def imu_array(rng, count: int):
    """(a (3, 3 count), b): `count` MPU-6050 triads in random orientations on one board."""
    parts = [mpu6050_triad(rng) for _ in range(count)]
    turns = Rotation.random(count, random_state=int(rng.integers(1 << 31))).as_matrix()
    return (np.hstack([r @ a for r, (a, _) in zip(turns, parts, strict=True)]),
            np.concatenate([b for _, b in parts]))


def assert_folds_match_ml_from_truth(a, b, v, readings):
    """Each fold (one pose left out) calibrates, and equals ML started from the true a, v, b
    within 1e-6 (canonical a, biases): the solver found the likelihood's maximum. Returns the
    starts used."""
    n, used = v.shape[1], []
    for j in range(n):
        keep = np.delete(np.arange(n), j)
        result = station.calibrate(readings[:, keep], G, bias="estimate")
        truth = ml.refine(readings[:, keep], a, G * v[:, keep], bias0=b, estimate_bias=True,
                          magnitude=G, max_iter=1000)
        assert truth.converged
        np.testing.assert_allclose(to_canonical(result.a), to_canonical(truth.a), atol=1e-6)
        np.testing.assert_allclose(result.bias, truth.bias, atol=1e-6)
        used.append(result.start)
    return used


def test_nine_pose_folds_of_a_triad_equal_ml_from_the_truth():
    """10 poses of an MPU-6050 (folds of 9, the fewest a triad with biases allows): no fold is
    refused. Before issue 14 the ellipsoid's SVD took the wrong row with exactly 9 poses and every
    such fold was refused as 'not closed'."""
    rng = np.random.default_rng(14)
    for _ in range(4):
        a, b = mpu6050_triad(rng)
        v = spread_poses(10, rng)
        readings, _ = pose_means(rng, a, b, v)
        assert set(assert_folds_match_ml_from_truth(a, b, v, readings)) == {"closed form"}
        held = leave_one_out(readings, G)
        assert held.refused == {} and np.all(np.isfinite(held))


def test_an_imu_array_falls_back_when_its_factorization_fails():
    """8 triads (24 accelerometers) from 9 poses: the joint-bias factorization often fails or
    starts ML too far away; the principal-axes start then reaches the same maximum."""
    rng = np.random.default_rng(15)
    a, b = imu_array(rng, 8)
    v = spread_poses(10, rng)
    readings, _ = pose_means(rng, a, b, v)
    used = assert_folds_match_ml_from_truth(a, b, v, readings)
    assert "principal axes" in used, used


def test_leave_one_out_reports_refused_folds_and_goes_on():
    """9 poses leave folds of 8: a triad with biases has 9 unknowns, so every fold is refused,
    with the pose and the reason; nothing is raised."""
    rng = np.random.default_rng(16)
    a, b = mpu6050_triad(rng)
    readings, stderr = pose_means(rng, a, b, spread_poses(9, rng))
    held = leave_one_out(readings, G, sigma=stderr)
    assert sorted(held.refused) == list(range(9)) and np.all(np.isnan(held))
    assert all("at least 9 poses" in why for why in held.refused.values())
    assert held.starts == (None,) * 9


def test_exactly_nine_noise_free_poses_give_the_triad_exactly():
    rng = np.random.default_rng(17)
    a, b = mpu6050_triad(rng)
    v = spread_poses(9, rng)
    result = station.calibrate(a.T @ (G * v) + b[:, None], G, bias="estimate")
    np.testing.assert_allclose(result.scale_factors, np.linalg.norm(a, axis=0), rtol=1e-9)
    np.testing.assert_allclose(result.bias, b, atol=1e-8)
    assert result.start == "closed form"


def refusal(v, rng):
    """The refusal of an MPU-6050's poses v (sigma from the samples)."""
    a, b = mpu6050_triad(rng)
    readings, stderr = pose_means(rng, a, b, v)
    with pytest.raises(station.CalibrationInputError) as err:
        station.calibrate(readings, G, bias="estimate", sigma=stderr, names=NAMES)
    return err.value


def test_poses_with_one_axis_at_one_angle_name_its_scale_and_bias():
    """Every pose has acc_z 30 degrees from up (the unit turned about the vertical on a wedge):
    acc_z reads s g cos 30 + b in every pose, so its scale and bias are not separable."""
    phi = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    tilt = np.radians(30)
    v = np.stack([np.sin(tilt) * np.cos(phi), np.sin(tilt) * np.sin(phi),
                  np.full(12, np.cos(tilt))])
    err = refusal(v, np.random.default_rng(18))
    assert "the scale and the bias of acc_z are not separable" in err.problem
    assert "every pose gives acc_z the same reading" in err.problem
    assert "acc_z turned the other way or horizontal" in err.advice


def test_poses_in_a_plane_name_the_axis_they_never_tilt():
    """Turns about acc_x only: acc_x never sees gravity, so its scale is not determined."""
    phi = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    v = np.stack([np.zeros(12), np.cos(phi), np.sin(phi)])
    err = refusal(v, np.random.default_rng(19))
    assert "the scale and the bias of acc_x are not separable" in err.problem
    assert "acc_x turned the other way or horizontal" in err.advice


def test_inconsistent_readings_are_still_refused_after_the_fallbacks():
    """Readings on a hyperboloid (x^2 + y^2 - z^2 = g^2: no constant magnitude): the quadric is
    not closed, and the best fit of every fallback start misses them by far more than 1 % of g,
    so the refusal says so and quotes the closed form."""
    rng = np.random.default_rng(20)
    z = rng.uniform(-0.8, 0.8, 20)
    phi = rng.uniform(0, 2 * np.pi, 20)
    r = np.sqrt(1 + z**2)
    readings = G * np.stack([r * np.cos(phi), r * np.sin(phi), z]) + 0.3
    with pytest.raises(station.CalibrationInputError) as err:
        station.calibrate(readings, G, bias="estimate")
    assert "no calibration explains the readings" in err.value.problem
    assert "not a closed ellipsoid" in err.value.problem


def test_fallback_starts_reach_the_closed_forms_maximum():
    """Each fallback start of a triad (no closed form needed) refines to the same maximum as the
    ellipsoid: the axis-aligned ellipsoid is exact for an axis-aligned triad, the nominal layout and
    the principal axes start further off."""
    from station.solve import starts
    from station.solve.ellipsoid import ellipsoid_calibration

    rng = np.random.default_rng(21)
    v = spread_poses(16, rng)
    aligned, bias = np.diag([1.03, 0.98, 1.01]), np.array([0.4, -0.6, 0.2])
    a, _, b = ellipsoid_calibration(aligned.T @ (G * v) + bias[:, None], G, axis_aligned=True)
    np.testing.assert_allclose(a, aligned, atol=1e-12)
    np.testing.assert_allclose(b, bias, atol=1e-10)
    a_true, b_true = mpu6050_triad(rng)
    readings, stderr = pose_means(rng, a_true, b_true, v)
    best = station.calibrate(readings, G, bias="estimate")
    for name in starts.FALLBACKS:
        a0, v0, b0 = starts.fallback(name, readings, None, True, G, 3, np.eye(3))
        fit = ml.refine(readings, a0, v0, bias0=b0, estimate_bias=True, magnitude=G)
        np.testing.assert_allclose(to_canonical(fit.a), best.a, atol=1e-6, err_msg=name)
        np.testing.assert_allclose(fit.bias, best.bias, atol=1e-6, err_msg=name)
