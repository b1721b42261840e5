"""Extension `tone`, an open family (issue 32): the rate vector cones at a frequency that no named
effect has (a loose mount, a vibration of the fixture), fitted where the residuals' spectrum
peaks.

Model: the simulator's coning (station.model.effects.axis_wobble with a frequency f in Hz) added
to the motion: omega + rate sin(beta) (cos phi p_j + sin phi q_j), phi = 2 pi f t + phase_j (t the
time within the position, f < 0 turning against the table), scaled by the table rate as the
table's own coning is (zero at rest). Signature: a tone at |f| in each sensor, amplitude
rate sin(beta) |(a_i . p_j, a_i . q_j)|; the phases are nuisance (n of them, as axis_wobble's).

The frequency is the strongest in-plane point (turning with or against the table) of the residual
spectrum of the twin without it (station.diagnose.signature.residual_spectrum: steps of a
quarter of the resolution, up to 4 x the table rate): the likelihood ratio is the best of those
points, so its p-value is Bonferroni'd over them (`Fitted.searched`), and a named effect of the
same signature (axis_wobble at +1 x the table rate, which is not searched for) is preferred.
The frequency is then refined between that point's neighbours when that point alone is nearly
significant (`_worth_refining`; bounded search on the chi2 decrease, `REFINE` fits: the noise
can put the strongest point beside the tone's; the grid's
points are a quarter of the resolution apart, so the refinement adds little to what the
Bonferroni factor counts); its sigma from the decrease's curvature (a change of 1 in chi2).
The axial direction (a vibration along the table axis) is not modelled: it changes |omega|,
which coning does not.
"""

import numpy as np
from scipy.optimize import minimize_scalar

from station.diagnose import linear, signature
from station.diagnose.effects import Fitted, tone_null
from station.diagnose.goodness import log_sf
from station.model.effects import axis_wobble
from station.model.effects.axis_wobble import AxisWobble

GAPS = ("harmonics",)
"""Gap statistics (station.diagnose.gap) that hold this effect's signature: it is not named
while one of them stays unexplained (station.diagnose.select.settle)."""
STAGE = "motion"
REFINE = 10
"""Evaluations of the fit while its frequency is refined between the grid's neighbours."""
REFINE_BELOW = 0.1
"""The grid point's p-value (Bonferroni'd) below which the frequency is refined
(`_worth_refining`)."""
SENSES = (("with_table", 1.0), ("against_table", -1.0))
"""The spectrum's in-plane senses and the sign of the frequency each gives."""


def strongest(spectrum: dict) -> tuple:
    """(multiple of the table rate, signed: < 0 against the table; the grid's step; the points
    searched) at the strongest in-plane point of a residual spectrum."""
    grid = np.asarray(spectrum["frequency"])
    _, sign, i = max((float(spectrum[sense][i]), sign, i) for sense, sign in SENSES
                     for i in range(len(grid)))
    return sign * float(grid[i]), float(grid[0]), len(SENSES) * len(grid)


def _unit(ctx, rate, freq: float, phase_deg: float, rows: slice) -> np.ndarray:
    """(p, k, 3) the in-plane coning at sin(beta) = 1, frequency `freq` (Hz) and the given phase,
    at the positions `rows`."""
    d = ctx.data
    return axis_wobble.apply(rate[rows], d.angle[rows], d.t, ctx.orientation[rows],
                             AxisWobble(90.0, freq, phase_deg))


def fit(ctx, twin, r) -> Fitted:
    """sin(beta), the frequency and the phases; see the module docstring."""
    data = ctx.data
    multiple, step, searched = strongest(signature.residual_spectrum(data, ctx, twin))
    hz = data.c / (2 * np.pi)  # Hz per multiple of the table rate

    def fitted(m: float) -> tuple:
        return linear.phase_fit(data, r, lambda deg, rows: _unit(ctx, twin.rate, m * hz, deg,
                                                                  rows) @ ctx.a, ctx.sigma)

    free, phase, lf, _ = fitted(multiple)
    m_sigma = step / 2
    if _worth_refining(lf.reduction(), tone_null(free.h), searched):
        best = minimize_scalar(lambda m: -fitted(m)[2].reduction(), method="bounded",
                               bounds=(multiple - step, multiple + step),
                               options={"xatol": step / 100, "maxiter": REFINE})
        multiple = float(best.x)
        free, phase, lf, _ = fitted(multiple)
        m_sigma = _curvature_sigma(lambda m: fitted(m)[2].reduction(), multiple, step / 10)
    amp, amp_sigma = float(lf.theta[0, 0]), float(np.sqrt(lf.cov[0, 0, 0]))
    n = phase.size
    return Fitted(
        "tone",
        {"angle_deg": float(np.degrees(np.arcsin(np.clip(amp, -1, 1)))),
         "freq_hz": multiple * hz, "table_rate_multiple": multiple,
         "phase_deg": np.degrees(phase)},
        {"angle_deg": float(np.degrees(amp_sigma)), "freq_hz": m_sigma * abs(hz),
         "table_rate_multiple": m_sigma, "phase_deg": np.full(n, np.nan)},
        dof=n + 2,
        reduction=lf.reduction(),
        null=tone_null(free.h),
        searched=searched,
        units={"angle_deg": "deg", "freq_hz": "Hz", "table_rate_multiple": "",
               "phase_deg": "deg"},
        notes="an open family: coning at the strongest point of the residual spectrum, refined "
        "between its neighbours (f < 0 against the table), scaled by the table rate; the "
        "p-value is Bonferroni'd over the points searched; per-position phases are nuisance",
    )


def _worth_refining(gain: float, law: tuple, searched: int) -> bool:
    """Whether the grid point's chi2 decrease `gain` (null law scale * chi2(nu), Bonferroni'd over
    `searched` points) has a p-value below REFINE_BELOW: the refinement raises it by the power a
    point between two of the grid's loses, at most 5 %, and the decrease that p = REFINE_BELOW
    needs is some 30 % below the one any step's threshold needs (alpha / tests), so a tone the
    refinement could make significant is always refined, and a session without one saves its
    fits."""
    scale, nu = law
    return bool(np.log(searched) + log_sf(gain / scale, nu) < np.log(REFINE_BELOW))


def _curvature_sigma(gain, x: float, h: float) -> float:
    """1-sigma of x from the curvature of the chi2 decrease gain(x) at its maximum x (a parabola
    through x - h, x, x + h: the change of x that costs 1 of chi2); half of h when flat."""
    g0, g1, g2 = gain(x - h), gain(x), gain(x + h)
    curvature = (2 * g1 - g0 - g2) / h**2  # -d2 gain / dx2
    return float(np.sqrt(2.0 / curvature)) if curvature > 0 else h / 2


def apply(ctx, fitted: Fitted, omega: np.ndarray, rate: np.ndarray, rows: slice) -> np.ndarray:
    """Angular rate (p, k, 3) plus the fitted coning at the positions `rows`, per position."""
    out = omega.copy()
    amp = np.sin(np.radians(float(fitted.values["angle_deg"])))
    freq, d = float(fitted.values["freq_hz"]), ctx.data
    phases = fitted.value("phase_deg")
    for i, j in enumerate(d.positions(rows)):
        out[i:i + 1] += amp * axis_wobble.apply(rate[i:i + 1], d.angle[j:j + 1], d.t,
                                                ctx.orientation[j:j + 1],
                                                AxisWobble(90.0, freq, phases[j]))
    return out
