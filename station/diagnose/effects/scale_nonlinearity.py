"""Extension `scale_nonlinearity`: sensor i outputs s_i + k2_i s_i^2.

Signature per sensor: s_i(t)^2 (the rotating window moves by k2_i (a_i . v_j)^2, the static
window not at all); linear in k2, fitted per sensor.
"""


from station.diagnose import linear
from station.diagnose.effects import READ_FROM_M, Fitted, sensed_fit
from station.model.effects import scale_nonlinearity
from station.model.effects.scale_nonlinearity import ScaleNonlinearity

GAPS = ("averaged",)
"""Gap statistics (station.diagnose.gap) that hold this effect's signature: it is not named
while one of them stays unexplained (station.diagnose.select.settle)."""
UNREADABLE_WITH = READ_FROM_M
STAGE = "sensed"


def fit(ctx, twin, r) -> Fitted:
    """k2 (m,) by least squares per sensor on the signature of unit k2."""
    lf, peak = linear.sensed_term(ctx, twin, r, scale_nonlinearity.apply, ScaleNonlinearity(1.0))
    return sensed_fit("scale_nonlinearity", "k2", lf, peak)


def params(fitted: Fitted) -> ScaleNonlinearity:
    """The simulator's parameters of the fitted term, for the output chain
    (station.model.sensing)."""
    return ScaleNonlinearity(tuple(fitted.value("k2")))
