"""Gyro calibration from hand turns between still poses (station.solve.gyro_carry): on simulated
recordings whose gyro sees the turns, the sensitivity is recovered within its stated sigma and the
carried gravity lands where the accelerometer measures it."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from station.errors import CalibrationInputError
from station.sim.static import attitude_path
from station.solve.gyro_carry import calibrate_carry

FS = 100.0
G = 9.81


def hand_recording(seed: int, a_true, poses: int = 24, acc_noise: float = 0.01,
                   gyro_noise: float = 0.003, bias=(0.02, -0.01, 0.015), axis=None, rot=None):
    """(gyro (K, 3), acc (K, 3), still intervals): poses held 3 s, turns of 2 s between them
    (the poses' attitudes `rot`, default random).
    The attitude maps world vectors into the unit frame; the body rate of step k is
    rotvec(R_k R_{k+1}^-1) fs, so that `carry_gravity`'s C_{k+1} = C_k exp([w/fs]x) holds."""
    rng = np.random.default_rng(seed)
    if rot is None and axis is None:
        rot = Rotation.random(poses, random_state=rng)
    elif rot is None:  # every pose a turn about one body axis: the gyro is not determined
        rot = Rotation.from_rotvec(np.outer(rng.uniform(-np.pi, np.pi, poses), axis))
    _, att, still = attitude_path(rot, 3.0, 2.0, FS)
    omega = (att[:-1] * att[1:].inv()).as_rotvec() * FS
    omega = np.vstack([omega, omega[-1:]])
    acc = G * att.apply([0.0, 0.0, 1.0]) + acc_noise * rng.standard_normal((len(att), 3))
    gyro = omega @ np.asarray(a_true) + np.asarray(bias) \
        + gyro_noise * rng.standard_normal((len(att), 3))  # rows: z^T = w^T a + b^T
    return gyro, acc, still


def true_sensitivity(seed: int) -> np.ndarray:
    """A gyro triad 3 % off in scale, about 1 deg misaligned."""
    rng = np.random.default_rng(1000 + seed)
    return np.diag(1 + 0.03 * rng.standard_normal(3)) + 0.02 * rng.standard_normal((3, 3))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_sensitivity_is_recovered_within_its_sigma(seed):
    a_true = true_sensitivity(seed)
    gyro, acc, still = hand_recording(seed, a_true)
    cal = calibrate_carry(gyro, FS, acc, still)
    z = (cal.a - a_true) / cal.a_sigma
    assert np.max(np.abs(z)) < 4.5, z  # 9 entries: |z| < 4.5 fails with p ~ 6e-5
    assert np.sqrt(np.mean(z ** 2)) < 2.0  # the stated sigma is not tiny
    k = np.linalg.norm(a_true, axis=0)
    assert np.all(np.abs(cal.scale_factors - k) < 4.5 * cal.scale_factors_sigma)
    assert np.median(cal.errors_after_deg) < 0.25 * np.median(cal.errors_before_deg)


def test_the_bias_is_the_still_mean():
    a_true = true_sensitivity(4)
    gyro, acc, still = hand_recording(4, a_true, gyro_noise=0.0)
    cal = calibrate_carry(gyro, FS, acc, still)
    np.testing.assert_allclose(cal.bias, [0.02, -0.01, 0.015], atol=1e-12)


def test_turns_about_one_axis_are_refused_by_name():
    gyro, acc, still = hand_recording(5, np.eye(3), axis=[1.0, 0.0, 0.0])
    with pytest.raises(CalibrationInputError, match="turns|axis"):
        calibrate_carry(gyro, FS, acc, still)


def test_too_few_turns_are_refused():
    gyro, acc, still = hand_recording(6, np.eye(3), poses=4)
    with pytest.raises(CalibrationInputError, match="at least five"):
        calibrate_carry(gyro, FS, acc, still)


# ------------------------------------------------------------------------------ command line

COUNTS = 4000.0  # raw counts per rad/s of the simulated gyro (mid-scale offset 32768)


def import_turned(capsys, tmp_path, a_true, poses: int = 24, gyro: bool = True,
                  acc: bool = True, rot=None) -> Path:
    """A simulated hand recording imported by `station import csv` (accelerometer in m/s^2, gyro
    in raw counts, counts:rad/s without a nominal scale), as a session file."""
    from test_import_solve import station

    rates, f, _ = hand_recording(11, a_true, poses=poses, rot=rot)
    t = np.arange(len(f)) / FS
    table = np.column_stack([t, f, np.round(COUNTS * rates + 32768.0)])  # 16-bit counts
    path = tmp_path / "turned.csv"
    np.savetxt(path, table, delimiter=",", header="t,ax,ay,az,gx,gy,gz", comments="")
    args = ["import", "csv", tmp_path / "turned.h5", path, "--time", "t"]
    if acc:
        args += ["--stream", "acc=ax,ay,az", "--unit", "acc=m/s^2"]
    if gyro:
        args += ["--stream", "gyro=gx,gy,gz", "--unit", "gyro=counts:rad/s"]
    code, _ = station(capsys, *args)
    assert code == 0
    return tmp_path / "turned.h5"


def test_station_solve_calibrates_a_gyro_stream_from_the_turns(tmp_path, capsys):
    import json

    from test_import_solve import station

    from station.calfiles.calfile import load

    a_true = true_sensitivity(7)
    h5 = import_turned(capsys, tmp_path, a_true)
    code, out = station(capsys, "solve", h5, "--stream", "gyro", "--magnitude", G, "--json")
    assert code == 0
    summary = json.loads(out)
    assert summary["poses"] == 24 and 5 <= summary["positions"] <= 23  # turns of > 30 deg
    cal = load(summary["calibration"])
    assert cal.sensors == ("gyro1", "gyro2", "gyro3")  # readings in counts of a rate (rad/s)
    assert cal.units == ("counts",) * 3 and cal.quantity == "rad/s"
    assert "accelerometer's" in cal.session["frame"] and cal.session["accelerometer"]["stream"] \
        == "acc"
    # raw counts, no nominal scale given: the scale factors (counts per rad/s) within 4.5 sigma
    k = COUNTS * np.linalg.norm(a_true, axis=0)
    z = (cal.scale_factors - k) / cal.scale_factors_sigma
    assert np.all(np.abs(z) < 4.5), z  # 3 normal errors: fails with p ~ 2e-5
    assert np.all(np.abs(cal.bias - 32768.0 - COUNTS * np.array([0.02, -0.01, 0.015]))
                  < 4.5 * cal.bias_sigma)
    # station apply reads the gyro stream the file names: rad/s, still means near zero
    code, _ = station(capsys, "apply", summary["calibration"], h5, "--out", tmp_path / "w.csv")
    assert code == 0
    w = np.loadtxt(tmp_path / "w.csv", delimiter=",", skiprows=1)[:, 1:]
    assert np.abs(w[:200].mean(axis=0)).max() < 0.003  # the first pose: 3 s of noise 0.003


def test_a_gyro_without_an_accelerometer_or_turns_is_refused_by_name(tmp_path, capsys):
    from test_import_solve import station_with_errors

    h5 = import_turned(capsys, tmp_path, np.eye(3), acc=False)
    code, _, err = station_with_errors(capsys, "solve", h5, "--stream", "gyro")
    assert code == 2 and "m/s^2 are none" in err and "Import the accelerometer" in err
    few = tmp_path / "few"
    few.mkdir()
    h5 = import_turned(capsys, few, np.eye(3), rot=clustered_poses())
    code, _, err = station_with_errors(capsys, "solve", h5, "--stream", "gyro")
    assert code == 2 and "only 3 turns" in err and "at least five" in err
    code, _, err = station_with_errors(capsys, "solve", h5, "--stream", "gyro", "--store")
    assert code == 2 and "leave out --store" in err


def clustered_poses() -> Rotation:
    """12 attitudes in 4 clusters: within a cluster each pose tilted 20 deg from the one before
    (gravity turns by less than 30 deg: no turn), between clusters a random turn (3 turns)."""
    rng = np.random.default_rng(12)
    tilt = Rotation.from_rotvec(np.radians(20.0) * np.array([[1.0, 0, 0], [0, 1.0, 0]]))
    poses = []
    for base in Rotation.random(4, random_state=rng):
        poses += [base, tilt[0] * base, tilt[1] * tilt[0] * base]
    return Rotation.concatenate(poses)
