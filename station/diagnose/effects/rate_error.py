"""Extension `rate_error`: the table's true rate is the command times 1 + delta_j per position.

Signature: position j's whole rotation signal scales by delta_j, so the residual is delta_j times
the twin's sensed signal s_j(t). The common part of the delta_j (the simulator's `scale`) is
indistinguishable from a common scale factor of all sensors (Remark 2 of Rupniewski), so the
fit keeps sum(delta_j) = 0 and reports `spread` (the standard deviation of the delta_j).
"""

import numpy as np

from station.diagnose import linear
from station.diagnose.effects import Fitted
from station.sim.effects import rate_error

STAGE = "rate"


def fit(ctx, prediction, r) -> Fitted:
    """delta_j (n,) by least squares per position on the signature s_j(t), centred to sum 0."""
    lf = linear.fit(ctx.data, r, [prediction.s], ctx.sigma, "position")
    delta = lf.theta[:, 0] - lf.theta[:, 0].mean()
    n = delta.size
    spread = float(np.std(delta, ddof=1))
    return Fitted(
        "rate_error",
        {"factors": 1.0 + delta, "spread": spread},
        {"factors": np.sqrt(lf.cov[:, 0, 0]), "spread": spread / np.sqrt(2 * (n - 1))},
        dof=n - 1,
        reduction=lf.reduction(delta[:, None]),
        notes="the common rate error (scale) is not separable from a common scale factor",
    )


def apply(ctx, fitted: Fitted, rate: np.ndarray) -> np.ndarray:
    """Table rate (n, k) times each position's factor (station.sim.effects.rate_error)."""
    return rate_error.apply(rate[..., None], fitted.value("factors"))[..., 0]
