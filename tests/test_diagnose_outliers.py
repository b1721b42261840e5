"""Issue 32, pattern 3: spikes (a heavy-tailed noise law) are detected with their rate, down-
weighted, and the free-static calibration returns near its bound; effect-free streams (white,
flicker, random walk, quantised, moving smoothly) are not flagged."""

import numpy as np
import pytest

from station.diagnose import outliers
from station.diagnose.static import diagnose_static, from_arrays
from station.model.effects import parse_all
from station.model.frames import eps
from station.reduce.spikes import NULL_CHANCE
from station.report.diagnosis import static_to_dict, text
from station.sim.layouts import accelerometer_triad
from station.sim.noise import simulated_noise
from station.sim.static import simulate_static
from station.solve.uncertainty import crlb, eps_tail_probability

ALPHA = 0.01
FS = 100.0


def null_stream(seed: int, k: int = 30_000) -> np.ndarray:
    """(k, 3) effect-free samples of unit white noise: channel 1 plus flicker and a random walk
    (docs/noise.md's terms at the white noise's level over 1 s), channel 2 quantised at 2 sigma
    a step, channel 3 turning smoothly by 50 sigma every 6 s (raised cosine, 2 s)."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((k, 3))
    x[:, 0] += simulated_noise(k, FS, bias_instability=0.1, random_walk=0.1, rng=rng)
    x[:, 1] = 2.0 * np.round(x[:, 1] / 2.0)
    phase = np.clip((np.arange(k) / FS % 6.0 - 4.0) / 2.0, 0, 1)
    x[:, 2] += 50 * (np.arange(k) // 600 + 0.5 - 0.5 * np.cos(np.pi * phase))
    return x


def test_effect_free_streams_are_not_flagged():
    """Gaussian noise puts a sample beyond 8 sigma once in 8e14: over 20 seeds x 90,000 samples
    the chance of any detection is 2e-9, far below alpha."""
    found = [outliers.test(outliers.clean(null_stream(s), np.array([0, 2.0, 0])).flags, ALPHA)
             for s in range(20)]
    assert not any(f["detected"] for f in found)
    assert sum(int(f["count"].sum()) for f in found) == 0


@pytest.mark.parametrize("size", [20.0, 40.0])
def test_spikes_at_a_few_times_the_limit_are_found_with_their_rate(size):
    """Spikes of 20 and 40 sigma on 0.2 % of the samples: every flagged sample is a spike. The
    limit is 8 robust sigma of a reference whose scatter is 1.1 sigma (8.8 sigma: 2.3 and 4.5 x),
    or 8 steps in the channel quantised at 2 sigma (its scatter about the reference is 0 in more
    than half the samples: 16 sigma, 2.5 x for the 40-sigma spikes): every spike above 2 x its
    channel's limit is found."""
    x = null_stream(7)
    rng = np.random.default_rng(8)
    hit = rng.random(x.shape) < 2e-3
    spiked = x + hit * np.where(rng.random(x.shape) < 0.5, -size, size)
    found = outliers.clean(spiked, np.array([0, 2.0, 0]))
    report = outliers.test(found.flags, ALPHA)
    assert report["detected"]
    assert not np.any(found.flags & ~hit)
    above = [0, 1, 2] if size >= 2 * 16 else [0, 2]
    assert np.array_equal(found.flags[:, above], hit[:, above])
    assert np.allclose(report["rate"][above], hit.mean(0)[above])
    assert np.all(report["log10_p"] < report["threshold_log10_p"])
    assert np.abs(found.x - x)[found.flags].max() < 8  # replaced by their neighbours' reference


def test_the_count_test_follows_its_poisson_law():
    """The p-value of a count is its Poisson tail at K x NULL_CHANCE (computed here by the sum of
    the probabilities of that count and more)."""
    flags = np.zeros((1000, 2), bool)
    flags[:3, 1] = True
    report = outliers.test(flags, ALPHA)
    lam = 1000 * NULL_CHANCE
    tail = sum(np.exp(-lam) * lam**n / np.prod(np.arange(1, n + 1)) for n in range(3, 8))
    assert report["log10_p"][0] == pytest.approx(0.0, abs=1e-20)
    assert report["log10_p"][1] == pytest.approx(np.log10(tail), rel=1e-9)
    assert report["count"].tolist() == [0, 3]


def test_the_simulator_spikes_samples_at_its_rate():
    """The `outliers` effect of the sensor output chain: spikes of its size on its rate of
    samples (Binomial 99.9 % band)."""
    unit = accelerometer_triad(np.random.default_rng(3), fs=FS)
    clean = simulate_static(unit, 10).arrays["y"][0]
    unit = accelerometer_triad(np.random.default_rng(3), fs=FS)
    fx = parse_all(["outliers=rate=0.01,size=1.0"])
    spiky = simulate_static(unit, 10, effects=fx).arrays["y"][0]
    moved = np.abs(spiky - clean) * unit.lsb
    hit = moved > 0.5
    k = hit.size
    assert abs(hit.sum() - 0.01 * k) < 3.3 * np.sqrt(0.01 * 0.99 * k)
    assert np.allclose(moved[hit], 1.0, atol=unit.lsb.max())


@pytest.fixture(scope="module")
def spiky_session():
    """A 20-pose free-static session (accelerometer triad, 100 Hz) with 30-sigma spikes on
    0.5 % of its samples, and its diagnosis."""
    unit = accelerometer_triad(np.random.default_rng(101), fs=FS)
    sim = simulate_static(unit, 20, effects=parse_all(["outliers=rate=5e-3,size=0.3"]))
    data = from_arrays(sim.arrays["y"][0] * unit.lsb, FS, gravity=sim.truth["gravity"])
    return data, diagnose_static(data), sim.truth, unit


def test_a_spiky_session_reports_its_outliers_and_names_nothing(spiky_session):
    data, result, _, _ = spiky_session
    doc = static_to_dict(result, data, "spiky")
    assert doc["outliers"]["detected"]
    assert np.all(np.array(doc["outliers"]["rate"][:3]) > 0.0025)  # 0.5 % of ~7000: -6 sigma
    assert result.effects == [] and not result.unexplained
    assert text(doc).splitlines()[1].startswith("OUTLIERS:")
    assert len(data.intervals) == 20


def test_a_spiky_session_is_calibrated_near_its_bound(spiky_session):
    """eps (Eq. 19) of the calibration against the law of an efficient estimate's error at the
    bound (the interval means' white and quantisation noise): not beyond its 99.9 % tail. Without
    the down-weighting the noise sigma is 2.5 x and eps 2-4 x the bound."""
    data, result, truth, unit = spiky_session
    a, v = np.asarray(truth["a"]), np.asarray(truth["v"])
    cov = crlb(a, v, unit.mean_sigma(400), estimate_bias=True)
    assert eps_tail_probability(eps(a, result.calibration.a), cov) > 1e-3
    assert np.all(data.sigma < 1.1 * unit.sigma)
