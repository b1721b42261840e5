"""Maximum-likelihood refinement: exact fixed point, bias estimation, and efficiency where the closed
form is not (a triad with very unequal scale factors)."""

import numpy as np
from layouts import A_MODEL, random_directions

import station
from station.ml import refine
from station.poses import tangent_basis


def test_tangent_basis_is_orthonormal_and_perpendicular():
    rng = np.random.default_rng(0)
    for d in (2, 3, 5):
        u = random_directions(rng, d, 50)
        u[:, 0] = -np.eye(d)[0]  # the Householder sign switch
        b = tangent_basis(u)
        np.testing.assert_allclose(np.einsum("ndk,ndl->nkl", b, b), np.broadcast_to(np.eye(d - 1), (50, d - 1, d - 1)), atol=1e-12)
        np.testing.assert_allclose(np.einsum("dn,ndk->nk", u, b), 0, atol=1e-12)


def test_converges_to_the_truth_from_a_perturbed_start_without_noise():
    rng = np.random.default_rng(1)
    a = A_MODEL + 0.01 * rng.standard_normal(A_MODEL.shape)
    v = random_directions(rng, 3, 30, 2.0)
    b = rng.normal(0, 0.3, 12)
    fit = refine(a.T @ v + b[:, None], a + 0.05 * rng.standard_normal(a.shape),
                 v + 0.1 * rng.standard_normal(v.shape), bias0=b + 0.1, estimate_bias=True, magnitude=2.0)
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
        e2_cf.append(station.eps(a, station.calibrate(readings, 1.0, sigma=0.01, refine=False).a) ** 2)
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
