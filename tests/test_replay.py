"""Replay of recorded rotary sessions: the committed example sessions reproduce their stored results
exactly, other settings give other results under new names, the CLI, and the raw stream sent again
through the serial pty twin reduces to the same readings as the original recording."""

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from results import assert_same

from station.cli import main
from station.reduce.rotary import rotary_readings
from station.replay import ReplaySettings, replay, replay_into, replay_raw, stored_settings
from station.session import Session

SESSIONS = Path(__file__).resolve().parent.parent / "sessions"


def _protocol(path) -> str:
    with Session.open(path) as f:
        return f.protocol


EXAMPLES = sorted(p for p in SESSIONS.glob("*.h5") if _protocol(p) == "rotary")


def stored(path, name="rotary"):
    with Session.open(path) as f:
        return f.results(name)


@pytest.fixture
def copy(tmp_path):
    """A writable copy of the first example session."""
    target = tmp_path / "copy.h5"
    shutil.copy(EXAMPLES[0], target)
    return target


def test_there_are_small_committed_example_sessions():
    assert EXAMPLES
    for path in EXAMPLES:
        assert path.stat().st_size < 2e6
        with Session.open(path) as f:
            assert f.closed_cleanly and f.protocol == "rotary" and "rotary" in f.result_names


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_replay_of_an_example_session_reproduces_its_stored_results_exactly(path):
    reduced, result = replay(path)
    s = stored(path)
    assert np.array_equal(reduced.M, s.readings)  # the reduction is exact on any machine
    assert np.array_equal(reduced.sigma, s.readings_sigma)
    # solved by another numpy/LAPACK build: last-bit differences (seen 2e-16 absolute, on
    # residuals of 1e-4 that are differences of readings near 1; 3e-9 relative on a 1-sigma
    # from the gauge pseudo-inverse). The file predates parameter_covariance: its diagonal must
    # give the stored 1-sigma of a. It predates the start and the white-noise figure too; its
    # readings need no per-pose term, so the replayed total figure is the stored one.
    assert s.calibration.parameter_covariance is None and s.calibration.start is None
    assert result.start == "closed form" and result.pose_sigma == 0.0
    later = ("parameter_covariance", "start", "pose_sigma", "a_sigma_white",
             "scale_factors_sigma_white", "axis_angles_sigma_white", "bias_sigma_white")
    assert_same(dataclasses.replace(result, **dict.fromkeys(later)), s.calibration, rtol=1e-6)
    np.testing.assert_allclose(np.sqrt(np.diag(result.parameter_covariance)),
                               s.calibration.a_sigma.ravel(), rtol=1e-6,
                               atol=1e-6 * s.calibration.a_sigma.max())  # zeros of Eq. (19)


def test_other_settings_give_other_numbers_under_a_new_name(copy):
    original = stored(copy)
    settings = ReplaySettings(trim=0.5, positions=tuple(range(10)), refine=False)
    reduced, result = replay_into(copy, "trimmed", settings)
    again, again_result = replay(copy, settings)  # identical settings, identical numbers
    assert np.array_equal(reduced.M, again.M) and np.array_equal(result.a, again_result.a)
    with Session.open(copy) as f:
        assert set(f.result_names) == {"rotary", "trimmed"}
        kept, new = f.results("rotary"), f.results("trimmed")
    assert np.array_equal(kept.readings, original.readings)  # stored results never change
    assert new.readings.shape == (12, 10) and new.calibration.method == "pca"
    # trimming 0.5 s of each window keeps the readings within their standard error
    assert np.all(np.abs(new.readings - original.readings[:, :10])
                  < 4 * original.readings_sigma[:, :10])
    assert not np.array_equal(new.readings, original.readings[:, :10])
    with pytest.raises(ValueError, match="exists"):
        replay_into(copy, "trimmed", settings)


def test_the_settings_are_stored_with_the_results_and_reproduce_them(copy, capsys):
    settings = ReplaySettings(trim=0.25, positions=(0, 2, 3, 4, 5, 6, 7, 9), refine=False)
    replay_into(copy, "mine", settings)
    assert stored_settings(copy, "mine") == settings
    with Session.open(copy) as f:
        assert f.results("mine").settings["positions"] == [0, 2, 3, 4, 5, 6, 7, 9]
        assert f.results("rotary").settings is None  # the recording's own results
    with pytest.raises(ValueError, match="holds no replay settings"):
        stored_settings(copy, "rotary")
    # --like: the stored settings reproduce the stored results bit for bit ...
    assert main(["replay", str(copy), "--like", "mine", "--store", "--json"]) == 0
    same = json.loads(capsys.readouterr().out)
    assert same["settings"] == {**dataclasses.asdict(settings),
                                "positions": list(settings.positions)}
    # ... and the options given change them (here: no trim)
    assert main(["replay", str(copy), "--like", "mine", "--trim", "0", "--store", "--json"]) == 0
    untrimmed = json.loads(capsys.readouterr().out)
    assert untrimmed["settings"] == {**same["settings"], "trim": 0.0}
    with Session.open(copy) as f:
        mine, like, full = (f.results(n) for n in ("mine", same["results"], untrimmed["results"]))
        original = f.results("rotary")
    assert np.array_equal(mine.readings, like.readings)
    assert_same(like.calibration, mine.calibration)
    assert np.array_equal(full.readings, original.readings[:, list(settings.positions)])


def test_replay_refuses_bad_settings(copy):
    with pytest.raises(ValueError, match="unknown solver method"):
        ReplaySettings(method="magic")
    with pytest.raises(ValueError, match="positions \\[13\\] were not completed"):
        replay(copy, ReplaySettings(positions=(0, 12)))
    with pytest.raises(ValueError, match="trim"):
        ReplaySettings(trim=-1.0)


def test_station_replay_command(copy, capsys):
    with Session.open(copy) as f:
        before = set(f.result_names)
    assert main(["replay", str(copy)]) == 0  # prints only: the recording stays as it was
    assert "not stored" in capsys.readouterr().out
    with Session.open(copy) as f:
        assert set(f.result_names) == before
    assert main(["replay", str(copy), "--positions", "1-8,11", "--store", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["results"] == "replay-1" and summary["positions"] == 9
    assert main(["replay", str(copy), "--method", "ellipsoid"]) == 2
    assert "ellipsoid fit is for a triad" in capsys.readouterr().err
    with Session.open(copy) as f:
        assert set(f.result_names) == {"rotary", "replay-1"}
        assert np.array_equal(f.results("replay-1").readings,
                              f.results("rotary").readings[:, [*range(8), 10]])


def test_raw_replay_through_the_serial_twin_gives_the_same_readings(tmp_path):
    out = tmp_path / "again.h5"
    replay_raw(EXAMPLES[0], out, speed=200.0)
    with Session.open(EXAMPLES[0]) as a, Session.open(out) as b:
        first, again = a.stream("imu"), b.stream("imu")
        reduced, reduced_again = rotary_readings(a), rotary_readings(b)
        assert b.closed_cleanly and b.metadata["replay_of"] == str(EXAMPLES[0])
    k = len(first.seq)
    assert len(again.seq) >= k and np.all(np.diff(again.seq) == 1)
    assert np.array_equal(again.counts[:k], first.counts)  # lossless over the wire
    assert np.allclose(np.diff(again.device_time[:k]), np.diff(first.device_time), atol=2e-6)
    assert np.array_equal(reduced_again.M, reduced.M)
    assert np.array_equal(reduced_again.sigma, reduced.sigma)
    with pytest.raises(FileExistsError, match="exists"):
        replay_raw(EXAMPLES[0], out)
