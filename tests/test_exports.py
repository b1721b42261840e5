"""`station export --to FORMAT` (issue 19, part 2): every export read back by a reader of its format
- imucal's own `load_calibration_info` and `calibrate`, pymavlink's parameter loader (MAVProxy's),
PyYAML (Kalibr's and ROS's YAML reader), a QGroundControl parameter file parser written here from
its documented layout - and the target tool's correction, written here from its documentation,
applied to simulated raw readings z = a^T v + b gives the vectors v of `Calibration.apply`."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_calfile import make

from station import cli
from station.calfiles.calfile import NoiseFigures, load
from station.errors import InputError
from station.exports.imu import Imu
from station.exports.imucal import imucal
from station.exports.kalibr import kalibr
from station.exports.ros import ros
from station.reduce.ferraris import read_recording

G = 9.80665
FERRARIS = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "imucal-ferraris"
# hand-made triads, columns = each sensor's sensitive vector in the unit's (nominal) frame
ACC_A = np.array([[1.012, 0.0021, -0.0017], [0.0013, 0.987, 0.0024], [-0.0008, 0.0015, 1.021]])
ACC_B = np.array([0.12, -0.31, 0.047])  # m/s^2
GYRO_A = np.array([[0.991, -0.0012, 0.0009], [0.0017, 1.006, -0.0021], [0.0011, 0.0006, 1.003]])
GYRO_B = np.array([0.0031, -0.0012, 0.0007])  # rad/s
RATE = 200.0
ACC_WHITE = np.array([1.8e-3, 2.1e-3, 2.6e-3])  # m/s^2 sqrt(s)
GYRO_WHITE = np.array([1.7e-4, 1.9e-4, 2.3e-4])  # rad/s sqrt(s)
ACC_WALK = np.array([4.0e-4, 4.4e-4, 5.1e-4])
GYRO_WALK = np.array([2.1e-5, 2.6e-5, 3.0e-5])


def triad_cal(a, bias, units, sensors, frame="nominal", **kw):
    """A triad's calibration file content with hand-made numbers."""
    return make(a=np.asarray(a, float), bias=np.asarray(bias, float), units=(units,) * 3,
                sensors=sensors, frame=frame, counts_per_unit=None, **kw)


def acc_cal(a=ACC_A, bias=ACC_B, **kw):
    return triad_cal(a, bias, "m/s^2", ("ax", "ay", "az"), magnitude=G, **kw)


def gyro_cal(a=GYRO_A, bias=GYRO_B, **kw):
    return triad_cal(a, bias, "rad/s", ("gx", "gy", "gz"), **kw)


def with_noise(cal, white, walk):
    """The calibration with noise figures (what `station noise` stores)."""
    noise = NoiseFigures(white=np.asarray(white), white_sigma=0.05 * np.asarray(white),
                         bias_instability=10 * np.asarray(white),
                         bias_instability_sigma=np.asarray(white),
                         random_walk=None if walk is None else np.asarray(walk),
                         random_walk_sigma=None if walk is None else 0.1 * np.asarray(walk),
                         rate_hz=RATE, seconds=7200.0)
    return dataclasses.replace(cal, noise=noise)


def readings(cal, scale, k=200, seed=3):
    """(v (k, 3), z (k, 3)): random stimuli up to `scale` and their readings z = a^T v + b."""
    v = np.random.default_rng(seed).uniform(-scale, scale, (k, 3))
    return v, v @ cal.a + cal.bias


def export(tmp_path, capsys, cals, *options):
    """Run `station export` on saved calibration files; (exit code, out path, summary or
    stderr)."""
    paths = []
    for i, cal in enumerate(cals):
        path = tmp_path / f"c{i}.cal.json"
        cal.save(path, overwrite=True)
        paths.append(str(path))
    argv = ["export", paths[0], *(["--gyro", paths[1]] if len(paths) > 1 else []), *options,
            "--json"]
    code = cli.main(argv)
    out, err = capsys.readouterr()
    return code, (json.loads(out) if code == 0 else err)


# imucal: its own reader and its own correction ------------------------------------------------

def test_imucal_loads_our_file_and_calibrates_to_our_vectors(tmp_path, capsys):
    from imucal import FerrarisCalibrationInfo
    from imucal.management import load_calibration_info

    acc, gyro = acc_cal(), gyro_cal()
    code, summary = export(tmp_path, capsys, [acc, gyro], "--to", "imucal", "--out",
                           str(tmp_path / "cal.json"))
    assert code == 0
    info = load_calibration_info(summary["out"])
    assert isinstance(info, FerrarisCalibrationInfo)
    v_acc, z_acc = readings(acc, 2 * G)
    v_gyr, z_gyr = readings(gyro, 5.0, seed=4)
    got_acc, got_gyr = info.calibrate(z_acc, z_gyr, "m/s^2", "rad/s")
    np.testing.assert_allclose(got_acc, acc.apply(z_acc.T).T, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got_gyr, gyro.apply(z_gyr.T).T, rtol=0, atol=1e-13)
    np.testing.assert_allclose(got_acc, v_acc, atol=1e-11)  # and the true stimuli
    assert np.all(info.K_ga == 0) and "K_ga" in " ".join(summary["notes"])


@pytest.mark.parametrize("files, words", [
    ("acc", "the gyroscope one is missing"),
    ("acc acc", "holds an accelerometer calibration"),
    ("gyro acc", "give the accelerometer calibration first"),
    ("canonical", "solve both against the unit's nominal layout"),
])
def test_imucal_refuses_what_it_cannot_hold(tmp_path, capsys, files, words):
    cals = {"acc": [acc_cal()], "acc acc": [acc_cal(), acc_cal()],
            "gyro acc": [gyro_cal(), acc_cal()],
            "canonical": [acc_cal(np.triu(ACC_A), frame="canonical"),
                          gyro_cal(np.triu(GYRO_A), frame="canonical")]}[files]
    code, err = export(tmp_path, capsys, cals, "--to", "imucal")
    assert code == 2 and words in err and len(err.strip().splitlines()) == 1


def carried_gyro(acc, **kw):
    """A gyro calibration carried through `acc`'s frame, with the record `station solve
    --stream GYRO` keeps of that accelerometer."""
    return gyro_cal(frame=acc.frame, fit={"method": "gravity carry (Tedaldi et al. 2014)"},
                    session={"accelerometer": {"scale_factors": acc.scale_factors.tolist(),
                                               "bias": acc.bias.tolist()}}, **kw)


def test_a_gyro_carried_by_the_accelerometer_shares_its_canonical_frame(tmp_path, capsys):
    from imucal.management import load_calibration_info

    acc = acc_cal(np.triu(ACC_A), frame="canonical")
    gyro = carried_gyro(acc)
    # carried through another accelerometer calibration: refused
    other = acc_cal(np.triu(ACC_A) * 1.001, frame="canonical")
    code, err = export(tmp_path, capsys, [other, gyro], "--to", "imucal")
    assert code == 2 and "carried through the frame of another accelerometer" in err
    code, summary = export(tmp_path, capsys, [acc, gyro], "--to", "imucal")
    assert code == 0 and summary["out"].endswith("c0.imucal.json")
    _, z = readings(gyro, 3.0)
    _, got = load_calibration_info(summary["out"]).calibrate(np.zeros_like(z), z, "m/s^2",
                                                             "rad/s")
    np.testing.assert_allclose(got, gyro.apply(z.T).T, atol=1e-13)


# ArduPilot: pymavlink's loader, ArduPilot's per-axis correction --------------------------------

AP_NAMES = {1: ("INS_ACCOFFS", "INS_ACCSCAL", "INS_GYROFFS"),  # ArduPilot's parameter docs
            2: ("INS_ACC2OFFS", "INS_ACC2SCAL", "INS_GYR2OFFS")}


def ardupilot_correct(params, z_acc, z_gyr, instance=1):
    """AP_InertialSensor_Backend: accel (raw - INS_ACCOFFS) * INS_ACCSCAL, gyro
    raw - INS_GYROFFS, per axis, in float32 (ArduPilot's parameters and arithmetic)."""
    f32 = np.float32
    offset, scale, gyro = AP_NAMES[instance]
    assert set(params) == {f"{name}_{k}" for name in AP_NAMES[instance] for k in "XYZ"}

    def vec(name):
        return np.array([params[f"{name}_{k}"] for k in "XYZ"], dtype=f32)

    acc = (z_acc.astype(f32) - vec(offset)) * vec(scale)
    gyr = z_gyr.astype(f32) - vec(gyro)
    return acc.astype(float), gyr.astype(float)


def load_mavproxy(path):
    """The parameters as MAVProxy's `param load` reads them (pymavlink.mavparm)."""
    from pymavlink.mavparm import MAVParmDict

    params = MAVParmDict()
    assert params.load(str(path))
    return params


def test_ardupilot_parameters_give_our_vectors_for_a_per_axis_unit(tmp_path, capsys):
    acc = acc_cal(np.diag(np.diag(ACC_A)))  # no cross-axis terms: exact in ArduPilot's model
    gyro = gyro_cal(np.eye(3))  # no scale error: ArduPilot has no gyro scale
    code, summary = export(tmp_path, capsys, [acc, gyro], "--to", "ardupilot")
    assert code == 0 and summary["out"].endswith(".ardupilot.param")
    params = load_mavproxy(summary["out"])
    _, z_acc = readings(acc, 2 * G)
    _, z_gyr = readings(gyro, 5.0)
    got_acc, got_gyr = ardupilot_correct(params, z_acc, z_gyr)
    # float32: 2^-24 relative of readings up to 2 g (|z| < 25 m/s^2), a few operations
    np.testing.assert_allclose(got_acc, acc.apply(z_acc.T).T, rtol=0, atol=25 * 2.0**-22)
    np.testing.assert_allclose(got_gyr, gyro.apply(z_gyr.T).T, rtol=0, atol=6 * 2.0**-22)


def test_ardupilot_states_what_its_per_axis_model_drops(tmp_path, capsys):
    acc, gyro = acc_cal(), gyro_cal()
    code, summary = export(tmp_path, capsys, [acc, gyro], "--to", "ardupilot", "--instance", "2")
    assert code == 0
    params = load_mavproxy(summary["out"])
    stated = {}
    for note in summary["notes"]:
        if "drops at most" in note:
            stated[note.split(":")[0]] = float(note.split("drops at most ")[1].split()[0])
    # the worst case over directions at 1 g / 1 rad/s, seen on many simulated unit stimuli
    rng = np.random.default_rng(5)
    u = rng.normal(size=(20000, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    got_acc, got_gyr = ardupilot_correct(params, G * u @ acc.a + acc.bias, u @ gyro.a + gyro.bias,
                                         instance=2)
    for kind, got, true in (("accelerometer", got_acc, G * u), ("gyroscope", got_gyr, u)):
        worst = np.max(np.linalg.norm(got - true, axis=1))
        # the statement is a bound (within float32 rounding) and tight: a direction within
        # arccos(0.97) of the worst one (+-) gives >= 0.97 of it; of 20000 uniform directions
        # about 20000 (1 - 0.97) = 600 fall there, so none with probability e^-600
        assert 0.97 * stated[kind] <= worst <= stated[kind] * 1.001 + 1e-5
    assert stated["gyroscope"] > 0.009  # the gyro's 0.9 % scale error is part of it


def test_ardupilot_refuses_large_cross_axis_terms_unless_forced(tmp_path, capsys):
    skewed = ACC_A + np.array([[0, 0.03, 0], [0, 0, 0], [0, 0, 0]])  # 3 % cross-axis
    code, err = export(tmp_path, capsys, [acc_cal(skewed)], "--to", "ardupilot")
    assert code == 2 and "drops up to" in err and "--force" in err
    code, summary = export(tmp_path, capsys, [acc_cal(skewed)], "--to", "ardupilot", "--force")
    assert code == 0 and any("drops at most 0.3" in n for n in summary["notes"])


@pytest.mark.parametrize("a, words", [
    (ACC_A[:, [1, 0, 2]], "points 90 deg away from the"),  # sensors in y, x, z order
    (ACC_A * [1, -1, 1], "points 180 deg away from the y axis"),  # y sensor reversed
])
def test_autopilots_refuse_a_frame_not_tied_to_the_sensor_axes(tmp_path, capsys, a, words):
    code, err = export(tmp_path, capsys, [acc_cal(a)], "--to", "ardupilot")
    assert code == 2 and words in err and "--nominal" in err


def test_ardupilot_refuses_readings_not_in_m_s2(tmp_path, capsys):
    code, err = export(tmp_path, capsys, [acc_cal(ACC_A / G, bias=ACC_B / G)], "--to",
                       "ardupilot", "--force")
    assert code == 2 and "INS_ACCOFFS/INS_ACCSCAL ranges" in err


# PX4: a QGroundControl parameter file parser from its documented layout ----------------------

def read_qgc_params(path):
    """QGroundControl's parameter file: '#' comment lines, then tab-separated rows
    vehicle-id, component-id, name, value, MAV_PARAM_TYPE (6 INT32, 9 REAL32)."""
    params = {}
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        vehicle, component, name, value, kind = line.split("\t")
        assert (int(vehicle), int(component)) == (1, 1) and kind in ("6", "9")
        assert name not in params and len(name) <= 16  # MAVLink param ids: 16 characters
        params[name] = int(value) if kind == "6" else float(np.float32(value))
    return params


def test_px4_parameters_give_our_vectors(tmp_path, capsys):
    acc = acc_cal(np.diag(np.diag(ACC_A)))
    gyro = gyro_cal(np.eye(3))
    code, summary = export(tmp_path, capsys, [acc, gyro], "--to", "px4", "--instance", "1",
                           "--acc-id", "2818058", "--gyro-id", "2818059")
    assert code == 0
    params = read_qgc_params(tmp_path / "c0.px4.params")
    assert params["CAL_ACC1_ID"] == 2818058 and params["CAL_GYRO1_ID"] == 2818059
    f32 = np.float32

    def vec(pattern):
        return np.array([params[pattern.format(k)] for k in "XYZ"], dtype=f32)

    _, z_acc = readings(acc, 2 * G)
    _, z_gyr = readings(gyro, 5.0)
    # calibration::Accelerometer::Correct / Gyroscope::Correct before the rotation
    got_acc = (z_acc.astype(f32) - vec("CAL_ACC1_{}OFF")) * vec("CAL_ACC1_{}SCALE")
    got_gyr = z_gyr.astype(f32) - vec("CAL_GYRO1_{}OFF")
    np.testing.assert_allclose(got_acc, acc.apply(z_acc.T).T, rtol=0, atol=25 * 2.0**-22)
    np.testing.assert_allclose(got_gyr, gyro.apply(z_gyr.T).T, rtol=0, atol=6 * 2.0**-22)


def test_px4_needs_the_device_id(tmp_path, capsys):
    code, err = export(tmp_path, capsys, [acc_cal()], "--to", "px4")
    assert code == 2 and "--acc-id" in err and "CAL_ACC0_ID" in err


# Kalibr: PyYAML (Kalibr's reader) and the scale-misalignment model -----------------------------

def noisy_pair(walk=True):
    return (with_noise(acc_cal(), ACC_WHITE, ACC_WALK if walk else None),
            with_noise(gyro_cal(), GYRO_WHITE, GYRO_WALK if walk else None))


def axis_figure(a, per_sensor):
    """Largest axis of per-sensor figures through the fusion: a triad's F is a^-T."""
    f = np.linalg.inv(a.T)
    return np.sqrt(np.max(np.diag(f @ np.diag(np.square(per_sensor)) @ f.T)))


def kalibr_statistics(doc):
    """kalibr_common/ConfigReader.py ImuParameters: its checks (rostopic a string, update_rate,
    densities and random walks > 0) and getAccelerometerStatistics / getGyroStatistics:
    (discrete sigma = density / sqrt(1 / update_rate), random walk, density) of each type."""
    assert isinstance(doc["rostopic"], str) and doc["update_rate"] > 0
    out = {}
    for kind in ("accelerometer", "gyroscope"):
        density, walk = doc[f"{kind}_noise_density"], doc[f"{kind}_random_walk"]
        assert density > 0 and walk > 0
        out[kind] = (density / np.sqrt(1.0 / doc["update_rate"]), walk, density)
    return out


def test_kalibr_and_ros_agree_on_the_sample_noise():
    """Kalibr's discrete sigma (its largest axis) is the largest standard deviation of the ROS
    covariance of one sample: the same figures, two formats."""
    acc, gyro = noisy_pair()
    stats = kalibr_statistics(yaml.safe_load(kalibr(Imu(acc, gyro)).text))
    params = yaml.safe_load(ros(Imu(acc, gyro)).text)["/**"]["ros__parameters"]
    for kind, key in (("accelerometer", "linear_acceleration_covariance"),
                      ("gyroscope", "angular_velocity_covariance")):
        largest = np.sqrt(np.max(np.diag(np.reshape(params[key], (3, 3)))))
        assert stats[kind][0] == pytest.approx(largest, rel=1e-12)


def test_kalibr_imu_yaml_has_the_noise_and_the_intrinsics():
    acc, gyro = noisy_pair()
    doc = yaml.safe_load(kalibr(Imu(acc, gyro), "/imu0").text)
    # ConfigReader.ImuParameters: numbers > 0, a topic, a rate
    expected = {"accelerometer_noise_density": axis_figure(ACC_A, ACC_WHITE),
                "accelerometer_random_walk": axis_figure(ACC_A, ACC_WALK),
                "gyroscope_noise_density": axis_figure(GYRO_A, GYRO_WHITE),
                "gyroscope_random_walk": axis_figure(GYRO_A, GYRO_WALK)}
    for key, value in expected.items():
        assert isinstance(doc[key], float) and doc[key] == pytest.approx(value, rel=1e-12)
    assert doc["rostopic"] == "/imu0" and doc["update_rate"] == RATE
    assert doc["model"] == "scale-misalignment"
    m_acc, m_gyr = np.array(doc["accelerometers"]["M"]), np.array(doc["gyroscopes"]["M"])
    c_gyro_i, a_g = np.array(doc["gyroscopes"]["C_gyro_i"]), np.array(doc["gyroscopes"]["A"])
    t_i_b = np.array(doc["T_i_b"])
    # the model's constraints: M lower triangular, C_gyro_i and T_i_b's block rotations
    assert np.all(np.triu(m_acc, 1) == 0) and np.all(np.triu(m_gyr, 1) == 0)
    for r in (c_gyro_i, t_i_b[:3, :3]):
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-14)
        assert np.linalg.det(r) > 0
    # IccScaledMisalignedImu: raw_acc = M a_i + b, raw_gyro = M C_gyro_i w_i + A a_i + b,
    # a_i = C_ib v (T_i_b); solved for v, it is our apply
    c_ib = t_i_b[:3, :3]
    _, z_acc = readings(acc, 2 * G)
    _, z_gyr = readings(gyro, 5.0)
    acc_i = np.linalg.solve(m_acc, (z_acc - acc.bias).T)
    w_i = c_gyro_i.T @ np.linalg.solve(m_gyr, (z_gyr - gyro.bias).T - a_g @ acc_i)
    np.testing.assert_allclose(c_ib.T @ acc_i, acc.apply(z_acc.T), atol=1e-12)
    np.testing.assert_allclose(c_ib.T @ w_i, gyro.apply(z_gyr.T), atol=1e-13)


def test_kalibr_in_the_canonical_frame_is_its_own_imu_frame():
    upper = np.triu(ACC_A)
    acc = with_noise(acc_cal(upper, frame="canonical"), ACC_WHITE, ACC_WALK)
    gyro = with_noise(carried_gyro(acc), GYRO_WHITE, GYRO_WALK)
    doc = yaml.safe_load(kalibr(Imu(acc, gyro), "/imu0", update_rate=400.0).text)
    np.testing.assert_allclose(np.array(doc["T_i_b"]), np.eye(4), atol=1e-15)
    np.testing.assert_allclose(np.array(doc["accelerometers"]["M"]), upper.T, rtol=1e-15)
    assert doc["update_rate"] == 400.0


def test_kalibr_refuses_missing_noise_figures(tmp_path, capsys):
    acc, gyro = noisy_pair(walk=False)
    with pytest.raises(InputError, match="no random walk figure.*station noise"):
        kalibr(Imu(acc, gyro))
    # a file without noise figures (what `station solve` writes today), on the command line
    code, err = export(tmp_path, capsys, [acc_cal(), gyro_cal()], "--to", "kalibr")
    assert code == 2 and "has no noise figures" in err and "station noise" in err


def test_noise_figures_of_another_shape_are_refused():
    acc, gyro = noisy_pair()
    bad = dataclasses.replace(gyro, noise=dataclasses.replace(gyro.noise, white=GYRO_WHITE[:2]))
    with pytest.raises(InputError, match="are not 3 finite numbers >= 0, one per sensor"):
        ros(Imu(acc, bad))


def test_kalibr_refuses_a_mirrored_gyro():
    acc, gyro = noisy_pair()
    mirrored = dataclasses.replace(gyro, a=-gyro.a)
    with pytest.raises(InputError, match="mirrored"):
        kalibr(Imu(acc, mirrored))


def random_triad(rng):
    """A triad in some frame: scale errors of a few %, axes a few degrees off, turned by a
    random rotation (det +1)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    q[:, 0] *= np.sign(np.linalg.det(q))
    return q @ (np.diag(rng.uniform(0.95, 1.05, 3)) + rng.normal(0, 0.03, (3, 3)))


def test_kalibr_and_imucal_are_exact_for_any_triads_in_one_frame():
    """50 random pairs of triads in one (nominal) frame, turned anyhow: Kalibr's model and
    imucal's `calibrate` give `Calibration.apply`'s vectors."""
    from imucal import CalibrationInfo

    rng = np.random.default_rng(8)
    for _ in range(50):
        acc = with_noise(acc_cal(random_triad(rng), rng.normal(0, 0.3, 3)), ACC_WHITE, ACC_WALK)
        gyro = with_noise(gyro_cal(random_triad(rng), rng.normal(0, 0.01, 3)), GYRO_WHITE,
                          GYRO_WALK)
        _, z_acc = readings(acc, 2 * G, k=20, seed=int(rng.integers(1 << 30)))
        _, z_gyr = readings(gyro, 5.0, k=20, seed=int(rng.integers(1 << 30)))
        doc = yaml.safe_load(kalibr(Imu(acc, gyro)).text)
        c_ib = np.array(doc["T_i_b"])[:3, :3]
        acc_i = np.linalg.solve(doc["accelerometers"]["M"], (z_acc - acc.bias).T)
        w_i = np.array(doc["gyroscopes"]["C_gyro_i"]).T @ np.linalg.solve(
            doc["gyroscopes"]["M"], (z_gyr - gyro.bias).T)
        np.testing.assert_allclose(c_ib.T @ acc_i, acc.apply(z_acc.T), atol=1e-11)
        np.testing.assert_allclose(c_ib.T @ w_i, gyro.apply(z_gyr.T), atol=1e-12)
        info = CalibrationInfo.from_json(imucal(Imu(acc, gyro)).text)
        got_acc, got_gyr = info.calibrate(z_acc, z_gyr, "m/s^2", "rad/s")
        np.testing.assert_allclose(got_acc, acc.apply(z_acc.T).T, atol=1e-11)
        np.testing.assert_allclose(got_gyr, gyro.apply(z_gyr.T).T, atol=1e-12)


# ROS: PyYAML, the covariance of fused samples ------------------------------------------------

def test_ros_covariances_are_those_of_fused_white_noise():
    acc, gyro = noisy_pair()
    doc = yaml.safe_load(ros(Imu(acc, gyro)).text)
    params = doc["/**"]["ros__parameters"]
    assert params["orientation_covariance"][0] == -1.0
    rng = np.random.default_rng(11)
    n = 40000
    for cal, key, white in ((acc, "linear_acceleration_covariance", ACC_WHITE),
                            (gyro, "angular_velocity_covariance", GYRO_WHITE)):
        cov = np.array(params[key], float).reshape(3, 3)  # row-major, message units squared
        # the fused samples of static white noise (per-sample sigma N sqrt(rate))
        z = cal.bias + rng.normal(size=(n, 3)) * white * np.sqrt(RATE)
        sample = np.cov(cal.apply(z.T))
        # a variance estimated from n samples has relative sigma sqrt(2/n): 5 sigma
        np.testing.assert_allclose(np.diag(cov), np.diag(sample), rtol=5 * np.sqrt(2 / n))
        np.testing.assert_allclose(cov, cov.T, rtol=0, atol=0)
        f = np.linalg.inv(cal.a.T)
        np.testing.assert_allclose(cov, f @ np.diag(white**2 * RATE) @ f.T, rtol=1e-12)


def test_ros_without_a_gyro_marks_no_estimate():
    acc, _ = noisy_pair()
    params = yaml.safe_load(ros(Imu(acc, None), rate_hz=100.0).text)["/**"]["ros__parameters"]
    assert params["angular_velocity_covariance"][0] == -1.0
    assert params["linear_acceleration_covariance"][0] > 0


# the command line ---------------------------------------------------------------------------

def test_c_header_by_either_option_is_the_same_file(tmp_path, capsys):
    cal = make()
    cal.save(tmp_path / "SN42.cal.json")
    assert cli.main(["export", str(tmp_path / "SN42.cal.json"), "--c-header",
                     str(tmp_path / "a.h")]) == 0
    assert cli.main(["export", str(tmp_path / "SN42.cal.json"), "--to", "c-header", "--out",
                     str(tmp_path / "b.h")]) == 0
    assert cli.main(["export", str(tmp_path / "SN42.cal.json"), "--to", "c-header"]) == 0
    text = (tmp_path / "a.h").read_text()
    assert text == (tmp_path / "b.h").read_text() == (tmp_path / "SN42.h").read_text()
    assert "IMU_CAL_FUSION[3][4]" in text


@pytest.mark.parametrize("fmt", ["ardupilot", "kalibr", "imucal"])
def test_a_redundant_array_is_refused_with_the_way_out(tmp_path, capsys, fmt):
    cals = [make(units=("m/s^2",) * 4)] + ([gyro_cal()] if fmt != "ardupilot" else [])
    code, err = export(tmp_path, capsys, cals, "--to", fmt)
    assert code == 2 and "has 4 sensors" in err and "--to c-header" in err


def test_a_magnetometer_is_refused(tmp_path, capsys):
    code, err = export(tmp_path, capsys, [make(units=("T",) * 4)], "--to", "ros")
    assert code == 2 and "magnetometer" in err


def test_existing_output_is_kept_unless_forced(tmp_path, capsys):
    (tmp_path / "c0.ardupilot.param").write_text("precious")
    code, err = export(tmp_path, capsys, [acc_cal()], "--to", "ardupilot")
    assert code == 2 and "exists" in err
    assert (tmp_path / "c0.ardupilot.param").read_text() == "precious"


def test_another_units_files_are_refused(tmp_path, capsys):
    code, err = export(tmp_path, capsys, [acc_cal(), gyro_cal(unit_serial="SN7")], "--to",
                       "imucal")
    assert code == 2 and "give two calibrations of one unit" in err


def test_calibration_files_still_load_after_export(tmp_path, capsys):
    cal = acc_cal()
    code, _ = export(tmp_path, capsys, [cal], "--to", "ardupilot")
    assert code == 0 and load(tmp_path / "c0.cal.json").unit_serial == cal.unit_serial


@pytest.mark.skipif(not FERRARIS.is_dir(), reason="real data (../shared) not available")
def test_imucals_recording_round_trips_through_imucal(tmp_path, capsys):
    """imucal's own continuous Ferraris recording (docs/realdata.md): import, solve the
    accelerometer on its faces and the gyro from the turns between them, export both to imucal;
    imucal's calibrate gives our vectors on all 10376 samples."""
    from imucal.management import load_calibration_info

    csv = FERRARIS / "example_ferraris_session.csv"
    h5, acc, gyro = tmp_path / "fer.h5", tmp_path / "fer.cal.json", tmp_path / "gyro.cal.json"
    for argv in (["import", "csv", h5, csv, "--no-time", "--fs", "102.4", "--stream",
                  "acc=acc_x,acc_y,acc_z", "--unit", "acc=m/s^2", "--stream",
                  "gyro=gyr_x,gyr_y,gyr_z", "--unit", "gyro=deg/s"],
                 ["solve", h5, "--magnitude", "9.81", "--faces", "--out", acc],
                 ["solve", h5, "--stream", "gyro", "--magnitude", "9.81", "--faces", "--out",
                  gyro],
                 ["export", acc, "--gyro", gyro, "--to", "imucal", "--out",
                  tmp_path / "imucal.json"]):
        assert cli.main([str(a) for a in argv]) == 0
    capsys.readouterr()
    rec = read_recording(csv)
    rates = np.radians(rec.gyro)  # the session holds the gyro in rad/s (SI inside)
    got_acc, got_gyr = load_calibration_info(tmp_path / "imucal.json").calibrate(
        rec.acc, rates, "m/s^2", "rad/s")
    np.testing.assert_allclose(got_acc, load(acc).apply(rec.acc.T).T, rtol=0, atol=1e-13)
    np.testing.assert_allclose(got_gyr, load(gyro).apply(rates.T).T, rtol=0, atol=1e-13)


def test_an_option_of_another_format_is_refused(tmp_path, capsys):
    code, err = export(tmp_path, capsys, [acc_cal()], "--to", "ardupilot", "--acc-id", "7")
    assert code == 2 and "--acc-id applies to --to px4, not to ardupilot" in err


def test_a_suspect_calibration_is_said_so(tmp_path, capsys):
    cal = acc_cal(fit={"method": "ml", "status": "suspect", "status_reasons": ["chi2 too large"]})
    code, summary = export(tmp_path, capsys, [cal], "--to", "ardupilot")
    assert code == 0 and "m/s^2 calibration marked suspect: chi2 too large" in summary["notes"]
