"""The final goodness-of-fit test: does white noise explain every gap the last model leaves?

Each gap statistic g_s (station.diagnose.gap, station.diagnose.static_report) is a mean of
squared normalised residual features, so that under the model and white noise g_s dof_s ~
chi2(dof_s). The test reads every statistic against that law and controls the family-wise error
by Bonferroni: a statistic fails when its upper-tail p-value is below alpha / (statistics
tested). A failed statistic is an `unexplained` gap: the library's effects, as fitted, do not
account for it, whatever was named (station.diagnose.select).
"""

import numpy as np
from scipy.special import gammaln
from scipy.stats import chi2 as chi2_law


def log_sf(x: float, nu: float) -> float:
    """log P(chi2(nu) > x); beyond double precision, the leading term of the incomplete gamma
    function's asymptotic series (so that overwhelming evidence still ranks)."""
    out = float(chi2_law.logsf(x, nu))
    if np.isfinite(out):
        return out
    return float((nu / 2 - 1) * np.log(x / 2) - x / 2 - gammaln(nu / 2))


def test(gap: dict, dof: dict, alpha: float, extra=None) -> dict:
    """The test of the gaps `gap` ({statistic: value}) with their degrees of freedom `dof`, and
    of `extra` tests ({name: {"gap", "dof", "log10_p"}}, their own p-values): per statistic its
    gap, dof and log10 p, the Bonferroni threshold of log10 p and the list of failed statistics
    (worst first)."""
    tested = {k: (float(g), int(dof[k])) for k, g in gap.items()
              if k in dof and dof[k] > 0 and np.isfinite(g)}
    stats = {k: {"gap": g, "dof": d, "log10_p": log_sf(g * d, d) / np.log(10)}
             for k, (g, d) in tested.items()}
    stats.update(extra or {})
    threshold = float(np.log10(alpha / max(len(stats), 1)))
    failed = sorted((k for k, s in stats.items() if s["log10_p"] < threshold),
                    key=lambda k: stats[k]["log10_p"])
    return {"alpha": alpha, "threshold_log10_p": threshold, "statistics": stats,
            "failed": failed}
