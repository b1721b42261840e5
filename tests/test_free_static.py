"""Free-static path on a simulated recording (accelerometer calibration, gyro bias from the rest),
leave-one-out check, and the table reader (text and MATLAB v5, hostile files refused)."""

import numpy as np
import pytest
import scipy.io
from test_stillness import A_TRUE, COUNTS, FS, simulated

from station.errors import CalibrationInputError
from station.imports.tables import read_table
from station.model.earth import normal_gravity
from station.reduce.free_static import calibrate_free_static, leave_one_out
from station.solve.uncertainty import axis_angles

G = normal_gravity(45.4)  # the latitude of `simulated`
GYRO_BIAS = np.array([12.0, -30.0, 7.0])  # counts
GYRO_NOISE = 25.0  # counts per sample


def with_gyro(seed: int):
    """Accelerometer counts of `simulated` plus a gyro: bias and white noise, large rates in
    motion."""
    y, truth, _, _ = simulated(seed)
    rng = np.random.default_rng(100 + seed)
    gyro = GYRO_BIAS + GYRO_NOISE * rng.standard_normal(y.shape)
    moving = np.ones(len(y), bool)
    for a, b in truth:
        moving[a:b] = False
    gyro[moving] += 2000 * np.sin(np.arange(moving.sum()) / 20.0)[:, None]
    return y, gyro


def test_recovers_the_simulated_accelerometer_and_gyro_bias():
    y, gyro = with_gyro(seed=7)
    fit = calibrate_free_static(y, FS, G, gyro=gyro)
    acc = fit.accel
    assert fit.readings.shape == (3, 15)
    true_scale = COUNTS * np.linalg.norm(A_TRUE, axis=0)
    assert np.all(np.abs(acc.scale_factors - true_scale) < 4 * acc.scale_factors_sigma)
    true_bias = COUNTS * np.array([0.2, -0.1, 0.3])
    assert np.all(np.abs(acc.bias - true_bias) < 4 * acc.bias_sigma)
    iu = np.triu_indices(3, 1)
    err = acc.axis_angles[iu] - axis_angles(A_TRUE)[iu]
    assert np.all(np.abs(err) < 4 * acc.axis_angles_sigma[iu])
    n_rest = np.diff(fit.still.intervals[fit.rest_index])[0]
    np.testing.assert_allclose(fit.gyro_bias_sigma, GYRO_NOISE / np.sqrt(n_rest), rtol=0.2)
    assert np.all(np.abs(fit.gyro_bias - GYRO_BIAS) < 4 * fit.gyro_bias_sigma)


def test_leave_one_out_matches_the_noise():
    """Held-out |a| - g: a pose mean has noise 3.2 counts / sqrt(~330 samples) / 400 counts per
    m/s^2 = 4.4e-4 m/s^2 along g; a prediction from 14 poses and 9 parameters inflates that by about
    sqrt(1 + 9/14): expected RMS ~5.7e-4. The bounds leave room for high-leverage held-out poses."""
    y, _ = with_gyro(seed=8)
    fit = calibrate_free_static(y, FS, G)
    errors = leave_one_out(fit.readings, G)
    assert errors.shape == (15,)
    rms = np.sqrt(np.mean(errors**2))
    assert 1e-4 < rms < 1.5e-3


def test_shape_mismatch_is_refused():
    y, gyro = with_gyro(seed=9)
    with pytest.raises(CalibrationInputError, match="same time base"):
        calibrate_free_static(y, FS, G, gyro=gyro[:-1])
    with pytest.raises(CalibrationInputError, match=r"m >= 3 accelerometer"):
        calibrate_free_static(y[:, :2], FS, G)


def test_four_accelerometers_go_through_the_joint_bias_factorization():
    # a fourth sensor along (1, 1, 1)/sqrt(3) of the triad: axis a w, bias b . w + 500 counts (a
    # bias in the span of the axes would be unidentifiable: the factorization refuses that case)
    y, _, _, _ = simulated(seed=12)
    w = np.ones(3) / np.sqrt(3)
    fit = calibrate_free_static(np.hstack([y, (y @ w + 500.0)[:, None]]), FS, G)
    assert fit.readings.shape == (4, 15) and fit.accel.method == "factorization"
    true_scale = COUNTS * np.linalg.norm(A_TRUE, axis=0)
    assert np.all(np.abs(fit.accel.scale_factors[:3] - true_scale)
                  < 4 * fit.accel.scale_factors_sigma[:3])
    expected_fourth = COUNTS * np.linalg.norm(A_TRUE @ w)
    assert abs(fit.accel.scale_factors[3] - expected_fourth) < 4 * fit.accel.scale_factors_sigma[3]


def test_too_few_poses_are_refused_with_advice():
    y, _, _, _ = simulated(seed=10, poses=6)
    with pytest.raises(CalibrationInputError, match="more static positions"):
        calibrate_free_static(y, FS, G)


def test_reads_text_and_matlab_tables(tmp_path):
    table = np.random.default_rng(0).normal(size=(50, 4))
    np.savetxt(tmp_path / "t.mat", table)  # text despite the suffix, like the imu_tk files
    np.testing.assert_allclose(read_table(tmp_path / "t.mat", 4), table, rtol=1e-15)
    scipy.io.savemat(tmp_path / "b.mat", {"data": table})
    np.testing.assert_array_equal(read_table(tmp_path / "b.mat", 4), table)


@pytest.mark.parametrize(
    "write, words",
    [
        (lambda p: scipy.io.savemat(p, {"a": np.ones((3, 4)), "b": np.ones((3, 4))}), "variables"),
        (lambda p: scipy.io.savemat(p, {"c": np.array([[1.0], "x"], dtype=object)}), "numeric"),
        (lambda p: p.write_text("1 2 3 4\n5 6 oops 8\n"), "neither"),
        (lambda p: p.write_text("1 2 3\n4 5 6\n"), "expected 4"),
        (lambda p: p.write_text("1 2 3 4\n5 nan 7 8\n"), "finite"),
    ],
)
def test_bad_tables_are_refused(tmp_path, write, words):
    path = tmp_path / "x.mat"
    write(path)
    with pytest.raises(CalibrationInputError, match=words):
        read_table(path, 4)
