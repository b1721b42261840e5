"""station.solve.allan_edf against allantools.edf_greenhall (the reference), and the solve's
noise fit free of allantools' imports."""

import json
import subprocess
import sys

import allantools
import pytest

from station.solve.allan_edf import allan_edf

FACTORS = (1, 2, 4, 16, 33, 34, 64, 1024, 4096)
"""Both sides of J_MAX = 100 lags (3 m <= 100 up to m = 33) and of r = M / m = 3."""


def lengths(m: int) -> list:
    """Phase points from the shortest (M = 1, 2 m + 1 points + 1) through J = M < 3 m, r just
    above and below 3, to the large-length limit."""
    return sorted({2 * m + 2, 2 * m + 5, 4 * m, 5 * m + 1, 5 * m + 3, 20 * m, 10**5, 2**40})


@pytest.mark.parametrize("alpha", [0, -1, -2])
def test_the_edf_is_greenhalls_in_every_case(alpha):
    for m in FACTORS:
        for n in lengths(m):
            ours = allan_edf(alpha, m, n)
            theirs = allantools.edf_greenhall(alpha=alpha, d=2, m=m, N=n, overlapping=True)
            assert ours == pytest.approx(theirs, rel=1e-12), (alpha, m, n)


def test_outside_its_cases_it_refuses():
    with pytest.raises(ValueError, match="alpha"):
        allan_edf(1, 4, 100)
    with pytest.raises(ValueError, match="phase points"):
        allan_edf(0, 4, 8)


def test_the_noise_fit_imports_no_allantools_nor_scipy_stats():
    code = ("import sys, json, numpy as np\n"
            "from station.solve.noise import allan_curve, fit_noise\n"
            "y = np.random.default_rng(1).standard_normal((4096, 2))\n"
            "fit = fit_noise(allan_curve(y, 100.0))\n"
            "print(json.dumps([m for m in sys.modules if m.startswith(('allantools', "
            "'scipy.stats'))]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert json.loads(out.stdout.splitlines()[-1]) == []
