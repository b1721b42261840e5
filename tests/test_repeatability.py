"""Repeatability between sessions (station.solve.repeatability, station combine): the
between-session variance, the next-session figure's coverage, and the combined calibration file."""

import numpy as np
import pytest
from scipy import stats

import station
from station.calfiles.calfile import Calibration, load
from station.calfiles.combined import combine
from station.cli import main
from station.errors import CalibrationFileError
from station.solve.repeatability import between_variance, pool

TRIALS = 600
K, P = 3, 24


def sessions(rng, tau: float, s: np.ndarray, k: int = K):
    """Estimates (k, P) of P parameters over k sessions: truth + session shift (tau) + noise (s)."""
    mu = rng.normal(0, 1, P)
    x = mu + rng.normal(0, tau, (k, P)) + rng.normal(0, 1, (k, P)) * s
    return mu, x


def test_sessions_that_agree_show_no_spread_yet_tau_is_never_zero():
    """Without a between-session spread, Q(0) ~ chi2(P (K-1)): the Paule-Mandel point estimate is
    0 exactly when Q <= dof, at the rate chi2.cdf(dof, dof) (3 binomial standard errors); the tau
    used for the next session (the posterior mean of tau^2) is never 0 (issue 31: 6 of 8 IMUs'
    scale factors had tau = 0 from 3 sessions, taken as known)."""
    rng = np.random.default_rng(11)
    s = rng.uniform(0.5, 2.0, (K, P))
    found = [between_variance(sessions(rng, 0.0, s)[1], s) for _ in range(TRIALS)]
    dof = P * (K - 1)
    expected = stats.chi2.cdf(dof, dof)
    zero = np.mean([b.point == 0 for b in found])
    assert abs(zero - expected) <= 3 * np.sqrt(expected * (1 - expected) / TRIALS)
    assert all(b.tau2 > 0 and b.upper >= b.tau2 and b.dof == dof for b in found)


def test_between_variance_recovers_the_spread():
    """tau^2 with tau = 3 x the median noise: the mean Paule-Mandel estimate within 3 standard
    errors of the truth (nearly unbiased when tau dominates); the posterior mean within 10 %."""
    rng = np.random.default_rng(12)
    s = rng.uniform(0.5, 1.5, (K, P))
    tau = 3.0
    found = [between_variance(sessions(rng, tau, s)[1], s) for _ in range(TRIALS)]
    point = np.array([b.point for b in found])
    assert abs(point.mean() - tau**2) <= 3 * point.std() / np.sqrt(TRIALS)
    assert abs(np.mean([b.tau2 for b in found]) / tau**2 - 1) < 0.1


@pytest.mark.parametrize("k, p, tau", [(2, P, 2.0), (3, P, 2.0), (3, P, 0.5), (2, 3, 3.0),
                                       (3, 3, 1.0)])
def test_next_session_figure_covers_a_new_session(k, p, tau):
    """A new session's estimate lies within +-1.96 sqrt(sigma_next^2 + s_new^2) of the pooled
    mean in 95 % of the cases: over TRIALS pools, the coverage (mean of per-pool fractions) within
    the issue's honesty band 92-98 %; also for a triad's 3 parameters from 2 or 3 sessions."""
    rng = np.random.default_rng(13 + k + p)
    fractions = []
    for _ in range(TRIALS):
        s = rng.uniform(0.5, 1.5, (k + 1, p))
        x = rng.normal(0, 1, p) + rng.normal(0, tau, (k + 1, p)) + rng.normal(0, 1, (k + 1, p)) * s
        pooled = pool(x[:k], s[:k])
        z = (x[k] - pooled.mean) / np.hypot(pooled.sigma, s[k])
        fractions.append(np.mean(np.abs(z) <= stats.norm.ppf(0.975)))
    assert 0.92 <= np.mean(fractions) <= 0.98, np.mean(fractions)


def test_frame_fixed_entries_stay_exact():
    """Entries every session fixes at 0 +- 0 (the canonical frame's zeros of a) are left out of
    tau and stay 0 +- 0."""
    rng = np.random.default_rng(14)
    x = rng.normal(0, 1, (3, 5))
    s = np.ones((3, 5))
    x[:, 2], s[:, 2] = 0.0, 0.0
    pooled = pool(x, s)
    assert pooled.dof == 4 * 2 and pooled.sessions == 3
    assert pooled.mean[2] == 0 and pooled.sigma[2] == 0


def calibration(rng, bias_shift: np.ndarray, sensors=("ax", "ay", "az")) -> Calibration:
    """A triad's calibration file content from 20 simulated poses (biases estimated)."""
    a = np.array([[1.01, 0.002, -0.003], [0.0, 0.99, 0.004], [0.0, 0.0, 1.005]])
    v = rng.normal(size=(3, 20))
    v *= 9.81 / np.linalg.norm(v, axis=0)
    b = np.array([0.1, -0.2, 0.05]) + bias_shift
    z = a.T @ v + b[:, None] + rng.normal(0, 0.002, (3, 20))
    result = station.calibrate(z, magnitude=9.81, bias="estimate", sigma=0.002)
    return Calibration.from_result(result, "SN1", sensors, "m/s^2")


def test_combined_file_holds_the_next_session_figure(tmp_path):
    """Three sessions whose biases move by 0.02 m/s^2: the combined file's bias sigma includes
    that spread (>> one session's), loads with every check, and station combine writes it."""
    rng = np.random.default_rng(15)
    cals = [calibration(rng, rng.normal(0, 0.02, 3)) for _ in range(3)]
    names = ["a.cal.json", "b.cal.json", "c.cal.json"]
    combined = combine(cals, names)
    assert combined.fit["repeatability"]["bias"]["tau"] > 0
    for section in combined.fit["repeatability"].values():  # none taken as known at 0
        assert section["sessions"] == 3 and 0 < section["tau"] <= section["tau_upper"]
    assert np.all(combined.bias_sigma > 5 * np.median([c.bias_sigma for c in cals]))
    assert np.allclose(np.diag(combined.covariance),
                       np.r_[combined.a_sigma.ravel(), combined.bias_sigma] ** 2)
    for cal, name in zip(cals, names, strict=True):
        cal.save(tmp_path / name)
    out = tmp_path / "unit.cal.json"
    assert main(["combine", *(str(tmp_path / n) for n in names), "--out", str(out)]) == 0
    assert np.allclose(load(out).bias, combined.bias)


def test_other_sensors_are_refused_by_name(tmp_path):
    """Files of other sensors cannot be combined; the message names the file and what differs."""
    rng = np.random.default_rng(16)
    cals = [calibration(rng, np.zeros(3)),
            calibration(rng, np.zeros(3), sensors=("x", "y", "z"))]
    with pytest.raises(CalibrationFileError, match="two.cal.json has sensors"):
        combine(cals, ["one.cal.json", "two.cal.json"])
    with pytest.raises(CalibrationFileError, match="at least 2"):
        combine(cals[:1], ["one.cal.json"])
