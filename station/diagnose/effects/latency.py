"""Extension `latency`: channel i reports the signal of t - delay_i.

Signature per sensor: -delay_i ds_i/dt, nonzero only while the table accelerates (negative on
spin-up, positive on spin-down for a positive projection). The unit signature is the simulator's
delay of one sample period, divided by that period.
"""

import numpy as np

from station.diagnose import linear
from station.diagnose.effects import Fitted
from station.model.effects import latency
from station.model.effects.latency import Latency

GAPS = ("transients",)
"""Gap statistics (station.diagnose.gap) that hold this effect's signature: it is not named
while one of them stays unexplained (station.diagnose.select.settle)."""
STAGE = "sensed"


def fit(ctx, prediction, r) -> Fitted:
    """delay (m,) in seconds by least squares per sensor."""
    data, s = ctx.data, prediction.s
    step = 1.0 / data.fs
    unit = latency.apply(s, data.t, Latency(step))
    unit -= s  # in place: one signal of the session's size at a time
    unit /= step
    lf = linear.fit(data, r, [unit], ctx.sigma, "sensor")
    return Fitted(
        "latency",
        {"delay": lf.theta[:, 0]},
        {"delay": np.sqrt(lf.cov[:, 0, 0])},
        dof=lf.theta.shape[0],
        reduction=lf.reduction(),
    )


def params(fitted: Fitted) -> Latency:
    """The simulator's parameters of the fitted delays, for the output chain
    (station.model.sensing)."""
    return Latency(tuple(fitted.value("delay")))
