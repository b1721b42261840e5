"""Effect `saturation`: the output is clipped at the sensor's range.

Parameters
----------
range : scalar, (m,) or None, SI output units
    Full scale +-range; None uses the sensor unit's `output_range`.

Signature: every sample whose true output lies beyond the range reads exactly the rail, so
samples pile up on the rail count.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Saturation:
    """Clip the outputs at +-range (None: the unit's output range)."""

    range: float | tuple | None = None


def apply(z: np.ndarray, p: Saturation, unit_range: np.ndarray) -> np.ndarray:
    """Outputs z (..., m) clipped to +-range."""
    r = np.asarray(unit_range if p.range is None else p.range, float)
    if not np.all(np.isfinite(r)):
        raise ValueError(
            "saturation needs a finite range: give the unit an output_range "
            "or the effect a range= parameter"
        )
    return np.clip(z, -r, r)
