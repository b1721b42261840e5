"""The uncertainties computed from the blocks of the covariance (station/solve/uncertainty.py) equal
the dense propagation they replace: the full Jacobian of every reported figure (the frame by
central differences) applied to the eigen-decomposition pseudo-inverse of the reduced Fisher
matrix; and Student-t intervals when the noise level comes from few spare readings."""

import numpy as np
import pytest
from layouts import A_MODEL, random_directions, section4_gyros
from scipy import stats
from test_uncertainty import TRIAD, binomial_band

import station
from station.model.frames import align_to, to_canonical
from station.solve import ml, uncertainty
from station.solve.calibrate import _sigmas, ml_covariance
from station.solve.uncertainty import frame_rotation

FD_RTOL = 1e-7
"""Central differences of step h = 1e-7 |a| err by about eps / h + h^2 ~ 1e-9 of the derivative;
exact formulas agree to rounding (EXACT_RTOL)."""
EXACT_RTOL = 1e-9


def dense_reference(fit: ml.MLFit, frame, estimate_bias: bool) -> dict:
    """The previous computation: full Jacobians (pairs x m p for the angles) on the full
    covariance, its pseudo-inverse over all but the gauge's smallest eigen-directions."""
    d, m = fit.a.shape
    p = d + (1 if estimate_bias else 0)
    lam, vec = np.linalg.eigh(uncertainty.reduced_fisher(fit.normal))
    keep = slice(d * (d - 1) // 2, None)
    cov = (vec[:, keep] / lam[keep]) @ vec[:, keep].T
    jac = uncertainty.frame_jacobian(fit.a, p, frame)
    if estimate_bias:
        bias = np.zeros((m, m, p))
        bias[np.arange(m), np.arange(m), d] = 1.0
        jac = np.vstack([jac, bias.reshape(m, m * p)])
    u = fit.a / np.linalg.norm(fit.a, axis=0)
    scale = np.zeros((m, m, p))
    scale[np.arange(m), np.arange(m), :d] = u.T
    scale = scale.reshape(m, m * p)
    i, k = np.triu_indices(m, 1)
    cos = np.einsum("dp,dp->p", u[:, i], u[:, k])
    sin = np.sqrt(1.0 - cos**2)
    norms = np.linalg.norm(fit.a, axis=0)
    angle = np.zeros((len(i), m, p))
    rows = np.arange(len(i))
    angle[rows, i, :d] = (-(u[:, k] - cos * u[:, i]) / (sin * norms[i])).T
    angle[rows, k, :d] = (-(u[:, i] - cos * u[:, k]) / (sin * norms[k])).T
    angle = angle.reshape(len(i), m * p)
    angles = np.zeros((m, m))
    angles[i, k] = angles[k, i] = np.sqrt(np.diag(angle @ cov @ angle.T))
    return {"theta": cov, "parameters": jac @ cov @ jac.T,
            "scale": np.sqrt(np.diag(scale @ cov @ scale.T)), "angles": angles}


def fits():
    """(name, fit, nominal or None, biases estimated): Section IV gyros, with and without biases
    and a nominal frame, and a planar array."""
    rng = np.random.default_rng(21)
    a, v, readings = section4_gyros(rng, 20, 0.01)
    b = rng.normal(0, 0.3, 12)
    biased = readings + b[:, None]
    yield "gyros", ml.refine(readings, a, v, sigma=0.01), None, False
    yield "gyros nominal", ml.refine(readings, a, v, sigma=0.01), A_MODEL, False
    yield ("gyros with biases", ml.refine(biased, a, v, bias0=b, estimate_bias=True, sigma=0.01),
           A_MODEL, True)
    a2, v2 = random_directions(rng, 2, 5), random_directions(rng, 2, 15)
    yield "planar", ml.refine(a2.T @ v2 + 0.01 * rng.standard_normal((5, 15)), a2, v2), None, False


@pytest.mark.parametrize("name, fit, nominal, estimate_bias", list(fits()),
                         ids=lambda x: x if isinstance(x, str) else "")
def test_block_uncertainties_equal_the_dense_propagation(name, fit, nominal, estimate_bias):
    frame = to_canonical if nominal is None else (lambda x: align_to(x, nominal) @ x)
    ref = dense_reference(fit, frame, estimate_bias)
    new = _sigmas(fit.a, frame_rotation(fit.a, nominal), ml_covariance(fit), nominal,
                  estimate_bias)
    big = np.abs(ref["theta"]).max()
    np.testing.assert_allclose(new["theta"], ref["theta"], rtol=0, atol=EXACT_RTOL * big)
    np.testing.assert_allclose(new["scale"], ref["scale"], rtol=EXACT_RTOL)
    np.testing.assert_allclose(new["angles"], ref["angles"], rtol=EXACT_RTOL)
    big = np.abs(ref["parameters"]).max()
    np.testing.assert_allclose(new["parameters"], ref["parameters"], rtol=0, atol=FD_RTOL * big)


def test_the_gauge_pseudo_inverse_inverts_beside_the_gauge_and_refuses_more_null_directions():
    rng = np.random.default_rng(3)
    basis = np.linalg.qr(rng.standard_normal((6, 6)))[0]
    gauge = basis[:, :1] * 3.0  # any scale: the basis is orthonormalised
    lam = np.array([0.0, 5.0, 1.0, 2.0, 3.0, 4.0])
    exact = (basis[:, 1:] / lam[1:]) @ basis[:, 1:].T
    np.testing.assert_allclose(uncertainty.gauge_pinv((basis * lam) @ basis.T, gauge), exact,
                               atol=1e-12)
    lam[1] = -1e-3  # not PSD beyond the gauge
    with pytest.raises(np.linalg.LinAlgError):
        uncertainty.gauge_pinv((basis * lam) @ basis.T, gauge)


@pytest.mark.parametrize("estimate_bias", [False, True])
def test_the_woodbury_covariance_of_many_sensors_at_few_poses_is_the_pseudo_inverse(estimate_bias):
    """60 sensors at 12 poses: the poses' 24 unknowns are few beside the sensors' 180 (240), so
    `normal_covariance` takes the Woodbury identity; it equals the eigen-decomposition
    pseudo-inverse of the reduced Fisher matrix to rounding. Poses in a plane leave the axes'
    normal components undetermined: refused (LinAlgError), as `gauge_pinv` refuses."""
    rng = np.random.default_rng(8)
    a, v = random_directions(rng, 3, 60), random_directions(rng, 3, 12)
    b = rng.normal(0, 0.3, 60) if estimate_bias else np.zeros(60)
    readings = a.T @ v + b[:, None] + 0.01 * rng.standard_normal((60, 12))
    fit = ml.refine(readings, a, v, bias0=b if estimate_bias else None,
                    estimate_bias=estimate_bias, sigma=0.01)
    m, p = fit.normal.g_global.shape
    assert uncertainty.WOODBURY_BELOW * (fit.normal.g_local.size + 3) < m * p
    lam, vec = np.linalg.eigh(fit.fisher)
    reference = (vec[:, 3:] / lam[3:]) @ vec[:, 3:].T
    ours = uncertainty.normal_covariance(fit.normal, fit.a, lambda: pytest.fail("not Woodbury"))
    np.testing.assert_allclose(ours, reference, rtol=0, atol=EXACT_RTOL * np.abs(reference).max())
    flat = v.copy()
    flat[2] = 0.0
    flat /= np.linalg.norm(flat, axis=0)
    planar = ml.refine(a.T @ flat, a, flat, sigma=0.01, max_iter=0)
    gauge = uncertainty.gauge_directions(planar.a, 3)
    with pytest.raises(np.linalg.LinAlgError):
        uncertainty.woodbury_pinv(planar.normal, gauge)


def triads_with_few_spare_readings(seed: int, poses: int, trials: int):
    """(truth a, biases, result) for accelerometer triads at `poses` random poses, biases
    estimated, the noise level estimated from the residuals (dof = poses - 9)."""
    rng = np.random.default_rng(seed)
    for _ in range(trials):
        b = rng.normal(0, 0.5, 3)
        v = random_directions(rng, 3, poses)
        readings = TRIAD.T @ v + b[:, None] + 0.01 * rng.standard_normal((3, poses))
        yield b, station.calibrate(readings, 1.0, bias="estimate")


def test_intervals_with_an_estimated_noise_level_cover_95_percent_at_4_dof():
    """dof = 4: a normal quantile on the estimated sigma covers P(|t_4| < 1.96) = 0.88 only; the
    Student-t widening restores 95 %. Band: 3 binomial standard deviations of one effective
    sample per trial (the intervals of one fit are correlated: conservative)."""
    trials, poses = 400, 13
    i, k = np.triu_indices(3, 1)
    u = TRIAD / np.linalg.norm(TRIAD, axis=0)
    angles = np.arccos(np.clip(u.T @ u, -1, 1))[i, k]
    cover = {"scale": [], "angles": [], "bias": []}
    for b, res in triads_with_few_spare_readings(31, poses, trials):
        assert res.dof == poses - 9 and res.sigma_estimated
        cover["scale"].append(np.abs(res.scale_factors - np.linalg.norm(TRIAD, axis=0))
                              < 1.96 * res.scale_factors_sigma)
        cover["angles"].append(np.abs(res.axis_angles[i, k] - angles)
                               < 1.96 * res.axis_angles_sigma[i, k])
        cover["bias"].append(np.abs(res.bias - b) < 1.96 * res.bias_sigma)
    lo, hi = binomial_band(0.95, trials)
    assert 2 * stats.t.sf(1.96, poses - 9) > 0.05 + (hi - lo) / 2  # the old figure fails the band
    for name, hits in cover.items():
        assert lo < np.mean(hits) < hi, (name, np.mean(hits))


def test_the_student_factor():
    assert uncertainty.t_widening(0) == 1.0
    np.testing.assert_allclose(uncertainty.t_widening(12) ** 0.5, 2.178813 / 1.959964, rtol=1e-6)
    assert 1.0 < uncertainty.t_widening(1e6) < 1.0 + 1e-5
