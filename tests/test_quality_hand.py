"""The quality gate on hand-placed poses (station.solve.quality, pose_term): poses that scatter
beyond the white noise (re-seating, settling, coloured noise) are judged against the fit's
per-pose error term; table positions keep the strict white-noise test; a pose disturbed far beyond
the others' scatter is still an outlier."""

import numpy as np
from posesim import G, mpu6050_triad, pose_means, random_directions

from station.solve.calibrate import calibrate
from station.solve.quality import FALSE_ALARMS, check_fit

POSES = 24
TRIALS = 60


def fit(seed: int, pose_sd: float, disturbed: float = 0.0):
    rng = np.random.default_rng(seed)
    a, b = mpu6050_triad(rng)
    m, stderr = pose_means(rng, a, b, random_directions(rng, POSES), pose_sd=pose_sd)
    m[2, 5] += disturbed  # one pose's z reading off (a knock, a slipped unit)
    return calibrate(m, G, bias="estimate", sigma=stderr)


def test_scattered_poses_pass_with_their_term_and_fail_without():
    passed = [not check_fit(fit(s, pose_sd=5e-3), pose_term=True).problems for s in range(TRIALS)]
    strict = [not check_fit(fit(s, pose_sd=5e-3)).problems for s in range(TRIALS)]
    # outlier test at FALSE_ALARMS = 0.01 expected false flags per fit; allow 3 x that, binomial
    assert sum(passed) >= TRIALS * (1 - 3 * FALSE_ALARMS) - 3 * np.sqrt(TRIALS * FALSE_ALARMS)
    assert sum(strict) <= 2  # pose scatter 3x the mean's standard error: chi2 refuses


def test_white_noise_poses_are_judged_as_before():
    for s in range(10):
        result = fit(100 + s, pose_sd=0.0)
        assert check_fit(result, pose_term=True).problems == check_fit(result).problems


def test_a_disturbed_pose_stands_out_of_the_scatter():
    """0.1 m/s^2 on one reading: the per-pose term it inflates would hide it from the residual
    test (the pose's direction bends towards it), the robust per-pose test does not."""
    for s in range(10):
        problems = check_fit(fit(200 + s, pose_sd=2e-3, disturbed=0.1), pose_term=True).problems
        named = [p.split(" disagree")[0].removeprefix("pose(s) ").split(", ") for p in problems
                 if p.startswith("pose(s)")]
        assert named and "6" in named[0], problems
