"""Identifiability and degeneracy checks for constant-magnitude calibration, with advice.

Each check raises `CalibrationInputError` saying what is wrong and what the operator should do.
"""

import functools

import numpy as np

from station.errors import CalibrationInputError

# relative singular-value level below which a direction counts as absent (double precision, with
# margin for noise-free but rounded inputs); noisy data is judged against its own noise floor.
RANK_TOL = 1e-9
# condition number beyond which the design of Eq. (7) is treated as singular
DESIGN_COND_MAX = 1e10


def min_positions(m: int, d: int) -> int:
    """Smallest n satisfying both Eq. (16), n >= d(d+1)/2, and Eq. (17),
    (n-d)(m-d+1) >= d(d-1)/2."""
    n = d * (d + 1) // 2
    while (n - d) * (m - d + 1) < d * (d - 1) // 2:
        n += 1
    return n


def check_positions(shape: tuple[int, int], d: int) -> None:
    """Enough sensors (m >= d) and positions (Eqs. 16 and 17) for the closed form."""
    m, n = shape
    if d < 1:
        raise CalibrationInputError(f"dimension d = {d} is invalid.",
                                    "Use d = 3 (space) or 2 (plane).")
    if m < d:
        raise CalibrationInputError(
            f"{m} sensor(s) cannot resolve a {d}-dimensional quantity (need m >= d).",
            f"Calibrate at least {d} sensors together, or set d to the dimension they span.",
        )
    need = min_positions(m, d)
    if n < need:
        raise CalibrationInputError(
            f"{n} position(s) are too few for d = {d}, m = {m}: Eqs. (16)-(17) need n >= {need}.",
            f"Record {need - n} more position(s) at new orientations.",
        )


def check_rank(singular_values: np.ndarray, d: int, shape: tuple[int, int]) -> None:
    """The readings must span d dimensions: otherwise the stimuli never left a lower subspace."""
    s = np.asarray(singular_values)
    if s.size < d or s[0] <= 0 or s[d - 1] <= RANK_TOL * s[0]:
        rank = int(np.sum(s > RANK_TOL * s[0])) if s.size and s[0] > 0 else 0
        raise CalibrationInputError(
            f"the readings span only {rank} of {d} dimensions: every position's stimulus lies in a "
            f"common {'plane' if rank == 2 else 'line' if rank == 1 else 'subspace'}.",
            "Add positions with the stimulus (spin axis or gravity) out of that "
            f"{'plane' if rank == 2 else 'subspace'}, e.g. turn the unit onto another face.",
        )


def gram_design(b: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Design matrix of Eq. (7) for the upper-triangular entries of symmetric g, and their
    indices."""
    d = b.shape[0]
    rows, cols = np.triu_indices(d)
    factor = np.where(rows == cols, 1.0, 2.0)
    return (b[rows] * b[cols] * factor[:, None]).T, (rows, cols)


def check_design(design: np.ndarray) -> None:
    """Eq. (7) must have a unique solution g: the positions must not lie on one quadric cone."""
    s = np.linalg.svd(design, compute_uv=False)
    if s[-1] <= s[0] / DESIGN_COND_MAX:
        raise CalibrationInputError(
            "the positions do not determine g of Eq. (7): all stimulus directions lie on one "
            "quadric cone (e.g. every spin axis at the same angle to one direction, or only "
            f"{int(np.sum(s > s[0] / DESIGN_COND_MAX))} independent orientations).",
            "Add positions whose stimulus points off that cone, e.g. along and perpendicular "
            "to it.",
        )


def check_gram(eigenvalues: np.ndarray) -> None:
    """g = f^T f must be positive definite (Eq. 8); otherwise the readings contradict |v_j| = c."""
    lam = np.asarray(eigenvalues)
    if lam.min() <= 0:
        raise CalibrationInputError(
            "the readings are inconsistent with a stimulus of constant magnitude (g of Eq. 8 is "
            f"not positive definite, eigenvalues {np.array2string(lam, precision=3)}).",
            "Check that biases were removed (static window subtracted), that all positions use "
            "the same rate or field, and that units are consistent; or add positions.",
        )


# Fisher information at a solution (station.solve.calibrate), in natural units (scale factors and
# axis turns relative, biases relative to the stimulus). A rank test: a direction is not identified
# when its information is below INFO_TOL of the largest (double precision, with margin) or, with
# the noise level known or estimated from spare readings, below 1 / UNBOUNDED^2: its 1-sigma then
# exceeds the quantity itself (the whole scale factor, a radian of axis, the whole stimulus as a
# bias), so not even its sign is determined. A rank-deficient design keeps 1e-8 .. 1e-4 at a noisy
# estimate (the pose unknowns absorb the noise: a sensor seen at one angle, poses in a plane); a
# full-rank but weak one far more (20 .. 100 on Rupniewski's 12 gyros at n = 8, sigma = 0.01).
# Directions with a 1-sigma beyond LOOSE (10 % of a scale factor, 6 degrees, 0.1 of the stimulus)
# are accepted as weakly determined: the fit exists, its 1-sigma says how loose it is, and the
# result names them (`CalibrationResult.weakly_determined`).
# Repeated poses (a block's six faces, each visited twice) differ only by their noise: their fitted
# directions then carry information that the noise made, not the design. The rank is taken on the
# distinct directions (`distinct_directions`): poses within SAME_POSE standard errors of a leader's
# direction are one pose (a 2-D normal error lands beyond 5 sigma with probability 4e-6).
INFO_TOL = 1e-12
UNBOUNDED = 1.0
LOOSE = 0.1
SAME_POSE = 5.0
# a sensor whose readings vary over the poses by less than this fraction of the widest-varying
# sensor's sees the stimulus at one angle only: its scale and bias are not separable
FLAT = 0.1
# size of the information from which its largest eigenvalue is found by Lanczos (below it all
# eigenvalues cost less than Lanczos' set-up)
LANCZOS_FROM = 300
# at most this many undetermined parameters are named in a refusal
NAMED = 4


def _norms(a: np.ndarray) -> np.ndarray:
    """|a_i|, with the largest standing in for a sensor that sees nothing (a_i ~ 0)."""
    norms = np.sqrt(np.einsum("ki,ki->i", a, a))
    top = norms.max()
    return np.where(norms > 1e-6 * top, norms, top)


def natural_scale(a: np.ndarray, magnitude: float, bias_estimated: bool) -> np.ndarray:
    """(m p,) factors D with theta = D theta_natural: a_i in units of |a_i|, b_i of c |a_i|."""
    per = np.ones(a.shape[0] + bias_estimated)
    per[a.shape[0]:] = magnitude
    return np.outer(_norms(a), per).ravel()


def gauge_directions(a: np.ndarray, p: int) -> np.ndarray:
    """(m p, d(d-1)/2) the rotations of Remark 1 acting on theta = (a_1, b_1, ...): a_i -> R a_i."""
    d, m = a.shape
    moved = rotation_generators(d) @ a  # (k, d, m): generator (r, s) times a
    out = np.zeros((len(moved), m, p))
    out[:, :, :d] = moved.transpose(0, 2, 1)
    return out.reshape(len(moved), m * p).T


@functools.cache
def rotation_generators(d: int) -> np.ndarray:
    """(d(d-1)/2, d, d) the generators of rotations in d dimensions, one per plane (r, s), r < s:
    entry (r, s) -1, entry (s, r) +1 (read-only)."""
    pairs = np.triu_indices(d, 1)
    gen = np.zeros((len(pairs[0]), d, d))
    k = np.arange(len(pairs[0]))
    gen[k, pairs[0], pairs[1]], gen[k, pairs[1], pairs[0]] = -1.0, 1.0
    gen.setflags(write=False)
    return gen


def undetermined(fisher: np.ndarray, a: np.ndarray, magnitude: float, bias_estimated: bool,
                 noise_known: bool, sigma_max: float = UNBOUNDED) -> np.ndarray:
    """(k, m p) orthonormal directions of theta, in natural units, whose 1-sigma exceeds
    `sigma_max` (noise known) or whose information is below INFO_TOL of the largest, besides the
    rotation gauge; k = 0 when there are none (found by one Cholesky factorisation; the
    eigen-decomposition only when some direction is that loose)."""
    d, m = a.shape
    p = fisher.shape[0] // m
    scale = natural_scale(a, magnitude, bias_estimated)
    scaled = fisher * np.outer(scale, scale)
    q, _ = np.linalg.qr(gauge_directions(a, p) / scale[:, None])
    # the trace bounds the largest eigenvalue: when INFO_TOL of it is below the loose floor, the
    # floor is that (and any shift above it lifts the gauge), without finding the eigenvalue
    top = float(np.trace(scaled))
    if not noise_known or INFO_TOL * top > 1.0 / sigma_max**2:
        top = _largest_eigenvalue(scaled)
    floor = INFO_TOL * top
    if noise_known:
        floor = max(floor, 1.0 / sigma_max**2)
    if _positive_definite(scaled + (top + floor) * (q @ q.T) - floor * np.eye(len(scaled))):
        return np.zeros((0, m * p))  # every eigenvalue beside the gauge's exceeds the floor
    lam, vec = np.linalg.eigh(scaled)
    null = vec[:, lam <= floor]
    rest = null - q @ (q.T @ null)
    u, s, _ = np.linalg.svd(rest, full_matrices=False)
    return u[:, s > 0.5].T


def distinct_directions(a: np.ndarray, v: np.ndarray, sigma: np.ndarray) -> np.ndarray | None:
    """(d, k) the distinct directions among the fitted poses v (d, n) of sensors a (d, m) with
    noise sigma (m, n): each the mean of the poses within SAME_POSE standard errors (angle) of a
    leader's direction, the leaders taken in order (no chaining along a slow turn); None when
    every pose is distinct."""
    u = v / np.linalg.norm(v, axis=0)
    info = np.einsum("di,in,ei->nde", a, 1.0 / sigma**2, a)  # per pose, of v (readings' units)
    c = np.linalg.norm(v, axis=0)
    angle_sd = 1.0 / (c * np.sqrt(np.maximum(np.linalg.eigvalsh(info)[:, 0], 1e-300)))
    free = np.ones(u.shape[1], bool)
    groups = []
    while free.any():
        lead = int(np.argmax(free))
        near = free & (u[:, lead] @ u >= np.cos(SAME_POSE * np.hypot(angle_sd[lead], angle_sd)))
        near[lead] = True  # its own direction, whatever the rounding of u . u
        groups.append(u[:, near].sum(axis=1))
        free &= ~near
    if len(groups) == u.shape[1]:
        return None
    g = np.array(groups).T
    return c.mean() * g / np.linalg.norm(g, axis=0)


def _largest_eigenvalue(sym: np.ndarray) -> float:
    """The largest eigenvalue of a symmetric matrix, to 1e-6 relative: enough for a floor
    INFO_TOL of it (Lanczos, O(n^2) per step; deterministic)."""
    if len(sym) <= LANCZOS_FROM:
        return float(np.linalg.eigvalsh(sym)[-1])
    from scipy.sparse.linalg import eigsh  # only here: its import costs more than a small solve

    return float(eigsh(sym, k=1, which="LA", v0=np.ones(len(sym)), tol=1e-6)[0][0])


def _positive_definite(sym: np.ndarray) -> bool:
    """Whether a symmetric matrix has a Cholesky factorisation."""
    try:
        np.linalg.cholesky(sym)
    except np.linalg.LinAlgError:
        return False
    return True


def named_parts(direction: np.ndarray, a: np.ndarray, bias_estimated: bool, names) -> list:
    """The parameters a direction (natural units) moves, largest first: "the scale of s3"..."""
    d, m = a.shape
    theta = direction.reshape(m, -1)
    unit = a / _norms(a)
    along = np.einsum("id,di->i", theta[:, :d], unit)
    across = np.linalg.norm(theta[:, :d] - along[:, None] * unit.T, axis=1)
    parts = [(abs(along[i]), f"the scale of {names[i]}") for i in range(m)]
    parts += [(across[i], f"the axis direction of {names[i]}") for i in range(m)]
    if bias_estimated:
        parts += [(abs(theta[i, d]), f"the bias of {names[i]}") for i in range(m)]
    top = max(w for w, _ in parts)
    return [label for w, label in sorted(parts, key=lambda x: -x[0]) if w >= 0.3 * top]


def check_information(fisher, a, readings, bias_estimated: bool, magnitude: float, names, *,
                      noise_known: bool, free: int, distinct=None,
                      context: CalibrationInputError | None = None) -> tuple:
    """Refuse a solution whose Fisher information (m p x m p, theta = (a_1, b_1, ...), the poses
    eliminated) leaves parameters unidentified (a rank test, module notes), naming them and the
    poses that would fix them; return the parameters identified but weakly determined (a 1-sigma
    beyond LOOSE in natural units, with the noise level known), named the same way.

    readings (m, n) locate the sensors that see the stimulus at one angle only; free: the number
    of unknowns (a, b and the poses, the gauge removed); distinct: called when some parameter is
    weakly determined, the information of the distinct poses only (`distinct_directions`) or None
    when they are all distinct: the rank is taken on it; context: the closed form's own refusal,
    quoted."""
    weak = undetermined(fisher, a, magnitude, bias_estimated, noise_known, LOOSE) \
        if noise_known else np.zeros((0, fisher.shape[0]))
    if noise_known and not len(weak) and LOOSE <= UNBOUNDED:
        return ()  # every direction above LOOSE's floor, so above the rank test's lower one
    design = fisher if not len(weak) or distinct is None else distinct()
    design = fisher if design is None else design
    null = undetermined(design, a, magnitude, bias_estimated, noise_known)
    if not len(null):
        return tuple(dict.fromkeys(p for w in weak for p in named_parts(w, a, bias_estimated,
                                                                        names)))
    m, n = readings.shape
    d = a.shape[0]
    parts = list(dict.fromkeys(p for w in null for p in named_parts(w, a, bias_estimated, names)))
    flat = _flat(readings, names, parts)
    problem = _flat_words(readings, names, flat, parts) if flat else _listed(parts) + (
        " is not determined by these poses" if len(parts) == 1 else
        " are not separable by these poses")
    quadric = d * (d + 1) // 2 + d
    advice = ("Add poses in new orientations that change the readings of "
              f"{_listed(list(dict.fromkeys(p.rsplit(' of ', 1)[1] for p in parts)), 'others')} "
              "(turn the unit onto other faces, tilt it about other axes).")
    if flat:
        advice = (f"Add a pose with {' and '.join(names[i] for i in flat)} turned the other way "
                  "or horizontal, so that the reading changes by about the stimulus.")
    if bias_estimated and n < quadric:
        problem += (f" ({n} poses: with the biases unknown the poses must fix the stimuli's "
                    f"quadric, at least {quadric} poses whatever the number of sensors)")
        advice = f"Record {quadric - n} more pose(s) in new orientations. " + advice
    elif m * n < free:
        problem += f" ({n} poses give {m * n} readings for {free} unknowns)"
    if context is not None:
        problem += f"; the closed form said: {context.problem.rstrip('.')}"
        advice += " " + context.advice
    raise CalibrationInputError(problem + ".", advice)


def _listed(items: list, rest: str = "more") -> str:
    """"x", "x and y", "x, y, z, w and 3 more": at most NAMED items named."""
    shown = items[:NAMED] + ([f"{len(items) - NAMED} {rest}"] if len(items) > NAMED else [])
    return shown[0] if len(shown) == 1 else f"{', '.join(shown[:-1])} and {shown[-1]}"


def _flat(readings, names, parts) -> list:
    """Indices of the named sensors whose readings hardly vary over the poses (< FLAT of the
    widest-varying sensor's spread): they see the stimulus at one angle only."""
    spread = np.ptp(readings, axis=1)
    return [i for i, name in enumerate(names) if any(p.endswith(f"of {name}") for p in parts)
            and spread[i] < FLAT * spread.max()]


def _flat_words(readings, names, flat, parts) -> str:
    """The refusal for sensors stuck at one reading, and the other undetermined parameters."""
    spread = np.ptp(readings, axis=1)
    widest = int(np.argmax(spread))
    words = "; ".join(
        f"the scale and the bias of {names[i]} are not separable: every pose gives {names[i]} "
        f"the same reading ({readings[i].mean():.6g}, spread {spread[i]:.2g} against "
        f"{spread[widest]:.2g} of {names[widest]})" for i in flat)
    others = [p for p in parts if not any(p.endswith(f"of {names[i]}") for i in flat)]
    return words + (f" (nor are {_listed(others)} determined)" if others else "")
