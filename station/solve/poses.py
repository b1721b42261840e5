"""How the positions' stimuli are parametrised in the maximum-likelihood fit (station/solve/ml.py).

- `Directions`: every position its own direction on the sphere of radius c (magnitude constraints
  only, any d): d - 1 tangent coordinates per position.
- `SoftMagnitudes`: every position a free vector v_j (d coordinates) whose magnitude has a Gaussian
  prior |v_j| = c (1 + delta_j), delta_j ~ N(0, spread^2): a random effect, e.g. the rate of a
  rotary table that is not exactly the commanded one. The prior adds one residual row
  (|v_j| - c) / (c spread) per position (`prior`); spread -> 0 is the sphere of `Directions`.
- `RigidGroups` (d = 3): positions whose mutual inner products are all known (one mounting of a
  right-angle iron, Hwangbo & Kanade Eq. 15) share one rotation: v_j = c R_g s_j, with s_j fixed
  unit vectors from the constraint Gram matrix. Three rotation coordinates per group.

Both expose the same small interface: `vectors()`, `jacobian()` (dv_j / d local, (n, d, k)), `group`
(group of each position), `count`, `null` (local directions with no effect, (count, k) bools),
`free` (local degrees of freedom) and `moved(step)`; `SoftMagnitudes` adds `prior()`.
"""

from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError


def tangent_basis(u: np.ndarray) -> np.ndarray:
    """Orthonormal bases (n, d, d-1) of the planes perpendicular to unit vectors u (d, n).

    Columns 2..d of the Householder reflection that maps e_1 onto -sign(u_1) u.
    """
    d = u.shape[0]
    s = np.where(u[0] >= 0, 1.0, -1.0)
    w = u.T.copy()
    w[:, 0] += s
    norm2 = np.einsum("nk,nk->n", w, w)[:, None, None]
    return (np.eye(d)[None] - 2 * w[:, :, None] * w[:, None, :] / norm2)[:, :, 1:]


def skew(x: np.ndarray) -> np.ndarray:
    """Cross-product matrices [x]_x of vectors x (..., 3)."""
    z = np.zeros(x.shape[:-1])
    return np.stack([np.stack([z, -x[..., 2], x[..., 1]], -1),
                     np.stack([x[..., 2], z, -x[..., 0]], -1),
                     np.stack([-x[..., 1], x[..., 0], z], -1)], -2)


def rotation_matrices(w: np.ndarray) -> np.ndarray:
    """exp([w]_x) for rotation vectors w (..., 3): Rodrigues' formula, I + sinc(t) K +
    (1 - cos t) / t^2 K^2 with t = |w|, K = [w]_x, the second factor as sinc(t / 2)^2 / 2 (no
    cancellation near t = 0). A few microseconds where scipy's Rotation takes milliseconds."""
    t = np.linalg.norm(w, axis=-1)[..., None, None] / np.pi
    k = skew(w)
    return np.eye(3) + np.sinc(t) * k + 0.5 * np.sinc(t / 2) ** 2 * (k @ k)


@dataclass(frozen=True)
class _OnePerPosition:
    """Pose models with one stimulus vector per position (its own pose group)."""

    v: np.ndarray  # (d, n)
    magnitude: float

    @property
    def group(self):
        return np.arange(self.v.shape[1])

    @property
    def count(self):
        return self.v.shape[1]

    def vectors(self):
        return self.v


@dataclass(frozen=True)
class Directions(_OnePerPosition):
    """One free direction per position: v_j on the sphere of radius `magnitude`."""

    @classmethod
    def start(cls, v0, magnitude):
        v = np.asarray(v0, float)
        return cls(magnitude * v / np.linalg.norm(v, axis=0), float(magnitude))

    @property
    def null(self):
        return np.zeros((self.count, self.v.shape[0] - 1), bool)

    @property
    def free(self):
        return self.v.shape[1] * (self.v.shape[0] - 1)

    def jacobian(self):
        return self.magnitude * tangent_basis(self.v / self.magnitude)

    def moved(self, step):
        v = self.v + np.einsum("ndk,nk->dn", self.jacobian(), step)
        return Directions.start(v, self.magnitude)


@dataclass(frozen=True)
class SoftMagnitudes(_OnePerPosition):
    """A free vector per position, prior |v_j| = c (1 + delta_j), delta_j ~ N(0, spread^2)."""

    spread: float

    @classmethod
    def start(cls, v0, magnitude, spread):
        """From start vectors v0, put on the sphere of radius `magnitude` (the prior's mean)."""
        return cls(Directions.start(v0, magnitude).v, float(magnitude), float(spread))

    @property
    def null(self):
        return np.zeros(self.v.shape[::-1], bool)

    @property
    def free(self):
        return self.v.size

    def jacobian(self):
        d, n = self.v.shape
        return np.broadcast_to(np.eye(d), (n, d, d))

    def moved(self, step):
        return SoftMagnitudes(self.v + step.T, self.magnitude, self.spread)

    def prior(self) -> tuple[np.ndarray, np.ndarray]:
        """Prior rows as (residual (n,), Jacobian of the model side (n, d)), in the sign convention
        of station/solve/ml.py (residual = observed - model): (c - |v_j|) / (c s) and
        u_j / (c s)."""
        norm = np.linalg.norm(self.v, axis=0)
        scale = self.magnitude * self.spread
        return (self.magnitude - norm) / scale, (self.v / norm).T / scale


@dataclass(frozen=True)
class RigidGroups:
    """Positions in rigid groups: v_j = c R_g s_j with the group's rotation R_g (d = 3)."""

    rot: np.ndarray  # (G, 3, 3)
    s: np.ndarray  # (3, n) unit vectors in each group's frame
    group: np.ndarray  # (n,)
    # rank: (G,) rank of each group's Gram matrix (1: one axis, rotation about it is null)
    rank: np.ndarray
    magnitude: float

    @property
    def count(self):
        return len(self.rot)

    @property
    def null(self):
        return np.stack([self.rank == 1, np.zeros(self.count, bool), np.zeros(self.count, bool)], 1)

    @property
    def free(self):
        return int(3 * self.count - np.sum(self.rank == 1))

    def vectors(self):
        return self.magnitude * np.einsum("nij,jn->in", self.rot[self.group], self.s)

    def jacobian(self):
        # v_j(w) = c R_g exp([w]_x) s_j  ->  dv_j/dw = -c R_g [s_j]_x
        return -self.magnitude * self.rot[self.group] @ skew(self.s.T)

    def moved(self, step):
        return RigidGroups(self.rot @ rotation_matrices(step), self.s, self.group, self.rank,
                           self.magnitude)


def rigid_groups(constraints, v0: np.ndarray, magnitude: float) -> RigidGroups | None:
    """Groups of positions whose inner products the constraints fix completely, or None if the
    constraints do not describe rigid groups (then each position keeps its own direction).

    Positions linked by constraints form a group; every pair in it must be constrained, with unit
    magnitudes, and the Gram matrix must be positive semidefinite of rank <= 3.
    """
    from scipy.sparse import csr_matrix  # here: scipy.sparse costs a solve without constraints
    from scipy.sparse.csgraph import connected_components  # (a rotary one) 0.2 s of imports

    d, n = v0.shape
    if d != 3:
        return None
    gram = np.full((n, n), np.nan)
    gram[constraints.j, constraints.k] = constraints.h
    gram[constraints.k, constraints.j] = constraints.h
    if not np.allclose(np.diag(gram), 1.0):
        return None  # magnitudes missing or unequal: the directions model does not apply
    count, group = connected_components(csr_matrix(~np.isnan(gram)), directed=False)
    rot, rank, s = [], [], np.zeros((3, n))
    for g in range(count):
        idx = np.flatnonzero(group == g)
        sub = gram[np.ix_(idx, idx)]
        if np.isnan(sub).any():
            return None  # not every pair in the group is constrained
        lam, vec = np.linalg.eigh(sub)
        if lam[0] < -1e-9 or np.sum(lam > 1e-9) > 3:
            raise CalibrationInputError(
                "the constraints contradict each other (their Gram matrix is not that of "
                "vectors in 3-D space).",
                "Check the face labels of each position and the mounting of each group.",
            )
        top = np.argsort(lam)[::-1][:3]
        s_g = (np.sqrt(np.maximum(lam[top], 0))[:, None] * vec[:, top].T)  # (3, n_g)
        u, _, vt = np.linalg.svd(v0[:, idx] @ s_g.T)  # Procrustes: R s_g ~ v0 / c
        rot.append(u @ vt)
        rank.append(int(np.sum(lam > 1e-9)))
        s[:, idx] = s_g
    return RigidGroups(np.array(rot), s, group, np.array(rank), float(magnitude))
