"""The closed-form ML of one mounting's faces (station.solve.iron_faces) against the iterative path
(`station.calibrate` with the faces' constraints) field by field, against the linear-regression
formulas it must reduce to, and its hand-overs to the general path; on imucal's Ferraris
recordings both paths of `calibrate_ferraris` (skipped without ../shared)."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from station.errors import CalibrationInputError
from station.model.frames import align_to
from station.reduce.ferraris import (
    calibrate_ferraris,
    find_sections,
    labelled_sections,
    read_recording,
)
from station.solve.calibrate import calibrate
from station.solve.constraints import FACES, face_directions, from_faces
from station.solve.iron_faces import calibrate_faces, fit_faces

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "imucal-ferraris"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason="real data (../shared) not available")
G = 9.81
TOL = 1e-9
SKIPPED = {"iterations", "covariance", "axis_angles"}
"""Fields compared apart: iterations (the closed form needs none), the covariance of theta (each
path expresses it at its own estimate of a, in a frame the gauge leaves free: compared by its
eigenvalues), the axis angles (their diagonal is arccos(1) to rounding, about 1e-8: compared off
the diagonal)."""


def triad(rng):
    """A triad with 2-5 % scale errors, about 1 deg misalignments and biases."""
    return np.diag([1.02, 0.97, 1.05]) + 0.02 * rng.standard_normal((3, 3)), rng.normal(0, 0.2, 3)


def six_faces(rng, noise: float, faces=FACES):
    a, b = triad(rng)
    v = G * face_directions(faces)
    return a.T @ v + b[:, None] + noise * rng.standard_normal((3, len(faces)))


def assert_same(fast, general):
    """Every field of two CalibrationResults equal to TOL of the field's size (residuals: of the
    readings' size, to which the iterative fit converges; chi2: of m n; module notes)."""
    readings = np.abs(general.a.T @ general.v).max()
    for field in dataclasses.fields(fast):
        x, y = getattr(fast, field.name), getattr(general, field.name)
        if field.name in SKIPPED:
            continue
        if isinstance(y, np.ndarray):
            size = readings if field.name == "residuals" else np.abs(y).max()
            np.testing.assert_allclose(x, y, rtol=0, atol=TOL * max(size, 1e-300),
                                       err_msg=field.name)
        elif isinstance(y, float):  # chi2 of an exact fit: rounding, on the scale of m n
            floor = TOL * general.residuals.size if field.name == "chi2" else 1e-300
            assert x == pytest.approx(y, rel=TOL, abs=floor), field.name
        else:
            assert x == y, field.name
    off = ~np.eye(fast.m, dtype=bool)
    np.testing.assert_allclose(fast.axis_angles[off], general.axis_angles[off], rtol=TOL)
    scale = np.abs(general.covariance).max()
    np.testing.assert_allclose(np.linalg.eigvalsh(fast.covariance),
                               np.linalg.eigvalsh(general.covariance), atol=TOL * scale)
    assert fast.iterations == 0 < general.iterations


@pytest.mark.parametrize("sigma", [None, 0.01, 0.002])
def test_six_faces_match_the_iterative_ml(sigma):
    # sigma 0.002 against noise 0.01: a per-pose term is estimated (pose_sigma > 0)
    readings = six_faces(np.random.default_rng(7), 0.01)
    fast = calibrate_faces(readings, FACES, G, bias="estimate", sigma=sigma)
    general = calibrate(readings, G, d=3, bias="estimate", constraints=from_faces(FACES),
                        sigma=sigma)
    assert_same(fast, general)
    if sigma == 0.002:
        assert fast.pose_sigma > 0


def test_repeated_faces_with_a_noise_per_sensor_match_the_iterative_ml():
    rng = np.random.default_rng(3)
    faces = FACES + ("+z", "-x")
    readings = six_faces(rng, 0.01, faces)
    sigma = rng.uniform(0.005, 0.02, 3)
    fast = calibrate_faces(readings, faces, G, bias="estimate", sigma=sigma)
    general = calibrate(readings, G, d=3, bias="estimate", constraints=from_faces(faces),
                        sigma=sigma)
    assert_same(fast, general)


def test_a_noise_per_reading_goes_to_the_general_path():
    """Unequal weights within a sensor move the estimate with the per-pose term: not the closed
    form's (fit_faces)."""
    rng = np.random.default_rng(3)
    faces = FACES + ("+z", "-x")
    readings = six_faces(rng, 0.01, faces)
    sigma = rng.uniform(0.005, 0.02, readings.shape)
    fast = calibrate_faces(readings, faces, G, bias="estimate", sigma=sigma)
    general = calibrate(readings, G, d=3, bias="estimate", constraints=from_faces(faces),
                        sigma=sigma)
    assert fast.iterations == general.iterations > 0
    np.testing.assert_array_equal(fast.a, general.a)


def test_loose_turns_keep_the_closed_form_estimate_and_the_general_result():
    """Turns so noisy that the scale factors' 1-sigma passes 10 %: the estimate is the closed
    form's at once (three turns: no weight moves it), the result the general path's, the loose
    parameters named."""
    rng = np.random.default_rng(5)
    a, _ = triad(rng)
    senses = ("-x", "+y", "-z")
    w = a.T @ (2 * np.pi * face_directions(senses)) + 1e-3 * rng.standard_normal((3, 3))
    sigma = np.full((3, 3), 2.0)
    solved = fit_faces(w, senses, 2 * np.pi, sigma=sigma)
    general = calibrate(w, 2 * np.pi, d=3, constraints=from_faces(senses), sigma=sigma)
    assert general.weakly_determined
    np.testing.assert_allclose(solved.a, a, rtol=0, atol=1e-3)
    assert solved.result.iterations == general.iterations > 0
    assert solved.result.weakly_determined == general.weakly_determined
    np.testing.assert_allclose(align_to(general.v, 2 * np.pi * face_directions(senses))
                               @ general.a, solved.a, rtol=0, atol=TOL * np.abs(a).max())


def test_three_turns_match_the_iterative_ml():
    rng = np.random.default_rng(5)
    a, _ = triad(rng)
    senses = ("-x", "+y", "-z")
    w = a.T @ (2 * np.pi * face_directions(senses)) + 1e-3 * rng.standard_normal((3, 3))
    sigma = rng.uniform(1e-3, 3e-3, (3, 3))
    fast = calibrate_faces(w, senses, 2 * np.pi, sigma=sigma)
    general = calibrate(w, 2 * np.pi, d=3, constraints=from_faces(senses), sigma=sigma)
    assert_same(fast, general)
    assert fast.dof == 0 and fast.chi2 == pytest.approx(0, abs=1e-20)


def test_the_result_made_later_is_of_the_readings_given():
    """The result is made when read: changing the caller's arrays before that changes nothing."""
    readings = six_faces(np.random.default_rng(13), 0.01)
    sigma = np.full(3, 0.002)
    solved = fit_faces(readings, list(FACES), G, bias="estimate", sigma=sigma)
    expected = calibrate_faces(readings, FACES, G, bias="estimate", sigma=sigma)
    readings[:] = 0.0
    sigma[:] = 1.0
    np.testing.assert_array_equal(solved.result.a, expected.a)
    np.testing.assert_array_equal(solved.result.a_sigma, expected.a_sigma)


def test_six_faces_are_the_linear_regression():
    """b = mean of the six readings, a's column k (iron frame) = (z(+k) - z(-k)) / (2 g), and the
    1-sigmas of a linear regression with s^2 = RSS / 6, widened by (t_6(0.975) / 1.96)^2."""
    readings = six_faces(np.random.default_rng(11), 0.01)
    fit = calibrate_faces(readings, FACES, G, bias="estimate")
    a_iron = (readings[:, 0::2] - readings[:, 1::2]) / (2 * G)  # rows: sensors, columns: x y z
    bias = readings.mean(axis=1)
    residuals = readings - a_iron @ (G * face_directions(FACES)) - bias[:, None]
    s2 = np.sum(residuals**2) / 6
    widen = (stats.t.ppf(0.975, 6) / stats.norm.ppf(0.975)) ** 2
    np.testing.assert_allclose(fit.bias, bias, rtol=1e-12)
    np.testing.assert_allclose(fit.scale_factors, np.linalg.norm(a_iron, axis=1), rtol=1e-12)
    np.testing.assert_allclose(fit.residuals, residuals, atol=1e-12)
    assert fit.dof == 6 and fit.chi2 == pytest.approx(6.0)
    np.testing.assert_allclose(fit.bias_sigma, np.sqrt(widen * s2 / 6), rtol=1e-10)
    np.testing.assert_allclose(fit.scale_factors_sigma, np.sqrt(widen * s2 / (2 * G**2)),
                               rtol=1e-10)
    norms = np.linalg.norm(a_iron, axis=1)
    angle_var = widen * s2 / (2 * G**2) * (1 / norms[:, None] ** 2 + 1 / norms[None, :] ** 2)
    off = ~np.eye(3, dtype=bool)
    np.testing.assert_allclose(fit.axis_angles_sigma[off], np.sqrt(angle_var)[off], rtol=1e-10)


def test_designs_it_does_not_cover_go_to_the_general_path():
    rng = np.random.default_rng(2)
    five = FACES[:5]
    readings = six_faces(rng, 0.01, five)  # -z missing: not every axis on both faces
    fast = calibrate_faces(readings, five, G, bias="estimate")
    general = calibrate(readings, G, d=3, bias="estimate", constraints=from_faces(five))
    assert fast.iterations == general.iterations > 0
    np.testing.assert_array_equal(fast.a, general.a)
    known = calibrate_faces(six_faces(rng, 0.01), FACES, G, bias=np.zeros(3))
    assert known.iterations > 0 and not known.bias_estimated


@pytest.mark.parametrize("noise, faces", [
    (0.03 * G, FACES),  # residuals beyond 1 % of the stimulus: the general path decides
    (0.5 * G, FACES),  # and the scale factors' 1-sigma far beyond 10 %: loose or refused
    (0.001, ("+y", "-x", "+x", "-y", "+z", "-z")),  # +x and +y swapped: a wrong face label
])
def test_fits_the_closed_form_cannot_vouch_for_go_to_the_general_path(noise, faces):
    readings = six_faces(np.random.default_rng(4), noise)
    try:
        general = calibrate(readings, G, d=3, bias="estimate", constraints=from_faces(faces))
    except CalibrationInputError as exc:
        with pytest.raises(CalibrationInputError) as fast_exc:
            calibrate_faces(readings, faces, G, bias="estimate")
        assert str(fast_exc.value) == str(exc)
        return
    fast = calibrate_faces(readings, faces, G, bias="estimate")
    assert fast.iterations == general.iterations > 0
    np.testing.assert_array_equal(fast.a, general.a)
    assert fast.weakly_determined == general.weakly_determined


def test_bad_faces_are_refused_as_the_general_path_refuses_them():
    readings = six_faces(np.random.default_rng(1), 0.01)
    with pytest.raises(CalibrationInputError, match="Unknown face labels"):
        calibrate_faces(readings, FACES[:5] + ("+w",), G, bias="estimate")
    with pytest.raises(CalibrationInputError, match="NaN"):
        calibrate_faces(np.full((3, 6), np.nan), FACES, G, bias="estimate")


@needs_data
@pytest.mark.parametrize("recording", ["annotated_session.csv", "example_ferraris_session.csv"])
def test_ferraris_closed_form_is_the_iterative_ml_on_imucals_recordings(recording):
    rec = read_recording(DATA / recording)
    if rec.labels is not None:
        fs, sections = 204.8, labelled_sections(rec.labels)  # PROVENANCE.md
    else:
        fs = 102.4
        sections = find_sections(rec.acc, rec.gyro, fs, gyro_per_rad=180 / np.pi).sections
    fast = calibrate_ferraris(rec.acc, rec.gyro, fs, sections, G)
    general = calibrate_ferraris(rec.acc, rec.gyro, fs, sections, G, general=True)
    assert_same(fast.accel, general.accel)
    assert_same(fast.gyro.fit, general.gyro.fit)
    for x, y in ((fast.a_acc, general.a_acc), (fast.gyro.a, general.gyro.a)):
        np.testing.assert_allclose(x, y, rtol=0, atol=TOL * np.abs(y).max())
    np.testing.assert_array_equal(fast.readings, general.readings)
