"""Extension `bias_drift`: warm-up exp(-t / warmup_tau) and heating H(t) added to the biases.

Given the two time constants the offsets are linear in warmup_i and heating_i (per sensor); the
time constants are chosen on a logarithmic grid by the largest decrease of chi2, then refined
between the grid's points (Nelder-Mead on their logarithms, within the grid's span: a strong
warm-up whose tau falls between two points left its own `static` gap open, issue 32), and their
uncertainty is the span of grid values within 1 of that decrease (a profile likelihood).
Signatures against the per-position bias of Eq. (18): a warm-up shows as trends within each
position fading over the session, heating as the offset H(t) builds up while the table spins.
"""

import numpy as np
from scipy.optimize import minimize

from station.diagnose import linear, walk
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


def fit(ctx, twin, r) -> Fitted:
    """warmup, heating (m,) and the time constants from the grid; see the module docstring."""
    data, rate = ctx.data, twin.rate
    warm = {tau: linear.centred(data, _unit(ctx, rate, tau, 1.0, "warmup"))
            for tau in WARMUP_TAUS}
    heat = {tau: linear.centred(data, _unit(ctx, rate, 1.0, tau, "heating"))
            for tau in HEATING_TAUS}
    rb, w = r, linear.weights(data, ctx.sigma)
    grid = {
        (tw, th): linear.fit_binned(rb, [warm[tw], heat[th]], w, "sensor")
        for tw in WARMUP_TAUS for th in HEATING_TAUS
    }
    gains = {key: lf.reduction() for key, lf in grid.items()}
    near = [key for key, g in gains.items() if g >= max(gains.values()) - 1.0]
    (tw, th), lf = _refined(ctx, rate, rb, w, max(gains, key=gains.get))
    best = lf.reduction()
    m = lf.theta.shape[0]
    return Fitted(
        "bias_drift",
        {"warmup": lf.theta[:, 0], "warmup_tau": tw, "heating": lf.theta[:, 1],
         "heating_tau": th},
        {"warmup": np.sqrt(lf.cov[:, 0, 0]), "heating": np.sqrt(lf.cov[:, 1, 1]),
         "warmup_tau": _span([k[0] for k in near]), "heating_tau": _span([k[1] for k in near])},
        dof=2 * m + 2,
        reduction=best,
        notes="time constants from a grid, refined between its points; their sigma is half the "
        "span of grid values within a chi2 decrease of 1 of the best",
    )


def beyond_walk(current, fitted: Fitted) -> float:
    """log10 p of the fitted drift (its warm-up and heating at the static windows, the time
    constants as fitted) in the static windows' mean residuals of `current`, the model without
    it, against a bias random walk per sensor (station.diagnose.walk)."""
    ctx = current.ctx
    s0, s1 = ctx.data.windows["static"]
    shapes = [_unit(ctx, current.twin.rate, fitted.values["warmup_tau"],
                    fitted.values["heating_tau"], which)[:, s0:s1, 0].mean(1)
              for which in ("warmup", "heating")]
    return walk.static_log10_p(current, np.stack(shapes, 1), 2)


def _refined(ctx, rate, rb, w, start: tuple) -> tuple:
    """((warmup_tau, heating_tau), LinearFit) of the largest chi2 decrease from the grid point
    `start`, the time constants free within the grids' spans (Nelder-Mead on their logs)."""
    data = ctx.data

    def fitted(log_tau):
        tw, th = np.exp(log_tau)
        return linear.fit_binned(rb, [linear.centred(data, _unit(ctx, rate, tw, 1.0, "warmup")),
                                      linear.centred(data, _unit(ctx, rate, 1.0, th, "heating"))],
                                 w, "sensor")

    bounds = [np.log([WARMUP_TAUS[0], WARMUP_TAUS[-1]]), np.log([HEATING_TAUS[0],
                                                                  HEATING_TAUS[-1]])]
    sol = minimize(lambda x: -fitted(x).reduction(), np.log(start), method="Nelder-Mead",
                   bounds=bounds, options={"xatol": 1e-3, "fatol": 0.01, "maxfev": 80})
    return tuple(np.exp(sol.x)), fitted(sol.x)


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
