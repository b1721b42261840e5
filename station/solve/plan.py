"""Choose the positions of a session: which of a fixture's reachable stimulus directions, and how
many, give the smallest expected calibration error for a unit's nominal layout and noise.

The criterion is the Cramer-Rao bound of `station.solve.uncertainty.crlb`: trace(CRLB) is the
smallest achievable E[eps^2] of Eq. (19) (Rupniewski), so sqrt(trace) is the expected eps of an
efficient estimator (docs/solvers.md: ML reaches it within a few per cent from n = 12 on). Each
position j adds its own reduced Fisher information S_j (the Schur complement over that position's
unknown direction v_j, `station.solve.ml.reduced_system`) and the positions' unknowns are
separate, so the information of a plan is the sum of its positions' S_j; a candidate is tried by
one addition and one 33 x 33 inverse for a 12-gyro array (`Bound`).

Selection (classical optimal design, Fedorov 1972): greedy, one position at a time, the candidate
that lowers trace(CRLB) the most (positions may repeat: a repeated pose averages the noise down);
until the plan identifies a (Eqs. 16-17), the candidate that leaves the fewest unidentified
directions. The count stops growing when one more position would lower the expected eps by less
than `threshold` (relative), or at `most`; the chosen set is then improved by exchanges (one
position swapped for another candidate while that lowers the bound).

For equal noise at every position, sum_j v_j v_j^T has the fixed trace n c^2 and trace of its
inverse (each sensor's variance) is smallest for an isotropic design, which a Fibonacci sphere
already approximates: the planner cannot beat well-spread directions by much. What it brings is
a plan made of poses a technician can set, its count, and its expected eps before the session.
"""

from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError
from station.model import measurement
from station.solve.ml import normal_equations, reduced_system, sigma_matrix
from station.solve.poses import Directions
from station.solve.uncertainty import frame_jacobian

RANK_TOL = 1e-9
"""Relative eigenvalue of the reduced information below which a direction is unidentified."""


@dataclass(frozen=True)
class Plan:
    """A planned session.

    chosen    : (n,) indices into the candidates, in the order to record them
    expected  : (n,) expected eps (sqrt trace CRLB) of the first k + 1 greedy positions (inf while
                the plan does not yet identify a)
    eps       : expected eps of the final plan (after the exchanges)
    """

    chosen: np.ndarray
    expected: np.ndarray
    eps: float


def position_information(a, up, sigma, magnitude: float, estimate_bias: bool) -> np.ndarray:
    """(k, m p, m p) reduced Fisher information of one position per candidate up direction.

    a: (d, m) nominal layout; up: (k, d) unit-frame stimulus directions; sigma: the noise of one
    position's reading, scalar or (m,); readings a^T v (+ b) with v = magnitude * up.
    """
    a = np.asarray(a, float)
    d, m = a.shape
    weight = 1.0 / sigma_matrix(sigma, m) ** 2 * np.ones((m, 1))
    bias = np.zeros(m) if estimate_bias else None
    out = []
    for u in np.asarray(up, float):
        poses = Directions.start(u[:, None], magnitude)
        v = poses.vectors()
        neq, _ = normal_equations(a, poses, bias, measurement.forward(a, v, bias), weight)
        out.append(reduced_system(neq)[0])
    return np.array(out)


class Bound:
    """trace(CRLB) of Eq. (19)'s canonical a for sums of position informations, batched.

    The reduced information is singular exactly along the rotation gauge of Remark 1 (theta_i ->
    (W a_i, 0) for a skew W) when the plan identifies a; on an orthonormal basis Q of the
    directions orthogonal to the gauge, its pseudo-inverse is Q (Q^T S Q)^-1 Q^T
    (the pseudo-inverse of `station.solve.uncertainty.gauge_pinv`, one inverse per candidate).
    """

    def __init__(self, a, estimate_bias: bool):
        a = np.asarray(a, float)
        d, m = a.shape
        p = d + (1 if estimate_bias else 0)
        gauge = []
        for i, k in zip(*np.triu_indices(d, 1), strict=True):
            w = np.zeros((d, d))
            w[i, k], w[k, i] = 1.0, -1.0
            g = np.zeros((m, p))
            g[:, :d] = (w @ a).T
            gauge.append(g.ravel())
        u, _, _ = np.linalg.svd(np.array(gauge).T)
        self.q = u[:, len(gauge):]
        jq = frame_jacobian(a, p) @ self.q
        self._m = jq.T @ jq  # trace(J Q C Q^T J^T) = sum(C * M)

    def reduce(self, information: np.ndarray) -> np.ndarray:
        """Q^T S Q of one (m p, m p) information or a stack of them."""
        return self.q.T @ information @ self.q

    def scores(self, reduced: np.ndarray) -> np.ndarray:
        """Traces for a stack of reduced informations, each regularised by 1e-9 of its mean
        eigenvalue: the trace where a is identified, huge (about 1e9 x per unidentified
        direction) where not, so that the greedy first makes the plan identify a."""
        r = reduced.shape[-1]
        scale = np.trace(reduced, axis1=-2, axis2=-1)[..., None, None] / r
        inv = np.linalg.inv(reduced + 1e-9 * scale * np.eye(r))
        return np.sum(inv * self._m, axis=(-2, -1))

    def eps(self, reduced: np.ndarray) -> float:
        """sqrt(trace CRLB) of one reduced information; inf when a is not identified (an
        eigenvalue below RANK_TOL of the mean one)."""
        r = reduced.shape[-1]
        try:
            np.linalg.cholesky(reduced - RANK_TOL * np.trace(reduced) / r * np.eye(r))
        except np.linalg.LinAlgError:
            return np.inf
        return float(np.sqrt(np.sum(np.linalg.inv(reduced) * self._m)))


def plan(a, up, sigma, magnitude: float, *, estimate_bias: bool = False,
         threshold: float = 0.025, most: int = 40, distinct: bool = False) -> Plan:
    """The positions (indices into `up`, (k, d) candidate stimulus directions) that minimise the
    expected eps for layout `a` (d, m) and per-position reading noise `sigma` (scalar or (m,));
    see the module docstring. threshold: the smallest relative decrease of the expected eps worth
    one more position; most: the largest count; distinct: each candidate at most once (a
    protocol that refuses a pose it has seen)."""
    if not 0 <= threshold < 1 or most < 1:
        raise CalibrationInputError(f"plan threshold {threshold!r} must be in [0, 1) and the "
                                    f"largest count {most!r} at least 1.",
                                    "Give e.g. threshold = 0.025 and most = 40.")
    bound = Bound(a, estimate_bias)
    info = bound.reduce(position_information(a, up, sigma, magnitude, estimate_bias))
    chosen, expected, total = [], [], np.zeros(info.shape[1:])
    most = min(most, len(info)) if distinct else most
    while len(chosen) < most:
        k = _best(_taken(bound.scores(total + info), chosen if distinct else []))
        eps = bound.eps(total + info[k])
        if expected and np.isfinite(expected[-1]) and 1 - eps / expected[-1] < threshold:
            break
        chosen.append(k)
        expected.append(eps)
        total = total + info[k]
    if not np.isfinite(expected[-1]):
        raise CalibrationInputError(
            f"no plan of at most {most} positions of the fixture identifies this layout.",
            "Add the wedge to the fixture (diagonal poses), or allow more positions.")
    chosen = exchange(np.array(chosen), info, bound, distinct)
    return Plan(chosen, np.array(expected), bound.eps(info[chosen].sum(0)))


def exchange(chosen: np.ndarray, info: np.ndarray, bound: Bound,
             distinct: bool = False) -> np.ndarray:
    """Swap single positions for other candidates (not in the plan, when `distinct`) while that
    lowers the bound (Fedorov)."""
    chosen = chosen.copy()
    best = bound.eps(info[chosen].sum(0))
    improved = True
    while improved:
        improved = False
        for slot in range(len(chosen)):
            rest = info[np.delete(chosen, slot)].sum(0)
            k = _best(_taken(bound.scores(rest + info), chosen if distinct else []))
            eps = bound.eps(rest + info[k])
            if eps < best * (1 - 1e-9):
                chosen[slot], best, improved = k, eps, True
    return chosen


def _taken(scores: np.ndarray, chosen) -> np.ndarray:
    """`scores` with the candidates in `chosen` ruled out."""
    scores = scores.copy()
    scores[list(chosen)] = np.inf
    return scores


def _best(scores: np.ndarray) -> int:
    """The first of the candidates within rounding (1e-6) of the lowest score: symmetric layouts
    tie, and a plan must not depend on the rounding of the noise's scale."""
    return int(np.flatnonzero(scores <= scores.min() * (1 + 1e-6))[0])


def expected_eps(a, up, sigma, magnitude: float, estimate_bias: bool = False) -> float:
    """sqrt(trace CRLB) of a plan of stimulus directions `up` ((n, d)); inf when it does not
    identify a."""
    bound = Bound(a, estimate_bias)
    return bound.eps(bound.reduce(position_information(a, up, sigma, magnitude,
                                                       estimate_bias).sum(0)))
