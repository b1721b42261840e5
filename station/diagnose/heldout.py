"""Never a worse calibration: a correction is applied only when it improves a held-out check.

The check is the leave-one-position-out prediction of the Eq. (18) readings M (free-static:
the accelerometer's interval means, less the bias the calibration estimates): for each
position j the calibration of the other positions (station.calibrate, with the same options)
predicts M_j = a^T v_j, v_j fitted to M_j under the magnitude constraint |v_j| = c (soft, with
the spread s, when the calibration models a rate spread). Linearised about the free
least-squares fit v0 = (a W a^T)^-1 a W M_j (W = diag(sigma_j^-2)), the held-out chi2 of j is

    |M_j - a^T v0|_W^2 + (|v0| - c)^2 / (u^T (a W a^T)^-1 u + (c s)^2),   u = v0 / |v0|,

and the score is its sum over the positions. The readings corrected by the fitted extensions
(station.diagnose.model.readings) are used for the calibration only when their score is below
that of the uncorrected readings; otherwise the correction is reported and not applied.
"""

import numpy as np

from station.solve.calibrate import calibrate


def _predicted_chi2(a: np.ndarray, y: np.ndarray, sigma: np.ndarray, c: float,
                    spread: float) -> float:
    """Held-out chi2 of one position's readings y (m,) by a calibration a (d, m); see the
    module docstring."""
    w = 1.0 / sigma**2
    h = (a * w) @ a.T
    cov = np.linalg.inv(h)
    v0 = cov @ (a @ (w * y))
    radius = float(np.linalg.norm(v0))
    u = v0 / radius
    free = float(np.sum(w * (y - a.T @ v0) ** 2))
    return free + (radius - c) ** 2 / (float(u @ cov @ u) + (c * spread) ** 2)


def score(readings: np.ndarray, c: float, sigma: np.ndarray, options: dict) -> float:
    """Sum over positions of the held-out chi2 of the readings M (m, n) with standard errors
    sigma (m, n), each position predicted by the calibration of the others (`options` of
    station.calibrate; with an estimated bias, the readings less it)."""
    n = readings.shape[1]
    spread = float(options.get("magnitude_spread") or 0.0)
    total = 0.0
    for j in range(n):
        keep = np.arange(n) != j
        cal = calibrate(readings[:, keep], c, sigma=sigma[:, keep], **options)
        bias = 0.0 if cal.bias is None else cal.bias
        total += _predicted_chi2(np.asarray(cal.a, float), readings[:, j] - bias, sigma[:, j],
                                 c, spread)
    return total
