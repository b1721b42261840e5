"""Extension `earth_rate`: the Earth's rotation adds to the table's rate.

Signature: the horizontal Earth rate N turns with the table angle theta in the table frame, so
each position shows a tone a_i . C_j (N cos(h_j - theta), N sin(h_j - theta), 0), turning in the
opposite sense to the table (axis_wobble turns with it). The heading h_j of each position in the
unit frame depends on how the unit was mounted, which the data do not say, so each position has
its own heading: n + 1 parameters (N and the h_j). The vertical part U only shifts each
position's bias by U a_i . u_j; it is estimated afterwards from the position biases against
orientation with one bias per sensor, and gives the latitude atan2(U, N).
"""

import numpy as np

from station.diagnose import linear
from station.diagnose.effects import Fitted, tone_null
from station.model.effects import earth_rate
from station.model.effects.earth_rate import EarthRate

GAPS = ("static", "harmonics")
"""Gap statistics (station.diagnose.gap) that hold this effect's signature: it is not named
while one of them stays unexplained (station.diagnose.select.settle)."""
STAGE = "motion"


def _tone(ctx, heading_deg: float, rows: slice) -> np.ndarray:
    """(len(rows), k, m) sensed signal of a unit horizontal Earth rate at the given heading, at
    the positions `rows`."""
    angle = ctx.data.angle[rows]
    zero = np.zeros(angle.shape + (3,))
    omega = earth_rate.apply(zero, ctx.orientation[rows], angle, EarthRate(0.0, heading_deg, 1.0))
    return omega @ ctx.a


def fit(ctx, twin, r) -> Fitted:
    """N (horizontal rate), the headings h_j and U; see the module docstring."""
    free, heading, lf, static = linear.phase_fit(
        ctx.data, r, lambda deg, rows: _tone(ctx, deg, rows), ctx.sigma)
    horizontal = float(lf.theta[0, 0])
    vertical, vertical_sigma = _vertical(ctx, r[1], horizontal * static)
    n = heading.size
    vertical_gain = vertical**2 / vertical_sigma**2
    return Fitted(
        "earth_rate",
        {"horizontal_rate": horizontal, "vertical_rate": vertical,
         "latitude_deg": float(np.degrees(np.arctan2(vertical, horizontal))),
         "rate": float(np.hypot(horizontal, vertical)), "heading_deg": np.degrees(heading)},
        {"horizontal_rate": float(np.sqrt(lf.cov[0, 0, 0])), "vertical_rate": vertical_sigma,
         "latitude_deg": np.nan, "rate": np.nan, "heading_deg": np.full(n, np.nan)},
        dof=n + 2,
        reduction=lf.reduction() + vertical_gain,
        null=_shift(tone_null(free.h)),
        notes="per-position headings are nuisance (unknown mounting azimuth); the vertical "
        "rate comes from the static means and assumes constant biases",
    )


def _vertical(ctx, means: np.ndarray, horizontal: np.ndarray) -> tuple[float, float]:
    """U and its sigma from the static means (n, m) of the data minus the twin without the
    Earth rate, b_i + a_i . (U u_j + horizontal part), centred or not (b_i takes a constant per
    sensor); `horizontal` (n, m) that part's static means."""
    s0, s1 = ctx.data.windows["static"]
    k = s1 - s0
    b = means - horizontal  # (n, m)
    n, m = b.shape
    proj = (ctx.orientation[:, :, 2] @ ctx.a)  # (n, m): a_i . u_j
    x = np.zeros((n * m, m + 1))
    x[np.arange(n * m), np.tile(np.arange(m), n)] = 1.0
    x[:, m] = proj.ravel()
    w = np.tile(1 / (ctx.sigma**2 / k + ctx.data.kept), n)
    h = x.T @ (w[:, None] * x)
    theta = np.linalg.solve(h, x.T @ (w * b.ravel()))
    return float(theta[m]), float(np.sqrt(np.linalg.inv(h)[m, m]))


def _shift(law: tuple) -> tuple:
    """The tone fit's law (scale, nu) plus one chi2(1) for the vertical rate, moment-matched."""
    scale, nu = law
    mean, var = scale * nu + 1, 2 * scale**2 * nu + 2
    return var / (2 * mean), 2 * mean**2 / var


def apply(ctx, fitted: Fitted, omega: np.ndarray, rate: np.ndarray, rows: slice) -> np.ndarray:
    """Angular rate (p, k, 3) plus the Earth rate at the positions `rows`, per position at its
    heading (station.model.effects)."""
    out = np.empty_like(omega)
    lat, mag = float(fitted.values["latitude_deg"]), float(fitted.values["rate"])
    heading = fitted.value("heading_deg")
    for i, j in enumerate(ctx.data.positions(rows)):
        out[i:i + 1] = earth_rate.apply(omega[i:i + 1], ctx.orientation[j:j + 1],
                                        ctx.data.angle[j:j + 1], EarthRate(lat, heading[j], mag))
    return out
