"""Identifiability and degeneracy checks for constant-magnitude calibration, with advice.

Each check raises `CalibrationInputError` saying what is wrong and what the operator should do.
"""

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
