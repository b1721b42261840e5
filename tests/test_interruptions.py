"""Interrupted sessions resume to the readings of an uninterrupted one (tests/interruption.py).

36 interruption points: Ctrl-C (SIGINT), `kill` (SIGTERM) and a crash (SIGKILL) of `station record`
right after each protocol event (mounting, static window start and end, rotating window start and
end, position done) of the first two positions of a 3-position session on `station twin`, each
followed by `station resume`. Every window of every position must hold exactly the samples due
(found / due within one sample of 1), and the Eq. (18) readings must equal those of an
uninterrupted session of the same twin within their noise: |M - M_ref| / sqrt(sigma^2 +
sigma_ref^2) below the normal quantile of a 1e-3 family-wise false alarm over every entry of every
point. A twin whose fixture and station disagree on the position gives readings of another
orientation (hundreds of sigma); readings timed onto the wrong windows give counts of 2.00.

8 more points lose a device on the wire instead (`station twin` told by a signal): the IMU
unplugged in the static window and after the rotating window, the table silent (Modbus requests
unanswered) in the static and in the rotating window, of positions 1 and 2. `record` must end by
itself (no signal) with the file closed cleanly, the loss recorded (`fault`, `pause`) and, for the
IMU, the table stopped; then the device comes back and `station resume` must meet the same checks.
"""

import numpy as np
import pytest
from interruption import LOSSES, POSITIONS, STATES, deviation, record
from scipy import stats

SIGNALS = ("SIGINT", "SIGTERM", "SIGKILL")
POINTS = [(sig, kind, j) for sig in SIGNALS for kind in STATES for j in (0, 1)]
DEVICE_POINTS = [(device, kind, j) for device, kinds in LOSSES.items() for kind in kinds
                 for j in (0, 1)]
ENTRIES = 12 * POSITIONS * (len(POINTS) + len(DEVICE_POINTS))
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
    check_resumed(run, reference)


@pytest.mark.parametrize("point", DEVICE_POINTS, ids=["-".join(map(str, p)) for p in DEVICE_POINTS])
def test_a_session_that_lost_a_device_resumes_to_the_uninterrupted_readings(point, reference,
                                                                              tmp_path):
    run = record(tmp_path, point)
    assert run["record_exit"] == 3, run["record_stderr"]  # ProtocolError, SessionPaused
    left = run["record"]
    assert left["clean"] and left["abort"] + left["pause"] >= 1, left
    assert left["fault" if point[0] == "imu" else "pause"] >= 1, left
    if point[0] == "imu":
        assert not run["table_running"]
    assert run["resume_exit"] == 0, run["resume_stderr"]
    check_resumed(run, reference)


def check_resumed(run: dict, reference: dict) -> None:
    """Every window holds the samples due; the readings are the uninterrupted ones within noise."""
    ratios = np.array(run["ratios"])
    assert ratios.shape == (POSITIONS, 2)
    assert np.all(np.abs(ratios - 1) <= 2 / 2000), ratios  # one sample each side of a 10 s window
    z = deviation(run, reference)
    assert np.max(np.abs(z)) < LIMIT, np.round(z, 1)
