"""Issue 32, the samples' own law in rotary sessions. Pattern 3: sparse spikes are found against
each position's steady model in the table rate, replaced, and said; the noise sigma and the
calibration come back to the spike-free session's (before: spikes of 30 sigma on 0.1 % of the
samples inflated the noise sigma 1.34-1.38 times, the variance by rate x 30^2 = 0.9, and nothing
said so). Pattern 4: a step coarser than the noise is recognised from the counts and the error
the window means keep is in the noise of the readings."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from station.diagnose import diagnose
from station.model.frames import eps
from station.report.diagnosis import text, to_dict
from station.sim.layouts import gyro_array
from station.solve.uncertainty import crlb

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("bench_diagnose", ROOT / "bench" / "diagnose.py")
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)

SEEDS = (3000, 3001, 3002)
RATE = 1e-3
"""Chance that a sample of a channel is a spike: about 40 spikes a sensor in a session."""


@pytest.fixture(scope="module", autouse=True)
def spiky_case():
    """bench/diagnose.py's case `outliers`: spikes of 30 x the unit's per-sample sigma."""
    sigma = float(gyro_array(np.random.default_rng(0), bench.LAYOUTS[3], fs=100.0).sigma.max())
    bench.CASES["outliers"] = f"outliers=rate={RATE:g},size={30 * sigma:.6g}"
    yield sigma
    del bench.CASES["outliers"]


@pytest.mark.parametrize("seed", SEEDS)
def test_spikes_are_found_replaced_and_said(seed, spiky_case):
    data, truth = bench.session("outliers", 3, seed)
    clean, _ = bench.session("none", 3, seed)  # the same noise draws but the spikes' own
    report = data.outlier_test(0.01)
    assert report["detected"]
    # each sensor's count near RATE x samples (Poisson; the spikes hidden by the quantisation
    # or in a run with a neighbour are a few per cent of them)
    expected = RATE * report["samples"]
    assert np.all(np.abs(report["count"] - expected) < 5 * np.sqrt(expected) + 0.1 * expected)
    # the noise as without spikes: their variance RATE x 30^2 = 0.9 sigma^2 is gone
    np.testing.assert_allclose(data.sigma, clean.sigma, rtol=0.05)
    result = diagnose(data)
    doc = to_dict(result, data)
    assert doc["outliers"]["detected"] and "OUTLIERS" in text(doc)
    assert not result.effects and not result.unexplained
    # the calibration within 3 x the bound of the true noise (the line)
    bound = np.sqrt(np.trace(crlb(np.asarray(truth["a"]), np.asarray(truth["v"]),
                                  clean.sigma_m)))
    assert eps(np.asarray(truth["a"]), result.calibration.a) < 3 * bound


@pytest.mark.parametrize("case", ["none", "saturation", "latency", "scale_nonlinearity",
                                  "axis_wobble", "bias_drift", "rate_error", "earth_rate"])
def test_effect_free_noise_and_library_effects_are_not_called_spikes(case):
    """Gaussian noise puts a sample beyond 8 sigma once in 8e14; the ramps' corners and a clipped
    output's ramp follow the steady model or depart in runs, not alone."""
    for m in (3, 12):
        data, _ = bench.session(case, m, 3000)
        assert not data.outlier_test(0.01)["detected"], (case, m)


@pytest.mark.parametrize("seed", SEEDS)
def test_coarse_quantisation_is_said_and_kept_in_the_noise_of_the_readings(seed):
    """Issue 32, pattern 4 in rotary sessions: counts 10 times coarser than the default MEMS
    gyro's (a step of about 6 sigma): the windows' means keep up to step^2 / 12 of quantisation
    error, which the noise of M now holds (the calibration's error within its bound, which was
    9-19 times that bound without it); the report says so, and nothing else: the bins and local
    features keep the error too (`RotaryData.bin_variance`; before it, tone, axis_wobble,
    rate_error were named and harmonics, trend, spectrum left unexplained in these sessions).
    The default gyro (1.6 sigma a step) dithers its step: nothing kept, nothing said."""
    coarse = {"counts_per_unit": 16.4 / np.radians(1.0) / 10}
    unit = gyro_array(np.random.default_rng(seed), bench.LAYOUTS[3], fs=100.0, **coarse)
    sim = bench.simulate_rotary(unit, 20, bench.SHORT, a_nominal=bench.LAYOUTS[3])
    data = bench.session_data.from_arrays(sim.arrays)
    assert data.quantisation_report()["coarse"].any()
    assert np.all(data.kept > 0.01 * data.step**2 / 12)
    result = diagnose(data)
    doc = to_dict(result, data)
    said = [f for f in doc["findings"] if f.startswith("QUANTISED")]
    assert said and "finer counts" in said[0]
    assert not result.effects and not result.unexplained, (result.effects, result.unexplained)
    a, v = np.asarray(sim.truth["a"]), np.asarray(sim.truth["v"])
    assert eps(a, result.calibration.a) < 3 * np.sqrt(np.trace(crlb(a, v, data.sigma_m)))
    fine, _ = bench.session("none", 3, seed)
    assert not fine.quantisation_report()["coarse"].any() and np.all(fine.kept < 1e-9)
