"""Rupniewski Algorithm 2: exactness without noise and efficiency against the Cramer-Rao bound."""

import numpy as np
import pytest
from layouts import random_directions, section4_gyros

import station
from station.solve.identifiability import min_positions
from station.solve.pca import pca_calibration


@pytest.mark.parametrize("d", [1, 2, 3, 4])
def test_noiseless_exact_for_any_dimension(d):
    rng = np.random.default_rng(d)
    for _ in range(20):
        m = int(rng.integers(d, d + 6))
        n = int(rng.integers(min_positions(m, d), 40))
        a = rng.standard_normal((d, m))
        c = float(rng.uniform(0.1, 10))
        v = random_directions(rng, d, n, c)
        a_hat, v_hat = pca_calibration(a.T @ v, c, d)
        assert station.eps(a, a_hat) < 1e-9 * max(1.0, np.linalg.norm(a))
        np.testing.assert_allclose(np.linalg.norm(v_hat, axis=0), c, rtol=1e-9)


def efficiency(trials, n, sigma, refine, seed):
    """mean(eps^2) / mean(trace CRLB) and its standard error over `trials` Section IV runs."""
    rng = np.random.default_rng(seed)
    e2, bound = np.empty(trials), np.empty(trials)
    for t in range(trials):
        a, v, readings = section4_gyros(rng, n, sigma)
        e2[t] = station.eps(a, station.calibrate(readings, 1.0, sigma=sigma, refine=refine).a) ** 2
        bound[t] = np.trace(station.crlb(a, v, sigma))
    return e2.mean() / bound.mean(), e2.std() / np.sqrt(trials) / bound.mean()


@pytest.mark.parametrize("refine", [False, True])
def test_closed_form_and_ml_are_efficient_on_section4_layout(refine):
    # An efficient estimator has E[eps^2] = trace(CRLB): the ratio is 1 within its sampling error.
    ratio, se = efficiency(150, 20, 0.01, refine, seed=10)
    assert abs(ratio - 1.0) < 4 * se, (ratio, se)
