"""Interrupted sessions resume to the readings of an uninterrupted one (tests/interruption.py).

36 interruption points: Ctrl-C (SIGINT), `kill` (SIGTERM) and a crash (SIGKILL) of `station record`
right after each protocol event (mounting, static window start and end, rotating window start and
end, position done) of the first two positions of a 6-position session on `station twin`, each
followed by `station resume`. Every window of every position must hold exactly the samples due
(found / due within one sample of 1), and the Eq. (18) readings must equal those of an
uninterrupted session of the same twin within their noise: |M - M_ref| / sqrt(sigma^2 +
sigma_ref^2) below the normal quantile of a 1e-3 family-wise false alarm over every entry of every
point. A twin whose fixture and station disagree on the position gives readings of another
orientation (hundreds of sigma); readings timed onto the wrong windows give counts of 2.00.
"""

import numpy as np
import pytest
from interruption import POSITIONS, STATES, deviation, record
from scipy import stats

SIGNALS = ("SIGINT", "SIGTERM", "SIGKILL")
POINTS = [(sig, kind, j) for sig in SIGNALS for kind in STATES for j in (0, 1)]
ENTRIES = 12 * POSITIONS * len(POINTS)
LIMIT = float(stats.norm.isf(1e-3 / (2 * ENTRIES)))


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    return record(tmp_path_factory.mktemp("uninterrupted"))


def test_the_matrix_covers_at_least_30_points_over_every_state():
    assert len(POINTS) >= 30 and {kind for _, kind, _ in POINTS} == set(STATES)


@pytest.mark.parametrize("point", POINTS, ids=["-".join(map(str, p)) for p in POINTS])
def test_an_interrupted_session_resumes_to_the_uninterrupted_readings(point, reference, tmp_path):
    run = record(tmp_path, point)
    assert run["resume_exit"] == 0, run["resume_stderr"]
    assert run["record_exit"] in (130, -9), run["record_stderr"]  # Ctrl-C and kill: 130
    ratios = np.array(run["ratios"])
    assert ratios.shape == (POSITIONS, 2)
    assert np.all(np.abs(ratios - 1) <= 2 / 2000), ratios  # one sample each side of a 10 s window
    z = deviation(run, reference)
    assert np.max(np.abs(z)) < LIMIT, np.round(z, 1)
