"""Issue 32, pattern 4: coarse quantisation is recognised from the sample values (the step),
reported with its size in noise sigmas, and kept in the noise model (the error a mean keeps), not
refused as a constant channel nor flagged as a rail pile-up."""

import numpy as np
import pytest

from station.diagnose import quantisation
from station.diagnose.static import diagnose_static, from_arrays
from station.report.diagnosis import static_to_dict, text
from station.sim.layouts import accelerometer_triad
from station.sim.static import simulate_static

FS = 100.0


def quantised_means(sigma: float, n: int, poses: int, seed: int) -> tuple:
    """(scatter about the pose means, the pose means' squared errors) of `poses` poses of n
    samples of N(mu, sigma^2) on a grid of step 1, mu uniform: a direct simulation."""
    rng = np.random.default_rng(seed)
    mu = rng.uniform(0, 1, poses)
    x = np.round(mu[:, None] + sigma * rng.standard_normal((poses, n)))
    scatter = np.sqrt(np.mean(x.var(axis=1, ddof=1)))
    return scatter, (x.mean(axis=1) - mu) ** 2


def test_the_error_a_mean_keeps_spans_nothing_to_a_twelfth_of_the_step_squared():
    assert quantisation.kept(0.0, 2.0)[0] == pytest.approx(4 / 12, rel=1e-3)
    assert quantisation.kept(1.0, 2.0)[0] < 1e-5 * 4
    assert np.all(np.diff(quantisation.kept(np.linspace(0, 1, 11), 1.0)) < 0)


@pytest.mark.parametrize("sigma", [0.05, 0.15, 0.3, 1.0])
def test_the_noise_model_matches_simulated_means(sigma):
    """The variance of a quantised pose mean against scatter^2 / n + q(sigma) from the scatter
    (sigma recovered by analog_sigma): within the 99.9 % band of the mean of 4000 squared
    errors (their spread measured); white noise alone (scatter^2 / n) is far outside it where
    the noise is below half a step."""
    n, poses = 200, 4000
    scatter, d2 = quantised_means(sigma, n, poses, seed=int(100 * sigma))
    est = quantisation.analog_sigma([scatter], [1.0])[0]
    model = scatter**2 / n + quantisation.kept(est, 1.0)[0]
    band = 3.3 * d2.std() / np.sqrt(poses)
    assert abs(d2.mean() - model) < band
    if sigma < 0.5:
        assert d2.mean() - scatter**2 / n > band


@pytest.mark.parametrize("sigma", [0.1, 0.164, 0.3])
def test_the_noise_is_read_from_the_values_the_windows_read(sigma):
    """quantisation.level_sigma on 20 windows of 600 samples at levels spread over the steps (a
    rotary session's rotating windows), 10 sessions: the mean estimate within 3 standard errors
    of the truth (their spread measured), and its spread at most half the scatter inversion's
    (analog_sigma) on the same samples: where the noise is below the step, a window's samples
    say where its level sits, which their scatter's average over 20 levels does not."""
    rng = np.random.default_rng(int(1000 * sigma))
    ml, scatter = [], []
    for _ in range(10):
        windows = [np.round(mu + sigma * rng.standard_normal(600)).astype(np.int64)
                   for mu in rng.uniform(0, 50, 20)]
        ml.append(quantisation.level_sigma(windows))
        pooled = np.sqrt(np.mean([w.var(ddof=1) for w in windows]))
        scatter.append(quantisation.analog_sigma(pooled, 1.0)[0])
    ml, scatter = np.array(ml), np.array(scatter)
    assert abs(ml.mean() - sigma) < 3 * ml.std(ddof=1) / np.sqrt(len(ml))
    assert ml.std(ddof=1) < 0.5 * scatter.std(ddof=1)


def test_the_step_is_read_from_the_values():
    x = np.round(np.random.default_rng(1).normal(0, 3, (500, 2)) / 0.05) * 0.05
    x[:, 1] = np.round(x[:, 1] * 1e3) / 1e3 + 1e-9  # printed decimals
    assert quantisation.step(x) == pytest.approx([0.05, 0.05], rel=1e-6)


def session(step_sigmas: float, seed: int):
    """A 20-pose free-static session of the accelerometer triad quantised at `step_sigmas` of its
    noise, and its diagnosis."""
    noise = accelerometer_triad(np.random.default_rng(seed), fs=FS).sigma[0]
    unit = accelerometer_triad(np.random.default_rng(seed), fs=FS,
                               counts_per_unit=1 / (step_sigmas * noise))
    sim = simulate_static(unit, 20)
    data = from_arrays(sim.arrays["y"][0] * unit.lsb, FS, gravity=sim.truth["gravity"])
    return data, diagnose_static(data), unit


@pytest.mark.parametrize("step_sigmas", [12.0, 40.0])
def test_a_coarse_session_is_reported_quantised_not_refused(step_sigmas):
    """At 12 sigma a step (4 x the step at which the kept error equals a pose mean's white noise)
    and at 40 (every channel reads one value at rest): the step is reported, and the effect-free
    session names nothing and leaves nothing unexplained."""
    data, result, unit = session(step_sigmas, 5)
    doc = static_to_dict(result, data, "coarse")
    q = doc["quantisation"]
    assert q["coarse"][:3] == [True] * 3 and q["coarse"][3:] == []
    assert np.allclose(q["step"][:3], unit.lsb, rtol=1e-9)
    assert "QUANTISED" in text(doc)
    assert result.effects == [] and not result.unexplained


def test_a_finely_quantised_session_is_not_called_quantised():
    data, _, _ = session(0.24, 6)  # the triad's own 4096 counts per g
    assert not data.quantisation()["coarse"].any()
    assert np.allclose(data.sigma, data.scatter)  # the noise dithers the grid: nothing kept


def test_poses_at_a_steps_edge_are_judged_by_their_own_scatter():
    """bench/diagnose_static.py's quantised_12sigma, seed 109: most poses read one value, a few
    whose level sits at a step's edge flip between two; judged by the pooled scatter, those poses'
    bins named a warm-up and a saturation beside QUANTISED. Each coarse channel's bins are now
    judged by their own pose's scatter (StaticData.bin_sigma): nothing is named."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "bench" / "diagnose_static.py"
    spec = importlib.util.spec_from_file_location("bench_static_quantised", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    data, _ = bench.session("quantised_12sigma", 109)
    result = diagnose_static(data)
    assert data.quantisation()["coarse"].any() and result.effects == []
