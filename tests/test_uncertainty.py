"""Reported uncertainties are honest: nominal 95 % intervals cover the truth about 95 % of the
time."""

import numpy as np
from layouts import random_directions, section4_gyros
from scipy import stats

import station


def binomial_band(p, trials, k=3.0):
    """Acceptance band for a coverage fraction: p +- k binomial standard deviations."""
    half = k * np.sqrt(p * (1 - p) / trials)
    return p - half, p + half


def test_95_percent_intervals_of_scales_and_angles_cover_the_truth():
    rng = np.random.default_rng(7)
    trials = 300
    cover_s, cover_ang = [], []
    i, k = np.triu_indices(12, 1)
    for _ in range(trials):
        a, v, readings = section4_gyros(rng, 20, 0.01)
        res = station.calibrate(readings, 1.0)  # sigma estimated from the residuals
        true_s = np.linalg.norm(a, axis=0)
        u = a / true_s
        true_ang = np.arccos(np.clip(u.T @ u, -1, 1))
        cover_s.append(np.abs(res.scale_factors - true_s) < 1.96 * res.scale_factors_sigma)
        cover_ang.append(
            np.abs(res.axis_angles - true_ang)[i, k] < 1.96 * res.axis_angles_sigma[i, k])
    lo, hi = binomial_band(0.95, trials)  # conservative: one effective sample per trial
    assert lo < np.mean(cover_s) < hi, np.mean(cover_s)
    assert lo < np.mean(cover_ang) < hi, np.mean(cover_ang)


TRIAD = np.array([[9.7, 0.05, -0.1], [0.0, 9.9, 0.08], [0.0, 0.0, 9.8]])
"""An accelerometer triad (m/s^2 per g), upper triangular: already in the canonical frame."""


def triad_with_unknown_biases(seed: int, trials: int = 300):
    """(biases, calibration) of `trials` triads at 24 random poses, noise 0.01, biases estimated."""
    rng = np.random.default_rng(seed)
    for _ in range(trials):
        b = rng.normal(0, 0.5, 3)
        v = random_directions(rng, 3, 24)
        yield b, station.calibrate(TRIAD.T @ v + b[:, None] + 0.01 * rng.standard_normal((3, 24)),
                                   1.0, bias="estimate", sigma=0.01)


def test_bias_intervals_cover_the_truth_for_a_triad_with_unknown_biases():
    cover = [np.abs(res.bias - b) < 1.96 * res.bias_sigma
             for b, res in triad_with_unknown_biases(8)]
    lo, hi = binomial_band(0.95, len(cover))
    assert lo < np.mean(cover) < hi, np.mean(cover)


def test_the_joint_covariance_of_a_and_b_is_honest():
    """parameter_covariance (vec(a) in the canonical frame, then b): the Mahalanobis distance of
    the error is chi2 with d m + m - d(d-1)/2 = 9 dof (the frame fixes three entries of a)."""
    trials, d2 = 300, []
    for b, res in triad_with_unknown_biases(11, trials):
        cov = res.parameter_covariance
        np.testing.assert_allclose(np.diag(cov), np.r_[res.a_sigma.ravel(), res.bias_sigma] ** 2,
                                   rtol=1e-9, atol=1e-20)
        assert np.linalg.matrix_rank(cov, rtol=1e-8, hermitian=True) == 9
        err = np.r_[(res.a - TRIAD).ravel(), res.bias - b]
        d2.append(err @ np.linalg.pinv(cov, rcond=1e-8, hermitian=True) @ err)
    d2 = np.array(d2)
    assert abs(d2.mean() - 9) < 3 * np.sqrt(2 * 9 / trials), d2.mean()  # chi2(9): mean 9, var 18
    lo, hi = binomial_band(0.95, trials)
    assert lo < np.mean(d2 < stats.chi2.ppf(0.95, 9)) < hi


def test_crlb_trace_scales_with_sigma_squared_and_inverse_n():
    rng = np.random.default_rng(9)
    a, v, _ = section4_gyros(rng, 40, 0.0)
    t1 = np.trace(station.crlb(a, v, 0.01))
    np.testing.assert_allclose(np.trace(station.crlb(a, v, 0.02)), 4 * t1, rtol=1e-9)
    doubled = np.hstack([v, v])  # every position twice: information doubles
    np.testing.assert_allclose(np.trace(station.crlb(a, doubled, 0.01)), t1 / 2, rtol=1e-6)


def test_eps_tail_probability_matches_the_monte_carlo_of_an_efficient_estimator():
    # Section IV layout, n = 50: the closed form is efficient there (ratio 1.00 in
    # bench/solvers.py), so P(eps_trial >= eps_q) over real trials must match the predicted tail at
    # its quantiles
    from station.solve.uncertainty import eps_tail_probability

    rng = np.random.default_rng(12)
    a, v, _ = section4_gyros(rng, 50, 0.0)
    bound = station.crlb(a, v, 0.01)
    trials = np.array([station.eps(a, station.calibrate(
                           a.T @ v + 0.01 * rng.standard_normal((12, 50)),
                           1.0, sigma=0.01, refine=False).a)
                       for _ in range(400)])
    for q in (0.5, 0.9):
        level = np.quantile(trials, q)
        p = eps_tail_probability(level, bound)
        assert abs(p - (1 - q)) < 4 * np.sqrt(q * (1 - q) / 400), (q, p)
    assert eps_tail_probability(0.0, bound) == 1.0
    assert eps_tail_probability(10 * np.sqrt(np.trace(bound)), bound) == 0.0


def test_the_random_effects_bound_grows_with_the_spread_and_tends_to_the_sphere():
    rng = np.random.default_rng(10)
    a, v, _ = section4_gyros(rng, 20, 0.0)
    hard = np.trace(station.crlb(a, v, 0.01))
    traces = [np.trace(station.crlb(a, v, 0.01, spread=s)) for s in (1e-7, 1e-3, 1e-2)]
    np.testing.assert_allclose(traces[0], hard, rtol=1e-4)
    assert hard < traces[1] < traces[2]
