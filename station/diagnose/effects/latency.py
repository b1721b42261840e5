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


def fit(ctx, twin, r) -> Fitted:
    """delay (m,) in seconds by least squares per sensor."""
    data = ctx.data
    step = 1.0 / data.fs

    def unit(rows: slice) -> np.ndarray:
        """The signature of a delay of one sample per second, at the positions `rows`."""
        s = twin.sensed(rows)
        x = latency.apply(s, data.t, Latency(step))
        x -= s  # in place: one signal of a few positions' size at a time
        x /= step
        return x

    lf = linear.fit_binned(r, [linear.centred_signature(data, unit)],
                           linear.weights(data, ctx.sigma), "sensor")
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
