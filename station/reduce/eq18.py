"""Reduction of a rotary session to the readings matrix M, Eq. (18) of Rupniewski.

Per position j: m_j = m'_j - b'_j, the mean over the rotating window minus the mean over the static
window, in SI units. The rotating window is cut to a whole number of revolutions using the table
angle when it is known, so that anything fixed to the table (Earth rate, axis wobble, horizontal
misalignment) averages out over full turns. The per-window standard deviations come along so that
a solver can weight the readings.
"""

from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError


@dataclass(frozen=True)
class Reduced:
    """Averaged readings of a rotary session, SI units; arrays (m, n) unless noted.

    M : readings matrix (Eq. 18), rotating_mean - static_mean.
    static_sd, rotating_sd : sample standard deviations within each window.
    n_static, n_rotating : (n,) samples in each window (after the whole-revolution cut).
    revolutions : (n,) whole revolutions in each rotating window (0 when no angle was given).
    """

    M: np.ndarray
    static_mean: np.ndarray
    rotating_mean: np.ndarray
    static_sd: np.ndarray
    rotating_sd: np.ndarray
    n_static: np.ndarray
    n_rotating: np.ndarray
    revolutions: np.ndarray

    @property
    def sigma(self) -> np.ndarray:
        """(m, n) standard error of M from the windows' scatter: sqrt(s_s^2/N_s + s_r^2/N_r)."""
        return np.sqrt(self.static_sd**2 / self.n_static + self.rotating_sd**2 / self.n_rotating)

    def take(self, keep) -> "Reduced":
        """The readings of the positions `keep` (column indices), in that order."""
        keep = list(keep)
        return Reduced(**{name: getattr(self, name)[..., keep]
                          for name in self.__dataclass_fields__})

    def sensors(self, rows) -> "Reduced":
        """The readings of the sensors `rows` (row indices), in that order."""
        rows = list(rows)
        return Reduced(**{name: value[rows] if value.ndim == 2 else value
                          for name, value in vars(self).items()})


def _windows(window, n: int, k: int, name: str) -> np.ndarray:
    """(n, 2) [start, stop) windows from a (2,) or (n, 2) array, checked against k samples."""
    w = np.asarray(window)
    if w.shape == (2,):
        w = np.broadcast_to(w, (n, 2))
    if w.shape != (n, 2) or not np.issubdtype(w.dtype, np.integer):
        raise CalibrationInputError(
            f"{name} window has shape {w.shape} / dtype {w.dtype}.",
            f"Give integer [start, stop) sample indices, (2,) or ({n}, 2).",
        )
    if np.any(w[:, 0] < 0) or np.any(w[:, 1] > k) or np.any(w[:, 1] - w[:, 0] < 2):
        raise CalibrationInputError(
            f"{name} window {w.tolist()} lies outside 0..{k} or holds fewer than 2 samples.",
            "Check the segment indices.",
        )
    return w


def whole_revolutions(angle: np.ndarray, start: int, stop: int) -> tuple[int, int]:
    """(stop', revolutions): the samples [start, stop') span whole turns of the table angle.

    Sample i stands for the angle interval [angle[i], angle[i+1]); the cut picks the length whose
    swept angle |angle[stop'] - angle[start]| is closest to the largest whole number of turns.
    """
    swept = np.abs(angle[start:stop] - angle[start])
    turns = int(swept[-1] // (2 * np.pi))
    if turns == 0:
        raise CalibrationInputError(
            f"the rotating window [{start}, {stop}) turns the table by only {swept[-1]:.3f} rad.",
            "Record at least one full revolution, or reduce without the angle.",
        )
    i = int(np.searchsorted(swept, 2 * np.pi * turns))
    if i == swept.size or (
        i > 0 and abs(swept[i - 1] - 2 * np.pi * turns) <= abs(swept[i] - 2 * np.pi * turns)
    ):
        i -= 1
    return start + i, turns


def reduce_rotary(y, lsb, segments: dict, angle=None) -> Reduced:
    """Eq. (18) readings M (m x n) from recordings y (n, k, m) in counts (or SI with lsb = 1).

    lsb : SI units per count, scalar or (m,).
    segments : {"static": window, "rotating": window}, each (2,) or (n, 2) [start, stop) indices.
    angle : None, (k,) or (n, k) table angle in rad (cumulative); cuts whole revolutions.
    """
    y = np.asarray(y)
    if y.ndim != 3:
        raise CalibrationInputError(
            f"recordings have shape {y.shape}.", "Give y as (positions, samples, sensors)."
        )
    n, k, m = y.shape
    scale = np.broadcast_to(np.asarray(lsb, float), (m,))
    static = _windows(segments["static"], n, k, "static")
    rotating = _windows(segments["rotating"], n, k, "rotating")
    if angle is not None:
        angle = np.broadcast_to(np.asarray(angle, float), (n, k))
    stats = np.empty((4, n, m))
    counts = np.empty((2, n))
    revs = np.zeros(n, int)
    for j in range(n):
        r0, r1 = rotating[j]
        if angle is not None:
            r1, revs[j] = whole_revolutions(angle[j], r0, r1)
        for w, (a, b) in enumerate(((static[j]), (r0, r1))):
            x = y[j, a:b].astype(float)
            stats[w, j], stats[2 + w, j], counts[w, j] = x.mean(0), x.std(0, ddof=1), b - a
    s_mean, r_mean, s_sd, r_sd = (scale * s for s in stats)
    return Reduced(
        M=(r_mean - s_mean).T,
        static_mean=s_mean.T,
        rotating_mean=r_mean.T,
        static_sd=s_sd.T,
        rotating_sd=r_sd.T,
        n_static=counts[0],
        n_rotating=counts[1],
        revolutions=revs,
    )


def reduce_arrays(arrays) -> Reduced:
    """Eq. (18) reduction of a rotary data file's arrays (keys of docs/simulator.md).

    Uses the stored table `angle` when present, otherwise the integral of `rate_cmd`.
    """
    angle = arrays.get("angle")
    if angle is None and "rate_cmd" in arrays:
        rate = np.asarray(arrays["rate_cmd"], float)
        angle = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]))]) / float(
            arrays["fs"]
        )
    segments = {"static": arrays["seg_static"], "rotating": arrays["seg_rotating"]}
    return reduce_rotary(arrays["y"], arrays["lsb"], segments, angle=angle)
