"""Extension `saturation`: the outputs are clipped at +-range.

The range is the rail of the session (the largest |count| times the count size,
`RotaryData.rail`), known to half a count; one parameter. The twin applies the clip to the
expected output as an expectation over the noise, E[clip(mu + e)] for e ~ N(0, sigma^2), so
that the calibration corrected by the twin is unbiased where the output sat on the rail only part
of the time.
Evidence comes from the pile-up at the rail (rails.deviance) and from the binned residuals.
"""

import numpy as np
from scipy.special import ndtr

from station.diagnose.effects import Fitted
from station.model.effects import saturation
from station.model.effects.saturation import Saturation

GAPS = ("rails",)
"""Gap statistics (station.diagnose.gap) that hold this effect's signature: it is not named
while one of them stays unexplained (station.diagnose.select.settle)."""
STAGE = "output"


def fit(ctx, twin, r) -> Fitted:
    """The range: the rail count times each sensor's count size."""
    data = ctx.data
    rng = data.rail * data.lsb
    return Fitted("saturation", {"range": rng}, {"range": data.lsb / 2}, dof=1,
                  notes="range = the largest |count| of the session")


def apply(ctx, fitted: Fitted, z: np.ndarray) -> np.ndarray:
    """Expected clipped output for outputs z + N(0, sigma^2); the noise-free limit is the
    simulator's clip (station.model.effects.saturation)."""
    rng = np.broadcast_to(fitted.value("range"), z.shape[-1:])
    sigma = np.broadcast_to(ctx.sigma, z.shape[-1:])
    if not np.all(sigma > 0):
        return saturation.apply(z, Saturation(tuple(rng)), rng)
    near = np.abs(z) > rng - 10 * sigma  # elsewhere the expectation is z to 1e-23
    zn, r, s = z[near], np.broadcast_to(rng, z.shape)[near], np.broadcast_to(sigma, z.shape)[near]
    lo, hi = (-r - zn) / s, (r - zn) / s
    out = z.copy()
    out[near] = (zn * (ndtr(hi) - ndtr(lo)) + s * (np.exp(-0.5 * lo**2) - np.exp(-0.5 * hi**2))
                 / np.sqrt(2 * np.pi) + r * (1 - ndtr(hi)) - r * ndtr(lo))
    return out
