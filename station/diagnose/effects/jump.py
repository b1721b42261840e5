"""Extension `jump`, an open family (issue 32): the biases step at one instant (a knock on the
fixture, a connector, a reset of the unit's offsets) by delta_i per sensor.

Model: offset_i(t) = delta_i H(t - t0), t the session time, added beside the output chain's
offsets. Signature against Eq. (18)'s per-position bias: the static means of the positions after
t0 stand delta_i above those before it, and the position holding t0 steps within it.

The instant is searched over every bin edge of every position and every gap between two
positions; for a fixed instant the offsets are linear in delta_i (m parameters), and the scan is
in closed form over the residuals' centred parts (`scan`: cumulative sums of the bins, O(n K m)).
The likelihood ratio is the best of those instants, so its p-value is Bonferroni'd over them
(`Fitted.searched`). A jump between two positions may lie anywhere in their gap: `t0` is the
start of the position after it (its sigma the gap's half). A bias random walk is many small
jumps: the largest is not named when a walk explains it (`beyond_walk`, as bias_drift's).
"""

import numpy as np

from station.diagnose import linear, walk
from station.diagnose.effects import Fitted

GAPS = ("static",)
"""Gap statistics (station.diagnose.gap) that hold this effect's signature: it is not named
while one of them stays unexplained (station.diagnose.select.settle)."""
STAGE = "added"


def scan(data, r: tuple, w: tuple) -> tuple:
    """(LR (n, K), g (n, K, m), h (n, K, m)): for a jump at bin edge e of position j (e = 0: in the
    gap before it), the chi2 decrease and each sensor's normal equation h delta = g, from the
    residuals' centred parts r = (bins (n, K, m), static means (n, m)) and their weights w (m,).
    Bins: only position j's change, by (b >= e) - (K - e) / K (its bins are centred, so their
    sum is 0); static means: 0 before j, the static window's share after the instant at j, 1
    after j, centred over the positions (so are the residuals')."""
    bins, static = r
    n, k_bins, m = bins.shape
    e = np.arange(k_bins)
    tail = np.cumsum(bins[:, ::-1], axis=1)[:, ::-1]  # (n, K, m): sum over b >= e
    s0, s1 = data.windows["static"]
    share = np.clip((s1 - np.maximum(e * data.bin, s0)) / (s1 - s0), 0.0, 1.0)  # (K,)
    after = np.cumsum(static[::-1], axis=0)[::-1]  # (n, m): sum over j' >= j
    later = np.vstack([after[1:], np.zeros((1, m))])  # sum over j' > j
    g_static = share[None, :, None] * static[:, None, :] + later[:, None, :]
    count = (n - 1 - np.arange(n))[:, None]  # positions after j
    total = share[None, :] + count
    squares = share[None, :] ** 2 + count - total**2 / n  # sum of the centred u_j^2
    g = w[0] * tail + w[1] * g_static
    h = w[0] * (e * (k_bins - e) / k_bins)[None, :, None] + w[1] * squares[..., None]
    with np.errstate(divide="ignore", invalid="ignore"):
        lr = np.where(h > 0, g**2 / h, 0.0).sum(-1)
    return lr, g, h


def fit(ctx, twin, r) -> Fitted:
    """delta (m,) and the instant; see the module docstring."""
    data = ctx.data
    lr, g, h = scan(data, r, linear.weights(data, ctx.sigma))
    lr[0, 0] = 0.0  # a jump before the session is no jump
    j, e = np.unravel_index(int(np.argmax(lr)), lr.shape)
    delta, sd = g[j, e] / h[j, e], 1.0 / np.sqrt(h[j, e])
    lo, hi = span(data, np.argwhere(lr >= lr[j, e] - 2 * np.log(lr.shape[1])))
    return Fitted(
        "jump",
        {"delta": delta, "t0": _instant(data, j, e)[1], "position": int(j) + 1,
         "t0_span": np.array([lo, hi])},
        {"delta": sd, "t0": (hi - lo) / 4, "position": np.nan, "t0_span": np.full(2, np.nan)},
        dof=data.shape[2] + 1,
        reduction=float(lr[j, e]),
        null=(1.0, float(data.shape[2])),  # at one instant; the search: `searched`
        searched=int(lr.size - 1),
        units={"t0": "s (session time)", "t0_span": "s (session time)", "position": ""},
        notes="an open family: the biases step by delta at t0, the best of every bin edge and "
        "gap between positions (p-value Bonferroni'd over them); between positions t0 is the "
        "next position's start",
    )


def _instant(data, j: int, e: int) -> tuple:
    """(last sample time before, first sample time at or after) a jump at bin edge e of position
    j (e = 0: the gap before the position; before the first: its first sample)."""
    times = data.session_times(slice(j, j + 1))[0]
    after = float(times[e * data.bin])
    if e > 0:
        return float(times[e * data.bin - 1]), after
    return (float(data.session_times(slice(j - 1, j))[0][-1]) if j else after), after


def span(data, near) -> tuple:
    """(earliest, latest) session time a jump may lie at among the instants `near` ((j, e)
    pairs: those whose chi2 decrease is within 2 log K of the best, K the bin edges of a
    position). An instant's likelihood is not regular: near the true one the chi2 decrease
    wanders like a CUSUM of the noise, whose largest excursion over K edges grows as 2 log K
    (with 4, the chi2(1) 2-sigma, the true instant lay in the set in 6 of 10 bench sessions);
    the set is reported, and a quarter of its span as sigma."""
    bounds = np.array([_instant(data, int(j), int(e)) for j, e in near])
    return float(bounds[:, 0].min()), float(bounds[:, 1].max())


def _step(data, t0: float, rows: slice) -> np.ndarray:
    """(p, k) 1 at the samples at or after t0, else 0, at the positions `rows`."""
    return (data.session_times(rows) >= t0).astype(float)


def apply(ctx, fitted: Fitted, rows: slice) -> np.ndarray:
    """(p, k, m) the offsets delta_i H(t - t0) at the positions `rows`."""
    return _step(ctx.data, float(fitted.values["t0"]), rows)[..., None] * fitted.value("delta")


def beyond_walk(current, fitted: Fitted) -> float | None:
    """log10 p of the fitted jump (its static-window means at the fitted instant) in the static
    windows' mean residuals of `current`, the model without it, against a bias random walk per
    sensor (station.diagnose.walk); None for a jump after the last static window (its means do
    not step: the walk's test has no column to judge)."""
    data = current.ctx.data
    s0, s1 = data.windows["static"]
    shape = _step(data, float(fitted.values["t0"]), slice(None))[:, s0:s1].mean(1)
    if np.ptp(shape) == 0:
        return None  # after the last static window: no step in the means for a walk to mimic
    return walk.static_log10_p(current, shape[:, None], 1)
