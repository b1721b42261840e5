"""The calibration file (station.calfiles.calfile): exact round trip, refusals of tampered, foreign
and malformed files, and the least-squares fusion it applies (docs/conventions.md)."""

import dataclasses
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import station
from station.calfiles.calfile import (
    FORMAT_VERSION,
    Calibration,
    CalibrationFileError,
    checksum,
    load,
    loads,
)

SENSORS = ("g1", "g2", "g3", "g4")


def make(a=None, bias=None, **kw) -> Calibration:
    """A 4-sensor calibration with hand-made numbers (not computed by the code under test)."""
    a = np.array([[1.0, 0.0, 0.0, 0.6], [0.0, 2.0, 0.0, 0.0], [0.0, 0.0, 0.5, 0.8]]) \
        if a is None else a
    m = a.shape[1]
    fields = {
        "unit_serial": "SN42", "sensors": SENSORS[:m], "units": ("rad/s",) * m, "a": a,
        "a_sigma": np.full(a.shape, 1e-4), "bias": np.array([0.01, -0.02, 0.003, 0.5])[:m]
        if bias is None else bias, "bias_sigma": np.full(m, 1e-5),
        "scale_factors": np.linalg.norm(a, axis=0), "scale_factors_sigma": np.full(m, 2e-4),
        "axis_angles": np.zeros((m, m)), "axis_angles_sigma": np.zeros((m, m)), "frame": "nominal",
        "magnitude": 1.0, "scale_known": True, "fit": {"method": "pca", "chi2": 80.5, "dof": 81},
        "counts_per_unit": np.full(m, 1e6), "session": {"path": "/sessions/SN42.h5"},
        "created": "2026-05-09T07:35:25Z", "software_version": "0.1.0"}
    fields.update(kw)
    return Calibration(**fields)


def edited(cal: Calibration, change, fix_checksum: bool = False) -> str:
    """The file text of `cal` after `change(doc)` (optionally with a recomputed checksum)."""
    doc = cal.to_document()
    change(doc)
    if fix_checksum:
        doc["checksum"] = checksum(doc)
    return json.dumps(doc)


def test_save_and_load_round_trip_exactly(tmp_path):
    cal = make()
    path = tmp_path / "SN42.cal.json"
    cal.save(path)
    back = load(path, unit_serial="SN42", sensors=SENSORS, units="rad/s")
    for name in ("a", "a_sigma", "bias", "bias_sigma", "scale_factors", "counts_per_unit"):
        assert getattr(back, name).tobytes() == np.asarray(getattr(cal, name), float).tobytes()
    assert (back.unit_serial, back.sensors, back.units, back.frame, back.session, back.created) \
        == (cal.unit_serial, cal.sensors, cal.units, cal.frame, cal.session, cal.created)
    assert back.dumps() == path.read_text()


finite = st.floats(-1e9, 1e9, allow_nan=False)  # subnormals included; |b| <= LIMITS["b"]


@settings(max_examples=60, deadline=None)
@given(scale=st.floats(1e-5, 1e8), column=arrays(np.float64, (3,), elements=st.floats(1e-3, 1e3)),
       bias=arrays(np.float64, (4,), elements=finite))
def test_any_plausible_float_survives_the_file_bit_for_bit(scale, column, bias):
    """Every float a unit can have (calfile.LIMITS: column norms 1e-9..1e12, |b| <= 1e9)."""
    a = scale * np.column_stack([np.diag([1.0, 0.5, 0.25]), column])  # rank 3, no overflow
    cal = make(a=a, bias=bias, scale_factors=np.ones(4))
    back = loads(cal.dumps())
    assert back.a.tobytes() == a.tobytes() and back.bias.tobytes() == bias.tobytes()


@pytest.mark.parametrize("edit, problem", [
    (lambda d: d["sensitivity"].update(a=[[x * 1e300 for x in r] for r in d["sensitivity"]["a"]]),
     "a must be finite"),
    (lambda d: d["sensitivity"].update(a=[[10 ** 400, *r[1:]] if i == 0 else r
                                          for i, r in enumerate(d["sensitivity"]["a"])]),
     r"sensitivity\.a\[0\]\[0\] = an integer of 401 digits: give a finite number"),
    (lambda d: d["bias"].update(b=[1e300] * len(d["bias"]["b"])), "b must be finite"),
    (lambda d: d.update(magnitude=1e300), "magnitude"),
    (lambda d: d["sensitivity"].update(a=[[1.0, 0.0, 1.0, 0.6], [0.0, 2.0, 1.0, 0.0],
                                          [1e-10, 0.0, 0.0, 1e-10]]),  # axes nearly in a plane
     "condition number"),
])
def test_absurd_finite_numbers_are_refused(edit, problem):
    """A crafted or damaged file whose numbers are finite but no unit has: applying it would
    overflow (NaN vectors) or divide by almost nothing."""
    with pytest.raises(CalibrationFileError, match=problem):
        loads(edited(make(), edit, True))


def test_files_are_written_once_unless_overwrite(tmp_path):
    path = tmp_path / "c.json"
    path.write_text("precious")
    with pytest.raises(FileExistsError, match="exists"):
        make().save(path)
    assert path.read_text() == "precious"
    make().save(path, overwrite=True)
    assert load(path).unit_serial == "SN42"


def test_an_unknown_version_is_refused_naming_the_versions():
    text = edited(make(), lambda d: d.update(format_version=FORMAT_VERSION + 1), True)
    with pytest.raises(CalibrationFileError,
                       match=r"format_version 7 .*reads \(1, 2, 3, 4, 5, 6\).*newer"):
        loads(text)
    for bad in ("1", 1.0, True, None):
        with pytest.raises(CalibrationFileError, match="format_version"):
            loads(edited(make(), lambda d, v=bad: d.update(format_version=v), True))


def test_a_tampered_unit_serial_is_refused():
    text = edited(make(), lambda d: d["unit"].update(serial="SN43"))
    with pytest.raises(CalibrationFileError, match="checksum does not match"):
        loads(text)


def test_a_tampered_number_is_refused():
    text = edited(make(), lambda d: d["bias"]["b"].__setitem__(0, 0.011))
    with pytest.raises(CalibrationFileError, match="checksum"):
        loads(text)


def test_another_units_calibration_is_refused(tmp_path):
    path = tmp_path / "c.json"
    make().save(path)
    with pytest.raises(CalibrationFileError, match="unit 'SN42' but the data comes from unit "
                                                   "'SN7'; use that unit's calibration file"):
        load(path, unit_serial="SN7")
    with pytest.raises(CalibrationFileError, match="sensors"):
        load(path, sensors=("g1", "g2", "g4", "g3"))
    with pytest.raises(CalibrationFileError, match="convert the readings to SI"):
        load(path, units="deg/s")


@pytest.mark.parametrize("change, message", [
    (lambda d: d["units"].update(readings=["deg/s"] * 4, stimulus="deg/s"), "SI unit"),
    (lambda d: d["units"].update(stimulus="m/s^2"), "stimulus"),
    (lambda d: d["sensitivity"].update(a=[[1, 0, 0, 0], [0, 1, 0, 0]] + [[0, 0, 1]]),
     "ragged|shape"),
    (lambda d: d["sensitivity"].update(a=[[1, 0, 0, 0]] * 3), "rank"),
    (lambda d: d["bias"].update(sigma=[-1e-5, 0, 0, 0]), "non-negative"),
    (lambda d: d["bias"].update(b=[True, 0, 0, 0]), "list of numbers"),
    (lambda d: d.update(frame="world"), "frame"),
    (lambda d: d.update(magnitude=-1.0), "magnitude"),
    (lambda d: d.update(extra=1), "unknown keys"),
    (lambda d: d.pop("session"), "missing keys"),
    (lambda d: d["unit"].update(sensors=["g1", "g1", "g2", "g3"]), "distinct"),
    (lambda d: d["conventions"].update(bias="before the projection"), "conventions"),
])
def test_malformed_content_is_refused_even_with_a_valid_checksum(change, message):
    with pytest.raises(CalibrationFileError, match=message):
        loads(edited(make(), change, fix_checksum=True))


def test_non_json_and_foreign_files_are_refused(tmp_path):
    text = make().dumps()
    with pytest.raises(CalibrationFileError, match=r"= nan: give a finite number"):
        loads(text.replace("1e-05", "NaN", 1))
    with pytest.raises(CalibrationFileError, match="duplicate keys"):
        loads('{"format": 1, "format": 2}')
    with pytest.raises(CalibrationFileError, match="is not valid JSON"):
        loads(text[:-10])
    with pytest.raises(CalibrationFileError, match="not an IMU station calibration file"):
        loads('{"format": "imu-station-session"}')
    with pytest.raises(CalibrationFileError, match="not an IMU station calibration file"):
        loads("[1, 2]")
    big = tmp_path / "big.json"
    big.write_bytes(b" " * (5 << 20))
    with pytest.raises(CalibrationFileError, match="at most"):
        load(big)
    with pytest.raises(CalibrationFileError, match="cannot read"):
        load(tmp_path / "missing.json")


def test_apply_is_least_squares_fusion_of_the_conventions():
    cal = make()
    rng = np.random.default_rng(5)
    v = rng.standard_normal((10, 3))
    z = v @ cal.a + cal.bias  # z_i = a_i . v + b_i, exactly; one row per instant
    assert np.allclose(cal.apply(z.T), v.T, atol=1e-12)  # one column per instant
    assert np.allclose(cal.apply(z[0]), v[0], atol=1e-12)
    # fusion weighs all sensors: noise on one redundant sensor moves v less than on a lone one
    noisy = z.copy()
    noisy[:, 3] += 0.1
    assert np.all(np.linalg.norm(cal.apply(noisy.T).T - v, axis=1) < 0.1)
    with pytest.raises(CalibrationFileError, match="4 readings per instant"):
        cal.apply(np.zeros((3, 2)))


def test_from_result_keeps_the_solver_output_and_needs_biases():
    rng = np.random.default_rng(3)
    a = np.array([[1.0, 0.0, 0.0, 0.6], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.8]])
    v = rng.standard_normal((3, 12))
    v /= np.linalg.norm(v, axis=0)
    result = station.calibrate(a.T @ v + 1e-3 * rng.standard_normal((4, 12)), 1.0, sigma=1e-3)
    with pytest.raises(CalibrationFileError, match="no estimated bias"):
        Calibration.from_result(result, "SN1", SENSORS, "rad/s")
    cal = Calibration.from_result(result, "SN1", SENSORS, "rad/s", bias=np.zeros(4),
                                  bias_sigma=np.ones(4), session={"path": "x.h5"})
    back = loads(cal.dumps())
    assert back.a.tobytes() == result.a.tobytes()
    assert back.fit["dof"] == result.dof and back.frame == result.frame == "canonical"
    assert back.axis_angles_sigma.tobytes() == result.axis_angles_sigma.tobytes()


def test_the_joint_covariance_goes_into_the_file_and_back():
    rng = np.random.default_rng(4)
    a = np.array([[1.0, 0.0, 0.0, 0.6], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.8]])
    v = rng.standard_normal((3, 16))
    v /= np.linalg.norm(v, axis=0)
    b = np.array([0.1, -0.2, 0.05, 0.3])
    joint = station.calibrate(a.T @ v + b[:, None] + 1e-3 * rng.standard_normal((4, 16)), 1.0,
                              bias="estimate", sigma=1e-3)
    cal = loads(Calibration.from_result(joint, "SN1", SENSORS, "rad/s").dumps())
    assert cal.covariance.tobytes() == joint.parameter_covariance.tobytes()  # (a, b) correlated
    assert np.abs(cal.covariance[:12, 12:]).max() > 0
    # biases measured apart (a rotary session's static windows): independent of a
    unbiased = station.calibrate(a.T @ v + 1e-3 * rng.standard_normal((4, 16)), 1.0, sigma=1e-3)
    sb = np.full(4, 2e-5)
    cal = loads(Calibration.from_result(unbiased, "SN1", SENSORS, "rad/s", bias=b,
                                        bias_sigma=sb).dumps())
    assert np.array_equal(cal.covariance[:12, :12], unbiased.parameter_covariance)
    assert np.array_equal(cal.covariance[12:, 12:], np.diag(sb**2))
    assert not cal.covariance[:12, 12:].any()


def with_covariance(cov) -> Calibration:
    """make() with a covariance whose diagonal agrees with its sigmas unless `cov` is given."""
    return make(covariance=cov)


def test_a_covariance_that_contradicts_the_file_is_refused():
    sigma = np.r_[np.full(12, 1e-4), np.full(4, 1e-5)]
    good = np.diag(sigma**2)
    good[0, 1] = good[1, 0] = 0.5e-8  # correlation 0.5 between two entries of a
    assert loads(with_covariance(good).dumps()).covariance.tobytes() == good.tobytes()
    asymmetric = good.copy()
    asymmetric[0, 1] *= 2
    wrong_diagonal = good.copy()
    wrong_diagonal[3, 3] *= 4
    indefinite = good.copy()
    indefinite[0, 1] = indefinite[1, 0] = 2e-8  # correlation 2
    for cov, problem in ((asymmetric, "not symmetric"), (wrong_diagonal, "diagonal differs"),
                         (indefinite, "not positive semi-definite"), (good[:4, :4], "shape")):
        with pytest.raises(CalibrationFileError, match=problem):
            loads(with_covariance(cov).dumps())


def test_a_version_1_file_still_loads_without_covariance():
    from station.calfiles.calfile import CONVENTIONS_V1

    def to_v1(doc):
        del doc["covariance"], doc["verdict"], doc["uncertainty"], doc["noise"], doc["temperature"]
        doc.update(format_version=1, conventions=CONVENTIONS_V1)

    back = loads(edited(make(), to_v1, True))
    assert back.covariance is None and back.verdict is None and back.unit_serial == "SN42"
    assert back.white is None and back.pose_sigma is None
    with pytest.raises(CalibrationFileError,
                       match="unknown keys \\['covariance', 'noise', 'temperature', "
                             "'uncertainty', 'verdict'\\]"):
        loads(edited(make(covariance=None), lambda d: d.update(format_version=1,
                                                              conventions=CONVENTIONS_V1), True))


def test_a_version_2_file_loads_without_a_verdict_and_a_verdict_round_trips():
    from station.calfiles.calfile import CONVENTIONS

    def to_v2(doc):
        del doc["verdict"], doc["uncertainty"], doc["noise"], doc["temperature"]
        doc.update(format_version=2, conventions=CONVENTIONS)

    assert loads(edited(make(), to_v2, True)).verdict is None
    judged = dataclasses.replace(make(), verdict={"overall": "FAIL", "parameters": [
        {"name": "g1 bias", "value": 0.3, "sigma": 0.01, "nominal": 0.0, "limit": 0.1,
         "verdict": "fail"}], "untested": [], "margin_sigma": 2.0})
    assert loads(judged.dumps()).verdict == judged.verdict
    with pytest.raises(CalibrationFileError, match="verdict must be null or an object"):
        loads(edited(judged, lambda d: d["verdict"].update(overall="OK"), True))


def test_vector_covariance_is_the_first_order_propagation():
    """Against central differences of apply() over each parameter of (a row-major, b)."""
    rng = np.random.default_rng(6)
    root = rng.standard_normal((16, 16)) * 1e-4
    cov = root @ root.T
    sigma = np.sqrt(np.diag(cov))
    cal = make(a_sigma=sigma[:12].reshape(3, 4), bias_sigma=sigma[12:], covariance=cov)
    z = rng.uniform(-2, 2, (4, 5))
    jac = np.zeros((5, 3, 16))
    for k in range(16):
        h = np.zeros(16)
        h[k] = 1e-6
        plus, minus = (make(a=cal.a + s * h[:12].reshape(3, 4), bias=cal.bias + s * h[12:])
                       for s in (1, -1))
        jac[:, :, k] = (plus.apply(z) - minus.apply(z)).T / 2e-6
    expected = np.einsum("kpi,ij,kqj->kpq", jac, cov, jac)
    np.testing.assert_allclose(cal.vector_covariance(z), expected, rtol=1e-6,
                               atol=1e-9 * np.abs(expected).max())
    with pytest.raises(CalibrationFileError, match="no covariance"):
        make().vector_covariance(z)


def test_calibrated_vectors_scatter_as_their_covariance_says():
    """Over repeated calibrations, the error of F (z - b) at one reading, in the canonical frame,
    has Mahalanobis distance chi2(3): mean 3 within 3 standard errors."""
    from station.model.frames import to_canonical

    rng = np.random.default_rng(5)
    a = to_canonical(np.array([[1.0, 0.0, 0.0, 0.6], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.8]]))
    b = np.array([0.1, -0.2, 0.05, 0.3])
    truth = np.array([0.3, -0.5, 0.8])
    z = a.T @ truth + b
    trials, d2 = 300, []
    for _ in range(trials):
        v = rng.standard_normal((3, 16))
        v /= np.linalg.norm(v, axis=0)
        res = station.calibrate(a.T @ v + b[:, None] + 1e-3 * rng.standard_normal((4, 16)), 1.0,
                                bias="estimate", sigma=1e-3)
        cal = Calibration.from_result(res, "SN1", SENSORS, "rad/s")
        err = cal.apply(z) - truth
        d2.append(err @ np.linalg.solve(cal.vector_covariance(z)[0], err))
    assert abs(np.mean(d2) - 3) < 3 * np.sqrt(6 / trials), np.mean(d2)


def test_a_version_3_file_loads_without_the_white_noise_figure():
    from station.calfiles.calfile import CONVENTIONS_V3

    def to_v3(doc):
        del doc["uncertainty"], doc["noise"], doc["temperature"]
        doc.update(format_version=3, conventions=CONVENTIONS_V3)

    back = loads(edited(make(), to_v3, True))
    assert back.white is None and back.pose_sigma is None and back.unit_serial == "SN42"


def test_both_figures_of_a_solve_go_into_the_file_and_back():
    """A triad whose poses carry a per-pose error 5x the stated noise: the file keeps the total
    1-sigma (the result's), the white-noise figure beside it, and the per-pose term."""
    rng = np.random.default_rng(5)
    a = np.diag([1.02, 0.98, 1.01])
    v = rng.standard_normal((3, 30))
    v /= np.linalg.norm(v, axis=0)
    b = np.array([0.1, -0.2, 0.05])
    z = a.T @ v + b[:, None] + 1e-3 * rng.standard_normal((3, 30)) \
        + 5e-3 * rng.standard_normal((3, 30))
    result = station.calibrate(z, 1.0, bias="estimate", sigma=1e-3)
    cal = loads(Calibration.from_result(result, "SN1", SENSORS[:3], "m/s^2").dumps())
    assert cal.pose_sigma == result.pose_sigma and 2.5e-3 < cal.pose_sigma < 1e-2
    assert cal.scale_factors_sigma.tobytes() == result.scale_factors_sigma.tobytes()
    assert cal.white["scale_factors_sigma"].tobytes() \
        == result.scale_factors_sigma_white.tobytes()
    assert np.all(cal.white["bias_sigma"] < cal.bias_sigma / 2)  # sqrt(1 + 25) ~ 5x apart
    assert cal.fit["start"] == "closed form"
    with pytest.raises(CalibrationFileError, match="pose_sigma"):
        loads(edited(cal, lambda d: d["uncertainty"].update(pose_sigma=-1.0), True))
    with pytest.raises(CalibrationFileError, match="bias_sigma has shape"):
        loads(edited(cal, lambda d: d["uncertainty"]["white"].update(bias_sigma=[1.0]), True))


def noisy(resolved: bool = True) -> Calibration:
    """make() with hand-made noise figures; B and K None unless `resolved`."""
    from station.calfiles.calfile import NoiseFigures

    full = np.array([1.5e-4, 2.25e-4, 1.0e-4, 3.0e-4])
    terms = (full / 3, full / 300, full / 30, full / 900) if resolved else (None,) * 4
    return make().with_noise(NoiseFigures(full, full / 100, *terms, rate_hz=200.0,
                                          seconds=3600.5))


@pytest.mark.parametrize("resolved", [True, False])
def test_noise_figures_round_trip_bit_for_bit(tmp_path, resolved):
    cal = noisy(resolved)
    path = tmp_path / "n.cal.json"
    cal.save(path)
    back = load(path)
    for name in ("white", "white_sigma", "bias_instability", "bias_instability_sigma",
                 "random_walk", "random_walk_sigma"):
        mine, theirs = getattr(cal.noise, name), getattr(back.noise, name)
        if name.startswith("white") or resolved:
            assert mine.tobytes() == theirs.tobytes()
        else:
            assert mine is None and theirs is None
    assert (back.noise.rate_hz, back.noise.seconds) == (200.0, 3600.5)
    assert back.dumps() == path.read_text()
    doc = json.loads(path.read_text())
    assert doc["format_version"] == 6 and doc["noise"]["units"]["random_walk"] == \
        "rad/s / sqrt(s)"
    assert loads(make().dumps()).noise is None  # not measured: null


def test_a_version_4_file_loads_without_noise_figures():
    from station.calfiles.calfile import CONVENTIONS_V4

    def to_v4(doc):
        del doc["noise"], doc["temperature"]
        doc.update(format_version=4, conventions=CONVENTIONS_V4)

    back = loads(edited(make(), to_v4, True))
    assert back.noise is None and back.white is None and back.unit_serial == "SN42"
    with pytest.raises(CalibrationFileError, match="unknown keys \\['noise', 'temperature'\\]"):
        loads(edited(noisy(), lambda d: d.update(format_version=4, conventions=CONVENTIONS_V4),
                     True))


@pytest.mark.parametrize("edit, problem", [
    (lambda n: n.update(white=[1e-4, -1e-4, 1e-4, 1e-4]), "noise.white must be finite"),
    (lambda n: n.update(white=[1e-4, 0.0, 1e-4, 1e-4]), "and positive"),
    (lambda n: n.update(white=[1e-4] * 3), "noise.white has shape \\(3,\\)"),
    (lambda n: n.update(white_sigma=None), "noise.white_sigma must be a"),
    (lambda n: n.update(random_walk=None), "noise.random_walk must be a"),
    (lambda n: n.update(random_walk=["1e-5"] * 4), "noise.random_walk must be a"),
    (lambda n: n.update(bias_instability=[True] * 4), "noise.bias_instability must be a"),
    (lambda n: n.update(rate_hz=0), "noise.rate_hz 0 must be a positive"),
    (lambda n: n.update(seconds=True), "noise.seconds True must be a positive"),
    (lambda n: n.update(seconds=1e300), "noise.seconds .* must be a positive"),
    (lambda n: n["units"].update(white="rad/s"), "noise.units"),
    (lambda n: n.update(extra=1), "noise must be null or an object with exactly"),
    (lambda n: n.pop("seconds"), "noise must be null or an object with exactly"),
])
def test_a_hostile_noise_section_is_refused(edit, problem):
    text = edited(noisy(), lambda d: edit(d["noise"]), True)
    with pytest.raises(CalibrationFileError, match=problem):
        loads(text)
    with pytest.raises(CalibrationFileError, match="noise must be null or an object"):
        loads(edited(noisy(), lambda d: d.update(noise=[1, 2]), True))
