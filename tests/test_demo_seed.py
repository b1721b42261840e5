"""`station demo --seed N` twice: in lockstep time (the demo's default) the whole session repeats
bit for bit - the unit, the mountings, every sample and its host time, the windows the protocol
cut, the calibration - whatever the host's timing (docs/cli.md, "station demo")."""

import numpy as np
import pytest

from station.commands.demo import run_demo
from station.protocols.rotary import RotarySettings
from station.reduce.rotary import position_windows
from station.session import Session

FAST = RotarySettings(rate=1.0, revolutions=1, static=3.0, rest=0.5, guard=0.5, steady=0.5)
POSITIONS = 8


@pytest.fixture(scope="module")
def twice(tmp_path_factory):
    """Two demo runs with seed 5: [(summary, stream, windows)]."""
    runs = []
    for k in range(2):
        path = tmp_path_factory.mktemp(f"seed{k}") / "demo.h5"
        summary = run_demo(path, "serial", seed=5, positions=POSITIONS, settings=FAST)
        with Session.open(path) as s:
            runs.append((summary, s.stream("imu"), position_windows(s.events())))
    return runs


def test_every_sample_and_its_host_time_repeat(twice):
    (_, a, _), (_, b, _) = twice
    assert len(a.seq) > POSITIONS * FAST.static * 200
    for column in ("seq", "counts", "host_time"):
        assert np.array_equal(getattr(a, column), getattr(b, column)), column


def test_the_windows_repeat(twice):
    (_, _, a), (_, _, b) = twice
    assert a == b and len(a) == POSITIONS


def test_the_unit_its_truth_and_the_calibration_repeat(twice):
    (s1, _, _), (s2, _, _) = twice
    assert s1["speed"] is None  # lockstep time
    assert s1["scale_factors_true"] == s2["scale_factors_true"]
    for key in ("scale_factors", "scale_factors_sigma", "eps", "chi2_per_dof"):
        assert s1[key] == s2[key], key
