"""`station demo --seed N` twice: the seeded parts repeat bit for bit (the unit, the mountings and
every sample the twin sends: a sample instant gets the same noise whatever the host's timing), and
the calibrations differ only by the samples the host-timed windows take, well within their
sigma (docs/cli.md, "station demo")."""

import numpy as np
import pytest
from scipy import stats

from station.commands.demo import run_demo
from station.files.session import Session
from station.protocols.rotary import RotarySettings
from station.reduce.rotary import position_windows
from station.reduce.timeline import sample_times

FAST = RotarySettings(rate=1.0, revolutions=1, static=3.0, rest=0.5, guard=0.5, steady=0.5)
POSITIONS = 8
RATE_HZ = 200.0  # the virtual bench's default IMU rate
FALSE_ALARM = 1e-3


@pytest.fixture(scope="module")
def twice(tmp_path_factory):
    """Two demo runs with seed 5: [(summary, {seq: counts} of the static windows)]."""
    runs = []
    for k in range(2):
        path = tmp_path_factory.mktemp(f"seed{k}") / "demo.h5"
        summary = run_demo(path, "serial", seed=5, positions=POSITIONS, speed=40.0,
                           settings=FAST)
        with Session.open(path) as s:
            data, events = s.stream("imu"), s.events()
        t = sample_times(data.seq, data.host_time, data.spec.rate_hz)
        still = np.zeros(len(t), bool)
        for w in position_windows(events).values():
            still |= (t >= w["static"][0]) & (t <= w["static"][1])
        runs.append((summary, dict(zip(data.seq[still].tolist(), data.counts[still],
                                       strict=True))))
    return runs


def test_the_same_sample_numbers_carry_the_same_counts(twice):
    (_, a), (_, b) = twice
    common = sorted(set(a) & set(b))
    # the windows start when the host polls, the positions on the technician's metronome: many
    # samples are common to both runs (54 to 80 % measured on a loaded host); at least a window's
    assert len(common) >= FAST.static * RATE_HZ, (len(common), len(a), len(b))
    assert all(np.array_equal(a[n], b[n]) for n in common)


def test_the_unit_and_its_truth_repeat(twice):
    (s1, _), (s2, _) = twice
    assert s1["scale_factors_true"] == s2["scale_factors_true"]
    assert [r["true"] for r in s1["axis_angles_deg"]] == [r["true"] for r in s2["axis_angles_deg"]]


def test_the_calibrations_differ_by_less_than_two_independent_runs_would(twice):
    """Two runs share most samples: their difference is at most that of two independent runs,
    sd sqrt(2) sigma; bounded two-sided at FALSE_ALARM over the 12 scale factors."""
    (s1, _), (s2, _) = twice
    k1, k2 = np.array(s1["scale_factors"]), np.array(s2["scale_factors"])
    sigma = np.array(s1["scale_factors_sigma"])
    limit = stats.norm.isf(FALSE_ALARM / 2 / len(k1)) * np.sqrt(2)
    assert np.all(np.abs(k1 - k2) < limit * sigma), (np.abs(k1 - k2) / sigma, limit)
