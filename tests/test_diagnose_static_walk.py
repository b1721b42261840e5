"""Issue 32, a free-static drift or the unit's bias random walk (station.diagnose.static_walk):
without the unit's noise figures a walk of realistic size reads as a warm-up drift, and a session
of 20 poses cannot tell the two apart. A named drift that a free walk explains as well is said to
be maybe the walk, and the calibration is not corrected for it; with the unit's figures the walk
is in the noise model and nothing is named; a strong warm-up is no walk."""

from dataclasses import replace

import numpy as np
import pytest

from station.diagnose import static_walk
from station.diagnose.static import StaticData, base, diagnose_static, fit, from_arrays
from station.model.effects import parse_all
from station.report.diagnosis import static_to_dict as to_dict
from station.report.diagnosis import text
from station.sim.layouts import accelerometer_triad
from station.sim.noise import simulated_noise
from station.sim.static import simulate_static, static_gyro

FS = 100.0
WALK = (1e-4, 3e-5)
"""Bias random walks of the accelerometer (m/s^2/sqrt(s)) and the gyro (rad/s/sqrt(s)): 0.5 and
0.7 x the pose means' white noise from one pose to the next, 2-3 x over the session
(bench/diagnose_static.py `none_walk`, whose sessions these are)."""


def session(seed: int, warmup: float = 0.0, walk=WALK) -> StaticData:
    """bench/diagnose_static.py's free-static session (20 poses of 4 s, turns of 2 s): the walks
    added to both streams, a warm-up of `warmup` m/s^2 (tau 180 s) on the accelerometer."""
    unit = accelerometer_triad(np.random.default_rng(seed), fs=FS)
    effects = [f"bias_drift=warmup={warmup},warmup_tau=180"] if warmup else []
    sim = simulate_static(unit, 20, 4.0, 2.0, effects=parse_all(effects))
    acc = sim.arrays["y"][0] * sim.arrays["lsb"]
    rng = np.random.default_rng(seed + 1000)
    gyro = static_gyro(sim.truth, len(acc), rng, sigma=2e-3)
    acc, gyro = (x + np.stack([simulated_noise(len(x), FS, random_walk=k, rng=rng)
                               for _ in range(3)], 1)
                 for x, k in zip((acc, gyro), walk, strict=True))  # the bench's order of draws
    return from_arrays(acc, FS, gyro=gyro, gravity=sim.truth["gravity"])


@pytest.mark.parametrize("seed", [100, 101])
def test_a_walk_read_as_a_drift_is_said_to_be_maybe_the_walk_and_not_corrected(seed):
    data = session(seed)
    result = diagnose_static(data)
    assert "bias_drift" in result.effects  # against white noise alone: log10 p -20 and -29
    (said,) = result.caveats
    assert "may be the unit's bias random walk" in said and "--noise" in said
    assert not result.correction["applied"] and "walk" in result.correction["withheld"]
    assert result.calibration is result.steps[0].model.calibration
    doc = to_dict(result, data)
    assert said in doc["findings"] and "withheld" in text(doc)


def test_with_the_unit_figures_the_walk_is_noise():
    data = session(100)
    k = np.array([WALK[0]] * 3 + [WALK[1]] * 3)
    result = diagnose_static(replace(data, random_walk=k))
    assert result.effects == [] and result.caveats == ()


def test_figures_without_a_walk_let_a_drift_be_corrected():
    # the unit's figures resolve no walk (K = 0 on every channel): the warm-up is judged
    # against white noise, as before the caveat, and corrected
    data = session(100, warmup=0.01, walk=(0.0, 0.0))
    bare = diagnose_static(data)
    result = diagnose_static(replace(data, random_walk=np.zeros(data.c)))
    assert bare.caveats and not bare.correction["applied"]
    assert result.effects == ["bias_drift"] and result.caveats == ()
    assert result.correction["applied"]


def test_a_strong_warm_up_is_no_walk():
    # 0.05 m/s^2 (tau 180 s over a 2-minute session): log10 p about -4 against a free walk
    result = diagnose_static(session(100, warmup=0.05, walk=(0.0, 0.0)))
    assert result.effects == ["bias_drift"] and result.caveats == ()
    assert result.correction["applied"]


def test_a_walk_alone_is_not_told_from_a_drift_without_the_figures():
    # the free walk's likelihood ratio on the same session without a warm-up: no evidence
    data = session(101)
    b0 = base(data)
    current = fit(data, b0)
    log10_p, k = static_walk.beside_walk(data, current, fit(data, b0, ("bias_drift",),
                                                             current).tau)
    assert log10_p > -1.0
    # the walks' K, each from its stream's pose means (11 and 57 dof): within a factor of 3
    assert np.all(k[:3] > WALK[0] / 3) and np.all(k[:3] < WALK[0] * 3)
    assert np.all(k[3:] > WALK[1] / 3) and np.all(k[3:] < WALK[1] * 3)


def test_the_pose_means_walk_covariance():
    """unit_walk against the covariance of simulated walks' interval means (Monte Carlo, 4000
    walks), read through the successive poses' differences (the free level drops out, and their
    variances, about 4.7 s, are where the spans' thirds and halves differ by 15 %): each entry
    within 5 standard errors of a sample covariance, sqrt((s_pp s_qq + s_pq^2) / N)."""
    data = session(100, walk=(0.0, 0.0))
    rng = np.random.default_rng(7)
    n, k = 4000, len(data.t)
    walks = np.cumsum(rng.normal(0.0, np.sqrt(np.diff(data.t, prepend=data.t[0])), (n, k)), 1)
    means = np.stack([walks[:, a:z].mean(1) for a, z in data.intervals], 1)
    d = np.diff(np.eye(len(data.intervals)), axis=0)
    model = d @ static_walk.unit_walk(data) @ d.T
    sample = np.cov((means @ d.T).T)
    s = np.diag(sample)
    assert np.all(np.abs(sample - model) < 5 * np.sqrt((np.outer(s, s) + sample**2) / n))
