"""Extension `axis_wobble`: the table axis cones once per revolution by a half-angle beta.

Signature: rate(t) sin(beta) a_i . (cos phi p_j + sin phi q_j) with phi = theta + phase_j, a tone
turning with the table and scaled by its rate (zero at rest, unlike the Earth rate). The phase of
each position in the unit frame depends on the unknown mounting azimuth: n + 1 parameters (beta
and the phases). Only coning tied to the table angle (the simulator's freq = None) is modelled.
"""

import numpy as np

from station.diagnose import linear
from station.diagnose.effects import Fitted, tone_null
from station.model.effects import axis_wobble
from station.model.effects.axis_wobble import AxisWobble

GAPS = ("harmonics",)
"""Gap statistics (station.diagnose.gap) that hold this effect's signature: it is not named
while one of them stays unexplained (station.diagnose.select.settle)."""
STAGE = "motion"


def _tone(ctx, rate, phase_deg: float, rows: slice) -> np.ndarray:
    """(len(rows), k, m) sensed signal of the coning part at sin(beta) = 1 and the given phase,
    at the positions `rows`."""
    d = ctx.data
    omega = axis_wobble.apply(rate[rows], d.angle[rows], d.t, ctx.orientation[rows],
                              AxisWobble(90.0, None, phase_deg))
    return omega @ ctx.a


def fit(ctx, twin, r) -> Fitted:
    """beta (degrees) and the phases; see the module docstring."""
    free, phase, lf, _ = linear.phase_fit(
        ctx.data, r, lambda deg, rows: _tone(ctx, twin.rate, deg, rows), ctx.sigma)
    amp, amp_sigma = float(lf.theta[0, 0]), float(np.sqrt(lf.cov[0, 0, 0]))
    n = phase.size
    return Fitted(
        "axis_wobble",
        {"angle_deg": float(np.degrees(np.arcsin(np.clip(amp, -1, 1)))),
         "phase_deg": np.degrees(phase)},
        {"angle_deg": float(np.degrees(amp_sigma)), "phase_deg": np.full(n, np.nan)},
        dof=n + 1,
        reduction=lf.reduction(),
        null=tone_null(free.h),
        notes="per-position phases are nuisance (unknown mounting azimuth); coning once per "
        "table revolution only",
    )


def apply(ctx, fitted: Fitted, omega: np.ndarray, rate: np.ndarray, rows: slice) -> np.ndarray:
    """Angular rate (p, k, 3) of the coning table axis at the positions `rows`, per position
    (station.model.effects.axis_wobble).

    Replaces the nominal rate(t) u_j, so it comes before the Earth rate, as in the simulator.
    """
    out = np.empty_like(omega)
    beta = float(fitted.values["angle_deg"])
    d = ctx.data
    for i, j in enumerate(d.positions(rows)):
        out[i:i + 1] = axis_wobble.apply(rate[i:i + 1], d.angle[j:j + 1], d.t,
                                         ctx.orientation[j:j + 1],
                                         AxisWobble(beta, None, fitted.value("phase_deg")[j]))
    return out
