"""Replay of the hand protocols' sessions (right-angle iron, free-static) recorded on the virtual
hand bench: the defaults reproduce the stored `results/live` bit-identically, trimming moves the
readings as the noise says and shortens the windows, a subset of poses carries its constraints,
the CLI, and the errors with their advice."""

import json
import shutil

import numpy as np
import pytest
from results import assert_same
from scipy import stats

from station.cli import main
from station.errors import CalibrationInputError
from station.replay import ReplaySettings, replay
from station.session import Session, SessionWriter, StreamSpec
from station.twin.hand_bench import record_iron_session, record_static_session

RECORDINGS = {
    "iron": lambda path: record_iron_session(path, seed=2, mountings=2),
    "static": lambda path: record_static_session(path, seed=5, poses=12),
}

FALSE_ALARM = 1e-3
"""Chance that a statistical test below fails on a correct replay (two-sided)."""


@pytest.fixture(scope="module", params=sorted(RECORDINGS))
def session(request, tmp_path_factory):
    """(protocol, path) of a session recorded once per module on the hand bench at 40x: iron with
    two mountings (12 poses, ACC4), or free-static with 12 poses (triad)."""
    path = tmp_path_factory.mktemp(request.param) / f"{request.param}.h5"
    RECORDINGS[request.param](path)
    return request.param, path


@pytest.fixture
def copy(session, tmp_path):
    """A writable copy of the session (the CLI stores results in it)."""
    target = tmp_path / "copy.h5"
    shutil.copy(session[1], target)
    return target


def live(path):
    with Session.open(path) as f:
        return f.results("live")


def test_default_replay_reproduces_the_live_results_bit_identically(session):
    _, path = session
    readings, result = replay(path)
    stored = live(path)
    assert np.array_equal(readings.M, stored.readings)
    assert np.array_equal(readings.sigma, stored.readings_sigma)
    assert result.frame == "nominal"
    assert_same(result, stored.calibration)  # a, bias, ... every field


def test_trim_shortens_the_windows_and_moves_the_readings_by_the_noise(session):
    """Trimming k samples at both ends of a window of N white-noise samples moves its mean by
    d = mean_N - mean_(N-2k), Var d = s^2 (1/(N-2k) - 1/N) = sigma^2 (N/(N-2k) - 1) (sigma = the
    standard error of the N-sample mean): the sum of (d / sd d)^2 over the m x P readings is
    chi2(m P); two-sided, so an ineffective trim (d = 0) fails as well as a wrong one."""
    _, path = session
    full, _ = replay(path)
    trim = 0.5
    trimmed, result = replay(path, ReplaySettings(trim=trim))
    np.testing.assert_allclose(np.diff(full.windows) - np.diff(trimmed.windows), 2 * trim,
                               atol=1e-9)
    rate = 200.0  # the bench's sample rate
    n = np.rint(np.diff(full.windows)[:, 0] * rate) + 1
    kept = np.rint(np.diff(trimmed.windows)[:, 0] * rate) + 1
    assert np.all(kept == n - 2 * trim * rate)
    z = (trimmed.M - full.M) / (full.sigma * np.sqrt(n / kept - 1))
    chi2 = float(np.sum(z**2))
    law = stats.chi2(z.size)
    assert law.ppf(FALSE_ALARM / 2) < chi2 < law.isf(FALSE_ALARM / 2), (chi2, z.size)
    assert result.frame == "nominal" and trimmed.M.shape == full.M.shape


@pytest.mark.parametrize("keep", [(0, 1, 2, 3, 4, 6, 7, 8, 9, 10),
                                  (11, 4, 2, 7, 9, 0, 5, 3, 10, 1)])
def test_a_subset_of_poses_gives_its_columns_and_constraints(session, keep):
    protocol, path = session
    full, _ = replay(path)
    readings, result = replay(path, ReplaySettings(positions=keep))
    assert readings.M.shape == (full.M.shape[0], len(keep))
    assert np.array_equal(readings.M, full.M[:, list(keep)])
    assert np.array_equal(readings.windows, full.windows[list(keep)])
    assert result.a.shape == (3, full.M.shape[0])
    if protocol == "iron":  # the faces' constraints follow the subset (Eq. 15)
        sub, whole = readings.constraints(), full.constraints()
        h = dict(zip(zip(whole.j.tolist(), whole.k.tolist(), strict=True), whole.h, strict=True))
        for j, k, value in zip(sub.j, sub.k, sub.h, strict=True):
            a, b = sorted((keep[j], keep[k]))
            assert value == h[a, b], (j, k)
        assert len(sub.h) < len(whole.h)


def test_station_replay_command_stores_replay_1_and_prints_json(copy, capsys):
    assert main(["replay", str(copy), "--store", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["results"] == "replay-1" and summary["positions"] == 12
    assert summary["frame"] == "nominal"
    with Session.open(copy) as f:
        assert set(f.result_names) == {"live", "replay-1"}
        stored, again = f.results("live"), f.results("replay-1")
    assert np.array_equal(again.readings, stored.readings)
    assert_same(again.calibration, stored.calibration)
    assert main(["replay", str(copy), "--positions", "1-6,9-12", "--trim", "0.5"]) == 0
    assert "10 positions" in capsys.readouterr().out


def test_raw_replay_refuses_a_hand_session(copy, tmp_path, capsys):
    assert main(["replay", str(copy), "--raw", str(tmp_path / "again.h5")]) == 2
    assert "raw replay re-records rotary sessions only" in capsys.readouterr().err
    assert not (tmp_path / "again.h5").exists()


def test_replay_errors_say_what_to_do(session):
    protocol, path = session
    with pytest.raises(ValueError, match=r"positions \[13\] were not completed .* choose among"):
        replay(path, ReplaySettings(positions=(0, 12)))
    with pytest.raises(CalibrationInputError, match="fewer than 2 samples") as error:
        replay(path, ReplaySettings(trim=2.5))  # 5 s windows
    assert error.value.advice == "Trim less than half of the shortest still window."
    few, problem = {"iron": ((0, 1, 2), "at least 4 positions"),
                    "static": ((0, 1, 2, 3, 4), "an ellipsoid fit needs at least 9")}[protocol]
    with pytest.raises(CalibrationInputError, match=problem) as error:
        replay(path, ReplaySettings(positions=few))
    assert error.value.advice.startswith("Record")  # more poses
    with pytest.raises(CalibrationInputError, match="needs unbiased readings"):
        replay(path, ReplaySettings(method="pca"))


def test_replay_refuses_an_unknown_protocol(tmp_path):
    path = tmp_path / "other.h5"
    spec = StreamSpec(["a1", "a2", "a3"], ["m/s^2"] * 3, 1e4, 100.0, "int64")
    with SessionWriter.create(path, {"protocol": "other", "unit_serial": "T"}, {"imu": spec}):
        pass
    with pytest.raises(ValueError, match="'other' session; replay reduces rotary, iron, static, "
                                         "import"):
        replay(path)
    assert main(["replay", str(path)]) == 2


def test_station_diagnose_reads_the_recorded_hand_session(session, tmp_path, capsys):
    """An effect-free hand-bench session (iron or free static, recorded through the serial driver)
    goes to the free-static diagnosis: every still pose found, nothing named at a family-wise
    false alarm of FALSE_ALARM, the white-noise check holding."""
    _, path = session
    with Session.open(path) as f:
        poses = len(f.results("live").readings[0])
    assert main(["diagnose", str(path), "--json", "--alpha", str(FALSE_ALARM)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["protocol"] == "free_static" and doc["gyro_channels"] == 0
    assert doc["intervals"] >= poses  # the still poses (and the rest before the first turn)
    assert doc["effects"] == [], doc["steps"][0]["evidence"]
    assert "rate_error" in doc["not_testable"]
