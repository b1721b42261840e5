"""Extension `scale_asymmetry`: sensor i outputs s_i + k_i |s_i| (its scale 1 + k_i for positive
signals, 1 - k_i for negative ones).

Signature per sensor: |s_i(t)| (the rotating window moves by k_i |a_i . v_j|, the static window
not at all); linear in k, fitted per sensor. At one rate magnitude it is nearly scale_nonlinearity's
signature (both even in the signal), so the two are often indistinguishable on a session: the
diagnosis then says so and corrects with neither (station.diagnose.select, `TOLD_APART`).
"""


from station.diagnose import linear
from station.diagnose.effects import READ_FROM_M, Fitted, sensed_fit
from station.model.effects import scale_asymmetry
from station.model.effects.scale_asymmetry import ScaleAsymmetry

GAPS = ("averaged",)
"""Gap statistics (station.diagnose.gap) that hold this effect's signature: it is not named
while one of them stays unexplained (station.diagnose.select.settle)."""
UNREADABLE_WITH = READ_FROM_M
STAGE = "sensed"
TOLD_APART = {"scale_nonlinearity": "positions at a second table rate (|s| doubles with the rate, "
                                    "s^2 quadruples)"}
"""Candidates whose signature can match this one on a session -> what to record to tell them
apart (station.diagnose.select: an ambiguous pair)."""


def fit(ctx, twin, r) -> Fitted:
    """k (m,) by least squares per sensor on the signature of unit k."""
    lf, peak = linear.sensed_term(ctx, twin, r, scale_asymmetry.apply, ScaleAsymmetry(1.0))
    return sensed_fit("scale_asymmetry", "k", lf, peak, {"k": ""})


def params(fitted: Fitted) -> ScaleAsymmetry:
    """The simulator's parameters of the fitted term, for the output chain
    (station.model.sensing)."""
    return ScaleAsymmetry(tuple(fitted.value("k")))
