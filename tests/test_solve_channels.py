"""`station solve --channels` / `station replay --channels`: one IMU of an array recorded as one
stream, calibrated from the command line (issue 14: the per-IMU path had no CLI). A simulated
two-triad array (the second triad a known linear image of the first plus its own noise), each
triad against its own truth; the real 8-IMU array against the API path of bench/mimu4444.py;
the refusals."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from hand import A_TRUE, B_TRUE, FS, hand_session

from station.calfiles.calfile import load
from station.cli import main
from station.imports.recordings import import_binary
from station.session import Session

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
if not REAL.exists():
    REAL = Path("/work/shared/data/real")
MIMU = REAL / "mimu4444-array"

C = np.array([[0.97, 0.03, -0.01], [-0.02, 1.04, 0.02], [0.01, -0.03, 0.99]])
"""The second triad's readings are C times the first's plus D (and noise of its own): its truth is
C A_TRUE, C B_TRUE + D."""
D = np.array([-0.2, 0.1, 0.3])


def station(capsys, *argv) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of one `station` command, run in this process."""
    capsys.readouterr()
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # refused by the argument parser
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def array_h5(tmp_path_factory):
    """An imported two-triad array: channels acc1..acc6 of one accelerometer stream."""
    x, _ = hand_session(seed=5)
    rng = np.random.default_rng(55)
    second = x[:, :3] @ C.T + D + 0.01 * rng.standard_normal((len(x), 3))
    tmp = tmp_path_factory.mktemp("array")
    path = tmp / "array.csv"
    with open(path, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["t", "ax", "ay", "az", "bx", "by", "bz", "gx", "gy", "gz"])
        out.writerows(np.column_stack([np.arange(len(x)) / FS, x[:, :3], second, x[:, 3:]])
                      .round(7).tolist())
    h5 = tmp / "array.h5"
    assert main(["import", "csv", str(h5), str(path), "--time", "t", "--stream",
                 "acc=ax,ay,az,bx,by,bz", "--unit", "acc=m/s^2", "--stream", "gyro=gx,gy,gz",
                 "--unit", "gyro=rad/s"]) == 0
    return h5


def within(cal, a, b) -> None:
    """The calibration's scale factors (row norms of a) and biases within 4 sigma of the truth (12
    normal values: a false failure has probability 8e-4)."""
    z_scale = (cal.scale_factors - np.linalg.norm(a, axis=1)) / cal.scale_factors_sigma
    z_bias = (cal.bias - b) / cal.bias_sigma
    assert np.all(np.abs(z_scale) < 4) and np.all(np.abs(z_bias) < 4), (z_scale, z_bias)


def test_each_triad_of_an_array_is_calibrated_against_its_own_truth(array_h5, tmp_path, capsys):
    for names, a, b in ((("acc1", "acc2", "acc3"), A_TRUE, B_TRUE),
                        (("acc4", "acc5", "acc6"), C @ A_TRUE, C @ B_TRUE + D)):
        out = tmp_path / f"{names[0]}.cal.json"
        code, text, err = station(capsys, "solve", array_h5, "--channels", ",".join(names),
                                  "--out", out, "--json")
        assert code == 0, err
        cal = load(json.loads(text)["calibration"])
        assert cal.sensors == names
        within(cal, a, b)
    # the order given is the order calibrated
    code, text, _ = station(capsys, "solve", array_h5, "--channels", "acc6,acc4,acc5", "--out",
                            tmp_path / "r.cal.json", "--json")
    cal = load(json.loads(text)["calibration"])
    assert code == 0 and cal.sensors == ("acc6", "acc4", "acc5")
    within(cal, (C @ A_TRUE)[[2, 0, 1]], (C @ B_TRUE + D)[[2, 0, 1]])


def test_replay_stores_the_channels_and_like_reproduces_them(array_h5, capsys):
    code, _, err = station(capsys, "replay", array_h5, "--channels", "acc4,acc5,acc6",
                           "--name", "second")
    assert code == 0, err
    code, _, err = station(capsys, "replay", array_h5, "--like", "second", "--name", "again")
    assert code == 0, err
    with Session.open(array_h5) as s:
        first, again = s.results("second"), s.results("again")
        acc = s.specs["acc"].channels
    assert [acc[i] for i in first.channels] == ["acc4", "acc5", "acc6"]
    assert again.settings == first.settings and again.channels == first.channels
    np.testing.assert_array_equal(again.readings, first.readings)
    np.testing.assert_array_equal(again.calibration.a, first.calibration.a)


@pytest.mark.parametrize("channels, words", [
    ("acc1,acc2,accX", "no calibrated channel 'accX'"),
    ("acc1,acc2", "at least 3"),
    ("acc1,,acc2", "separated by commas"),
    ("acc1,acc1,acc2", "distinct"),
])
def test_bad_channels_are_refused_with_the_names_to_choose(array_h5, tmp_path, capsys, channels,
                                                            words):
    code, _, err = station(capsys, "solve", array_h5, "--channels", channels, "--out",
                           tmp_path / "x.cal.json")
    assert code == 2 and words in err, err
    assert not (tmp_path / "x.cal.json").exists()


def test_a_carried_gyro_triad_is_calibrated_whole(array_h5, tmp_path, capsys):
    code, _, err = station(capsys, "solve", array_h5, "--stream", "gyro", "--channels",
                           "gyro1,gyro2,gyro3", "--out", tmp_path / "g.cal.json")
    assert code == 2 and "leave --channels out" in err, err


@pytest.mark.skipif(not MIMU.is_dir(), reason="real data (../shared) not available")
def test_one_imu_of_the_real_array_matches_the_api_path(tmp_path, capsys):
    """The 8-IMU array's first recording: IMU 3's triad through `station solve --channels`
    equals the calibration of the same rows of the imported readings (bench/mimu4444.py's path)."""
    from station.reduce.imported import imported_readings
    from station.solve.still import calibrate_still

    h5 = import_binary(tmp_path / "exp_1.h5", MIMU / "exp_1.bin", "mimu4444")
    names = ("imu3_ax", "imu3_ay", "imu3_az")
    code, text, err = station(capsys, "solve", h5, "--magnitude", 9.81, "--channels",
                              ",".join(names), "--accept-suspect", "--json")
    assert code in (0, 1), err
    cal = load(json.loads(text)["calibration"])
    with Session.open(h5) as s:
        readings = imported_readings(s, "imu")
    api = calibrate_still(readings.sensors([9, 10, 11]), 9.81)
    assert cal.sensors == names
    np.testing.assert_allclose(cal.scale_factors, api.scale_factors, rtol=1e-9)
    np.testing.assert_allclose(cal.bias, api.bias, rtol=1e-9, atol=1e-12)
