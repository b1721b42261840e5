"""Extension `bias_drift`: warm-up exp(-t / warmup_tau) and heating H(t) added to the biases.

Given the two time constants the offsets are linear in warmup_i and heating_i (per sensor); the
time constants are chosen on a logarithmic grid by the largest decrease of chi2, and their
uncertainty is the span of grid values within 1 of that decrease (a profile likelihood).
Signatures against the per-position bias of Eq. (18): a warm-up shows as trends within each
position fading over the session, heating as the offset H(t) builds up while the table spins.
"""

import numpy as np

from station.diagnose import linear
from station.diagnose.effects import Fitted
from station.model.effects import bias_drift
from station.model.effects.bias_drift import BiasDrift

GAPS = ("static", "trend")
"""Gap statistics (station.diagnose.gap) that hold this effect's signature: it is not named
while one of them stays unexplained (station.diagnose.select.settle)."""
STAGE = "offset"
WARMUP_TAUS = np.geomspace(30.0, 3000.0, 7)
HEATING_TAUS = np.geomspace(10.0, 300.0, 6)


def _unit(ctx, rate, warmup_tau, heating_tau, which):
    """(n, k, 1) offset of unit warm-up or unit heating."""
    p = BiasDrift(warmup=float(which == "warmup"), warmup_tau=warmup_tau,
                  heating=float(which == "heating"), heating_tau=heating_tau)
    return bias_drift.apply(ctx.data.t_session, rate, p)


def fit(ctx, prediction, r) -> Fitted:
    """warmup, heating (m,) and the time constants from the grid; see the module docstring."""
    data, rate = ctx.data, prediction.rate
    warm = {tau: linear.centred(data, _unit(ctx, rate, tau, 1.0, "warmup"))
            for tau in WARMUP_TAUS}
    heat = {tau: linear.centred(data, _unit(ctx, rate, 1.0, tau, "heating"))
            for tau in HEATING_TAUS}
    rb, w = linear.centred(data, r), linear.weights(data, ctx.sigma)
    grid = {
        (tw, th): linear.fit_binned(rb, [warm[tw], heat[th]], w, "sensor")
        for tw in WARMUP_TAUS for th in HEATING_TAUS
    }
    gains = {key: lf.reduction() for key, lf in grid.items()}
    (tw, th), best = max(gains.items(), key=lambda item: item[1])
    lf = grid[(tw, th)]
    near = [key for key, g in gains.items() if g >= best - 1.0]
    m = lf.theta.shape[0]
    return Fitted(
        "bias_drift",
        {"warmup": lf.theta[:, 0], "warmup_tau": tw, "heating": lf.theta[:, 1],
         "heating_tau": th},
        {"warmup": np.sqrt(lf.cov[:, 0, 0]), "heating": np.sqrt(lf.cov[:, 1, 1]),
         "warmup_tau": _span([k[0] for k in near]), "heating_tau": _span([k[1] for k in near])},
        dof=2 * m + 2,
        reduction=best,
        notes="time constants from a grid; their sigma is half the span of grid values within "
        "a chi2 decrease of 1 of the best",
    )


def _span(values) -> float:
    """Half the span of the grid values (0 when one grid value stands out)."""
    return 0.5 * (max(values) - min(values))


def params(fitted: Fitted) -> BiasDrift:
    """The simulator's parameters of the fitted drift, for the output chain
    (station.model.sensing)."""
    return BiasDrift(
        warmup=tuple(fitted.value("warmup")), warmup_tau=float(fitted.values["warmup_tau"]),
        heating=tuple(fitted.value("heating")), heating_tau=float(fitted.values["heating_tau"]),
    )
