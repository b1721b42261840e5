"""Is a fit consistent with the noise of its readings? The quality gate a calibration passes
before it is written as good (`station solve`, `station record --solve`, `station replay`) and
the fit warnings of the session report.

Two tests, each at a stated false-alarm level when the model holds:
- chi2 of the normalised residuals against chi2(dof): the upper tail beyond `CHI2_P` / 2 means the
  readings disagree with the model by more than their noise (a disturbed window, readings timed
  wrongly, an effect the model lacks);
- each normalised residual r_ij / sigma_ij against N(0, 1), Bonferroni over the m n residuals at
  `FALSE_ALARMS` expected false flags per fit: an outlying sensor reading at one position.
Neither applies when sigma was estimated from the residuals (chi2/dof is then 1 by construction).

Poses placed by hand (`pose_term=True`: iron, free-static, imported recordings) scatter beyond the
white noise: they settle, the noise is coloured, the unit is re-seated. The fit then estimates a
per-pose error term (`CalibrationResult.pose_sigma`, docs/solvers.md "Honest uncertainties") and
its 1-sigma includes it. For such fits the residuals are judged against the total noise
sqrt(sigma^2 + pose_sigma^2): chi2 is 1 per degree of freedom by construction, so it is not
tested, and the term is stated in `notes`. A single disturbed pose inflates that term and bends the
fit's direction of the pose towards its readings (a triad's pose keeps one degree of freedom of
three), so the poses are also tested one by one against a robust scale: each pose's sum of squared
normalised residuals, over the median of them (scaled by the median of chi2 with m - 2 degrees of
freedom: its readings less the pose's two direction angles), against chi2(m - 2), Bonferroni over
the poses at `FALSE_ALARMS`. Table positions (rotary) keep the white-noise
chi2 test: a disturbed window there is a fault, not a property of the data.
"""

import math
from dataclasses import dataclass, field

import numpy as np

from station.solve.tails import chi2_isf, chi2_sf, normal_isf

CHI2_P = 1e-3
"""Two-sided probability below which chi2/dof is inconsistent with the model."""
FALSE_ALARMS = 0.01
"""Expected number of false outlier flags per fit when the model holds."""


@dataclass(frozen=True)
class FitCheck:
    """The verdict on one fit.

    chi2_per_dof, p_high : chi2 / dof and P(chi2 >= observed) under the model (None: untestable)
    limit                : |r / sigma| beyond which a residual is an outlier
    outliers             : (sensor index, position index, r / sigma) beyond `limit`
    problems             : why the fit is suspect, in words; empty when it is good
    notes                : what the fit found that is not a problem (a per-pose error term)
    """

    chi2_per_dof: float
    p_high: float | None
    limit: float
    outliers: list = field(default_factory=list)
    problems: list = field(default_factory=list)
    notes: list = field(default_factory=list)

    @property
    def status(self) -> str:
        return "suspect" if self.problems else "good"


def check_fit(result, names=None, pose_term: bool = False) -> FitCheck:
    """Test `result` (a `station.solve.calibrate.CalibrationResult`); `names` of the sensors for
    the messages (default s1..sm); `pose_term`: hand-placed poses, judged against the total noise
    when the fit found a per-pose error term (module docstring)."""
    m, n = result.residuals.shape
    names = list(names) if names is not None else [f"s{i + 1}" for i in range(m)]
    ratio = result.chi2 / result.dof if result.dof else math.nan
    limit = normal_isf(FALSE_ALARMS / (2 * m * n))
    if result.sigma_estimated or result.dof <= 0:
        return FitCheck(ratio, None, limit)
    p_high = chi2_sf(result.dof, result.chi2)
    pose = getattr(result, "pose_sigma", None) if pose_term else None
    z = result.residuals / np.hypot(result.sigma, pose) if pose else result.normalised_residuals
    outliers = [(int(i), int(j), float(z[i, j])) for i, j in zip(*np.nonzero(np.abs(z) > limit),
                                                                  strict=True)]
    problems, notes = [], []
    if pose:
        notes.append(f"the poses scatter beyond the white noise (chi2/dof {ratio:.2f}): a per-pose "
                     f"error of {pose:.2g} is in the 1-sigma and the outlier test")
        odd = odd_poses(z)
        if odd:
            problems.append(f"pose(s) {', '.join(str(j + 1) for j in odd)} disagree with the "
                            "others by more than the poses scatter (a knock or a slip during the "
                            "pose?)")
    elif p_high < CHI2_P / 2:
        problems.append(f"chi2/dof = {ratio:.2f} where 1 +- {math.sqrt(2 / result.dof):.2f} is "
                        f"expected (p = {p_high:.1e}): the readings disagree with the model by "
                        "more than their noise")
    if outliers:
        problems.append(f"residual outliers beyond {limit:.1f} sigma: "
                        f"{outlier_words(outliers, names)}")
    return FitCheck(ratio, p_high, limit, outliers, problems, notes)


def odd_poses(z) -> list:
    """0-based poses whose normalised residuals z (m, n) stand out of the others' robust scale
    (module docstring)."""
    m, n = z.shape
    k = max(m - 2, 1)
    per_pose = np.sum(z ** 2, axis=0)
    scale = np.median(per_pose) / chi2_isf(k, 0.5)  # chi2 median
    if not scale > 0:
        return []
    return np.flatnonzero(per_pose / scale > chi2_isf(k, FALSE_ALARMS / n)).tolist()


def outlier_words(outliers, names) -> str:
    """The first 8 outliers in words ("g3 at position 5 (+6.1 sigma), ..."), and how many more."""
    listed = ", ".join(f"{names[i]} at position {j + 1} ({v:+.1f} sigma)"
                       for i, j, v in outliers[:8])
    return listed + (f" and {len(outliers) - 8} more" if len(outliers) > 8 else "")
