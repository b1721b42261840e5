"""Maximum-likelihood refinement: exact fixed point, bias estimation, and efficiency where the
closed form is not (a triad with very unequal scale factors)."""

import numpy as np
import pytest
from layouts import A_MODEL, random_directions, section4_gyros

import station
from station.solve.ml import refine
from station.solve.poses import tangent_basis


def test_tangent_basis_is_orthonormal_and_perpendicular():
    rng = np.random.default_rng(0)
    for d in (2, 3, 5):
        u = random_directions(rng, d, 50)
        u[:, 0] = -np.eye(d)[0]  # the Householder sign switch
        b = tangent_basis(u)
        np.testing.assert_allclose(np.einsum("ndk,ndl->nkl", b, b),
                                   np.broadcast_to(np.eye(d - 1), (50, d - 1, d - 1)), atol=1e-12)
        np.testing.assert_allclose(np.einsum("dn,ndk->nk", u, b), 0, atol=1e-12)


def test_converges_to_the_truth_from_a_perturbed_start_without_noise():
    rng = np.random.default_rng(1)
    a = A_MODEL + 0.01 * rng.standard_normal(A_MODEL.shape)
    v = random_directions(rng, 3, 30, 2.0)
    b = rng.normal(0, 0.3, 12)
    fit = refine(a.T @ v + b[:, None], a + 0.05 * rng.standard_normal(a.shape),
                 v + 0.1 * rng.standard_normal(v.shape), bias0=b + 0.1, estimate_bias=True,
                 magnitude=2.0)
    assert station.eps(a, fit.a) < 1e-9
    np.testing.assert_allclose(fit.bias, b, atol=1e-9)
    assert fit.dof == 12 * 30 - (3 * 12 + 12 + 30 * 2 - 3)


def test_ml_reaches_the_bound_for_a_triad_with_unequal_scales():
    # DESIGN.md: closed form ~1.6 x the bound, ML ~1.03 x (scale factors 1, 0.3, 3; n = 20)
    rng = np.random.default_rng(2)
    a = np.diag([1.0, 0.3, 3.0])
    e2_cf, e2_ml, bound = [], [], []
    for _ in range(300):
        v = random_directions(rng, 3, 20)
        readings = a.T @ v + 0.01 * rng.standard_normal((3, 20))
        e2_cf.append(
            station.eps(a, station.calibrate(readings, 1.0, sigma=0.01, refine=False).a) ** 2)
        e2_ml.append(station.eps(a, station.calibrate(readings, 1.0, sigma=0.01).a) ** 2)
        bound.append(np.trace(station.crlb(a, v, 0.01)))
    bound = np.mean(bound)
    se = np.std(e2_ml) / np.sqrt(len(e2_ml)) / bound
    ratio_ml, ratio_cf = np.mean(e2_ml) / bound, np.mean(e2_cf) / bound
    assert ratio_ml < 1.0 + 4 * se, (ratio_ml, se)
    assert ratio_cf > 1.3, ratio_cf  # the closed form is not efficient here: refinement matters


def test_estimated_sigma_matches_the_noise():
    rng = np.random.default_rng(3)
    a = A_MODEL + 0.01 * rng.standard_normal(A_MODEL.shape)
    v = random_directions(rng, 3, 100)
    res = station.calibrate(a.T @ v + 0.02 * rng.standard_normal((12, 100)), 1.0)
    # s^2 (dof) / sigma^2 ~ chi2(dof): relative sd of s is 1 / sqrt(2 dof)
    assert abs(res.sigma[0, 0] / 0.02 - 1) < 4 / np.sqrt(2 * res.dof)
    assert res.sigma_estimated


def test_soft_magnitudes_are_exact_without_noise_and_keep_the_dof():
    rng = np.random.default_rng(4)
    a = A_MODEL + 0.01 * rng.standard_normal(A_MODEL.shape)
    v = random_directions(rng, 3, 30, 2.0)
    start_a = a + 0.05 * rng.standard_normal(a.shape)
    fit = refine(a.T @ v, start_a, v + 0.1 * rng.standard_normal(v.shape), magnitude=2.0,
                 sigma=0.01, magnitude_spread=1e-3)
    assert station.eps(a, fit.a) < 1e-9
    assert fit.dof == 12 * 30 - (3 * 12 + 30 * 2 - 3)  # n more unknowns, n more (prior) rows


def _spread_trials(rng, trials, spread, sigma):
    """eps^2 of the soft- and the hard-magnitude ML and the random-effects bound, per trial."""
    out = []
    for _ in range(trials):
        n = sigma.shape[1]
        v = random_directions(rng, 3, n) * (1 + spread * rng.standard_normal(n))
        readings = A_MODEL.T @ v + sigma * rng.standard_normal(sigma.shape)
        soft = station.calibrate(readings, 1.0, sigma=sigma, magnitude_spread=spread)
        hard = station.calibrate(readings, 1.0, sigma=sigma)
        out.append((station.eps(A_MODEL, soft.a) ** 2, station.eps(A_MODEL, hard.a) ** 2,
                    np.trace(station.crlb(A_MODEL, v, sigma, spread=spread))))
    return np.array(out).T


def test_soft_magnitudes_reach_the_random_effects_bound_where_the_sphere_does_not():
    # |v_j| = 1 + delta_j, delta_j ~ N(0, 0.01^2); half the positions 10x noisier than the others,
    # so the sphere's weights (noise only) trust the precise positions' magnitudes far too much
    rng = np.random.default_rng(5)
    sigma = np.repeat(np.where(np.arange(20) < 10, 0.001, 0.01)[None, :], 12, 0)
    e2_soft, e2_hard, bound = _spread_trials(rng, 150, 0.01, sigma)
    se = np.std(e2_soft) / np.sqrt(e2_soft.size) / bound.mean()
    assert abs(e2_soft.mean() / bound.mean() - 1) < 4 * se, (e2_soft.mean() / bound.mean(), se)
    diff = e2_hard - e2_soft
    assert diff.mean() > 4 * np.std(diff) / np.sqrt(diff.size), (e2_hard.mean() / bound.mean())


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"magnitude_spread": -1e-3, "sigma": 0.01}, "non-negative"),
    ({"magnitude_spread": 1e-3}, "noise level"),
])
def test_a_magnitude_spread_needs_a_valid_value_and_sigma(kwargs, match):
    rng = np.random.default_rng(6)
    v = random_directions(rng, 3, 20)
    with pytest.raises(station.CalibrationInputError, match=match):
        station.calibrate(A_MODEL.T @ v, 1.0, **kwargs)


def test_the_blocked_schur_complement_equals_the_dense_one(monkeypatch):
    """reduced_system over blocks of SCHUR_CHUNK groups (7 here: blocks end inside the data)
    equals the Schur complement of the dense normal matrix built from the same blocks."""
    from scipy.linalg import block_diag

    from station.solve import ml

    rng = np.random.default_rng(40)
    a, v, readings = section4_gyros(rng, 30, 0.01)
    bias = rng.normal(0, 0.1, 12)
    neq, _ = ml.normal_equations(a, ml.start_poses(v, 1.0), bias, readings + bias[:, None],
                                 rng.uniform(0.5, 2.0, readings.shape))
    m, p = neq.g_global.shape
    groups, k = neq.g_local.shape
    coupling = neq.h_cross.transpose(0, 1, 3, 2).reshape(m * p, groups * k)  # (m p, G k)
    damped = neq.h_local + 0.1 * np.einsum("gkk,kl->gkl", neq.h_local, np.eye(k))
    h_local_inv = np.linalg.inv(block_diag(*damped))
    dense = block_diag(*(neq.h_global + 0.1 * np.einsum("ipp,pq->ipq", neq.h_global, np.eye(p))))
    dense -= coupling @ h_local_inv @ coupling.T
    gradient = neq.g_global.ravel() - coupling @ h_local_inv @ neq.g_local.ravel()
    monkeypatch.setattr(ml, "SCHUR_CHUNK", 7)
    s, g, _ = ml.reduced_system(neq, damping=0.1)
    np.testing.assert_allclose(s, dense, rtol=1e-10, atol=1e-10 * np.abs(dense).max())
    np.testing.assert_allclose(g, gradient, rtol=1e-10, atol=1e-10 * np.abs(gradient).max())


@pytest.mark.parametrize("estimate_bias", [False, True])
def test_both_eliminations_solve_the_damped_normal_equations(estimate_bias):
    """The LM step by the sensors' Schur complement (many sensors at few positions, issue 35)
    and by the poses' one both solve the full damped system [[U, C], [C^T, L]] built densely
    from the same blocks; lm_step takes the first when the poses' unknowns are fewer."""
    from scipy.linalg import block_diag

    from station.solve import ml

    rng = np.random.default_rng(41)
    a, v = random_directions(rng, 3, 60), random_directions(rng, 3, 12)
    bias = rng.normal(0, 0.1, 60) if estimate_bias else None
    readings = a.T @ v + (0 if bias is None else bias[:, None])
    readings += 0.01 * rng.standard_normal(readings.shape)
    neq, _ = ml.normal_equations(a * 1.01, ml.start_poses(v, 1.0), bias, readings,
                                 rng.uniform(0.5, 2.0, readings.shape))
    m, p = neq.g_global.shape
    groups, k = neq.g_local.shape
    assert groups * k < m * p
    damp = 0.01
    coupling = neq.h_cross.transpose(0, 1, 3, 2).reshape(m * p, groups * k)
    full = np.block([
        [block_diag(*(neq.h_global + damp * np.einsum("ipp,pq->ipq", neq.h_global, np.eye(p)))),
         coupling],
        [coupling.T,
         block_diag(*(neq.h_local + damp * np.einsum("gkk,kl->gkl", neq.h_local, np.eye(k))))]])
    exact = np.linalg.solve(full, np.r_[neq.g_global.ravel(), neq.g_local.ravel()])
    for step in (ml.sensors_first, ml.poses_first, ml.lm_step):
        g, loc = step(neq, damp)
        np.testing.assert_allclose(np.r_[g.ravel(), loc.ravel()], exact, rtol=0,
                                   atol=1e-10 * np.abs(exact).max())


def test_rotation_matrices_equal_scipys_exponential_map():
    from scipy.spatial.transform import Rotation

    from station.solve.poses import rotation_matrices

    rng = np.random.default_rng(41)
    for size in (0.0, 1e-9, 1e-4, 1.0, 3.0):
        w = size * rng.standard_normal((20, 3))
        np.testing.assert_allclose(rotation_matrices(w), Rotation.from_rotvec(w).as_matrix(),
                                   rtol=0, atol=4 * np.finfo(float).eps)
