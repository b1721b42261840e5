"""Extension `polynomial`, an open family (issue 32): each sensor's output bends with its signal
by a polynomial whose order the data choose: s_i + sum_{q=2..Q} c_q,i s_i^q.

Signature per sensor: the powers s_i(t)^q (the rotating window moves by c_q,i (a_i . v_j)^q, the
static window not at all); linear in the c, fitted per sensor with every power up to the order
Q. Q is searched over `TOPS` (2, 3) and the one of smallest p-value kept: its p-value is
Bonferroni'd over them (`Fitted.searched`), so the named scale_nonlinearity (Q = 2, no search)
is preferred for a quadratic. The odd powers are partly a scale factor, which the calibration
takes; the family describes what it leaves. The model is the simulator's
(station.model.effects.polynomial, up to the fifth power).
"""

import numpy as np

from station.diagnose import linear
from station.diagnose.effects import READ_FROM_M, Fitted
from station.diagnose.goodness import log_sf
from station.model.effects import polynomial
from station.model.effects.polynomial import ORDERS, Polynomial

GAPS = ("averaged",)
"""Gap statistics (station.diagnose.gap) that hold this effect's signature: it is not named
while one of them stays unexplained (station.diagnose.select.settle)."""
UNREADABLE_WITH = READ_FROM_M
STAGE = "sensed"
TOPS = (2, 3)
"""The orders searched: the highest power of the signal. 2 is the named scale_nonlinearity's
model, which pays no search and so is named first for a quadratic; with it left out the family
still finds the quadratic without an odd power beside it (an odd power is partly a scale factor:
its noise moves the calibration's scales). Higher orders over-fit what they do not model: with a
table rate error left out of the candidates (m = 12, seeds 12002-12003), powers up to 4 or 5
were named and the calibration's eps / bound went from 1.36 to 2.55-3.03, where up to 3 they
are said AMBIGUOUS with the even terms and nothing is corrected. Orders beyond 3 need a nested
order selection and odd powers without their straight line first (not done)."""


def fit(ctx, twin, r) -> Fitted:
    """The coefficients (per sensor) of the powers 2 .. Q, Q the order of smallest p-value."""
    units = [Polynomial(**{f"c{q}": 1.0}) for q in ORDERS]
    terms, peak = linear.sensed_signatures(ctx, twin, polynomial.apply, units)
    w = linear.weights(ctx.data, ctx.sigma)
    m = peak.shape[0]
    fits = {top: linear.fit_binned(r, terms[:top - 1], w, "sensor") for top in TOPS}
    top = min(TOPS, key=lambda q: log_sf(fits[q].reduction(), m * (q - 1)))
    lf = fits[top]
    values = {f"c{q}": lf.theta[:, i] for i, q in enumerate(ORDERS[:top - 1])}
    sigma = {f"c{q}": np.sqrt(lf.cov[:, i, i]) for i, q in enumerate(ORDERS[:top - 1])}
    return Fitted(
        "polynomial",
        {**values, "order": top, "peak_signal": peak},
        {**sigma, "order": np.nan, "peak_signal": np.full(peak.shape, np.nan)},
        dof=m * (top - 1),
        reduction=lf.reduction(),
        notes=f"an open family: the powers 2 .. {top} of each sensor's signal, the order the one "
              f"of smallest p-value of {TOPS}, its p-value Bonferroni'd over them",
        units={"order": ""},
        searched=len(TOPS),
    )


def params(fitted: Fitted) -> Polynomial:
    """The simulator's parameters of the fitted polynomial, for the output chain
    (station.model.sensing)."""
    return Polynomial(**{k: tuple(fitted.value(k)) for k in fitted.values
                         if k.startswith("c")})
