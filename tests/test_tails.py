"""The normal and chi-square tails of station.solve.tails against scipy.special, which the solve
path no longer imports (issue 35). Tolerances from the method (the module notes): the prefactor
exp(-x + a log x - lgamma(a)) is formed in logs, so its relative error is the float's epsilon
times the size of the terms summed in the exponent, a few units of it; the series and the
continued fraction stop at epsilon. Below x = a + 1 the tail is 1 - P: P's error, relative to the
tail, grows by 1 / tail there."""

import math

import numpy as np
import pytest
from scipy import special

from station.solve import tails

EPS = np.finfo(float).eps
DOFS = [1, 2, 3, 4, 5, 7, 10, 31, 100, 101, 999, 1000, 5000, 10_000]


def log_terms(k: float, x: float) -> float:
    """The size of the terms summed in the prefactor's exponent."""
    a, y = k / 2, x / 2
    return y + a * abs(math.log(y)) + abs(math.lgamma(a)) + 1.0


@pytest.mark.parametrize("k", DOFS)
def test_the_chi2_tail_agrees_with_scipy_from_its_bulk_to_1e_minus_290(k):
    for x in k * np.r_[np.linspace(0.01, 10.0, 60), 20.0, 50.0, 100.0, 300.0]:
        ours, theirs = tails.chi2_sf(k, x), float(special.chdtrc(k, x))
        if theirs < 1e-290:
            continue
        series = x / 2 < k / 2 + 1
        bound = 16 * EPS * log_terms(k, x) * (1.0 if series else theirs)
        assert abs(ours - theirs) <= bound, (k, x, ours, theirs)


def test_the_chi2_tail_at_zero_and_a_bad_dof():
    assert tails.chi2_sf(5, 0.0) == 1.0
    with pytest.raises(ValueError, match="degrees of freedom"):
        tails.chi2_sf(0, 1.0)


@pytest.mark.parametrize("k", [1, 2, 3, 5, 10, 100, 1000, 5000])
def test_the_chi2_quantile_inverts_the_tail(k):
    """The quantiles the quality gate and the temperature model ask (p <= 0.5): to 1e-12. Above
    0.5 the tail's resolution near 1 limits it (p = 1 - 1e-9 keeps 7 digits)."""
    for p in [0.5, 0.1, 1e-3, 5e-4, 1e-6, 1e-12, 1e-30, 1e-200]:
        ours, theirs = tails.chi2_isf(k, p), float(special.chdtri(k, p))
        assert ours == pytest.approx(theirs, rel=1e-12), (k, p)
    with pytest.raises(ValueError, match="tail probability"):
        tails.chi2_isf(k, 1.0)


def test_the_normal_quantile_is_scipys_deep_in_the_tail():
    for p in [1e-300, 1e-20, 1e-9, 1e-6, 0.01, 0.3, 0.5, 0.7, 0.99]:
        assert tails.normal_isf(p) == pytest.approx(-float(special.ndtri(p)), rel=1e-14, abs=1e-15)
