"""A continuous rotation without still poses -> readings of short blocks (a magnetometer turned by
hand: hard- and soft-iron calibration on the ellipsoid, Eq. 8 with the biases estimated).

The recording is cut into blocks of `seconds`. Within a block the field turns, so each channel's
samples are fitted with a parabola in time (orthogonal polynomials 1, t, t^2 - <t^2>): the block's
reading is the parabola at the block's centre, its standard error from the scatter about the
parabolas pooled over the blocks (one per channel: a block of 5 samples at 50 Hz leaves 2 degrees
of freedom, whose own scatter is 0 now and then for readings in whole counts, and weighting by it
would trust some blocks without bound). A plain mean would be shortened by theta^2 / 24 for a turn
of theta radians within the block (0.1 % at 9 deg: a scale-factor bias); the parabola's centre is
exact to third order (the error left is about theta^4 / 1920, 4e-5 at 30 deg). Blocks whose
readings turned by more than `max_turn_deg` are still left out.
"""

from dataclasses import dataclass

import numpy as np

from station.errors import CalibrationInputError

SECONDS = 0.1
"""Default block length."""
MAGNETOMETER = "T"
MAX_TURN_DEG = 30.0
"""Blocks whose field turned by more than this are left out (centre error above 4e-5)."""


@dataclass(frozen=True)
class BlockReadings:
    """Readings of the blocks kept: M, sigma (m, n) (the parabola at each block's centre and its
    standard error, pooled per channel), windows (n, 2) sample indices [start, stop),
    turned_deg (n,) the field's turn within each block, dropped: blocks left out (turned too far,
    or too few samples)."""

    M: np.ndarray
    sigma: np.ndarray
    windows: np.ndarray
    turned_deg: np.ndarray
    dropped: int

    def constraints(self):
        """No inner-product constraints between blocks: equal magnitudes only (Eq. 8)."""
        return None

    def take(self, keep):
        """The readings of the blocks `keep` (column indices), in that order."""
        keep = list(keep)
        return BlockReadings(self.M[:, keep], self.sigma[:, keep], self.windows[keep],
                             self.turned_deg[keep], self.dropped)


def block_readings(samples, fs: float, seconds: float = SECONDS,
                   max_turn_deg: float = MAX_TURN_DEG) -> BlockReadings:
    """Readings of a continuous recording `samples` (k, m) at `fs` Hz in blocks of `seconds`."""
    z = np.asarray(samples, float)
    if z.ndim != 2 or not np.all(np.isfinite(z)):
        raise CalibrationInputError(f"samples of shape {z.shape} (or not finite).",
                                    "Give (samples, channels) finite readings.")
    size = int(round(seconds * fs))
    if size < 4:
        raise CalibrationInputError(
            f"blocks of {seconds:g} s hold {size} samples at {fs:g} Hz; a parabola through a "
            "block needs 4 or more.", "Give a longer --block (seconds).")
    n = len(z) // size
    blocks = z[:n * size].reshape(n, size, z.shape[1])
    t = np.arange(size) - (size - 1) / 2
    basis = np.stack([np.ones(size), t, t ** 2 - np.mean(t ** 2)])  # orthogonal on the block
    coef = np.einsum("pt,ntm->npm", basis, blocks) / (basis ** 2).sum(axis=1)[None, :, None]
    residual = blocks - np.einsum("npm,pt->ntm", coef, basis)
    at_centre = basis[:, size // 2] if size % 2 else np.array([1.0, 0.0, -np.mean(t ** 2)])
    centre = np.einsum("p,npm->nm", at_centre, coef)
    gain = np.sqrt(np.sum(at_centre ** 2 / (basis ** 2).sum(axis=1)))  # sd of centre / noise
    ss = (residual ** 2).sum(axis=1)  # (n, m): each block's scatter about its parabola
    sigma = np.broadcast_to(np.sqrt(ss.mean(axis=0) / (size - 3)) * gain, ss.shape)
    if not np.all(sigma > 0):
        flat = np.flatnonzero(~(sigma[0] > 0)).tolist()
        raise CalibrationInputError(
            f"channel(s) {flat} never vary about their parabolas (constant or stuck readings).",
            "Check the recording: a magnetometer turned by hand reads a changing field.")
    ends = np.einsum("npm,pt->ntm", coef, basis[:, [0, -1]])
    turned = _turned_deg(ends[:, 0], ends[:, 1])
    keep = turned <= max_turn_deg
    windows = np.stack([np.arange(n) * size, (np.arange(n) + 1) * size], axis=1)
    return BlockReadings(centre[keep].T, sigma[keep].T, windows[keep], turned[keep],
                         int(n - keep.sum()))


def magnetometer_readings(session, stream: str, seconds: float = SECONDS) -> BlockReadings:
    """Block readings of the channels in T of a recorded or imported stream, blocks cut within
    the runs of consecutive sample numbers (a lost sample ends a run; a block never spans a
    gap)."""
    data = session.stream(stream)
    z, fs = data.to_si()[:, magnetometer_channels(session, stream)], session.specs[stream].rate_hz
    breaks = np.flatnonzero(np.diff(data.seq) != 1) + 1
    runs = [(a, b) for a, b in zip(np.r_[0, breaks], np.r_[breaks, len(z)], strict=True)
            if b - a >= round(seconds * fs)]
    if not runs:
        raise CalibrationInputError(f"{session.path}: stream {stream!r} holds no run of "
                                    f"{seconds:g} s of consecutive samples.",
                                    "Record the magnetometer turning for a minute or more.")
    parts = [block_readings(z[a:b], fs, seconds) for a, b in runs]
    return BlockReadings(np.hstack([p.M for p in parts]), np.hstack([p.sigma for p in parts]),
                         np.vstack([p.windows + a for p, (a, _) in zip(parts, runs, strict=True)]),
                         np.concatenate([p.turned_deg for p in parts]),
                         sum(p.dropped for p in parts))


def magnetometer_channels(session, stream: str) -> np.ndarray:
    """Indices of a stream's channels in T."""
    return np.flatnonzero([u == MAGNETOMETER for u in session.specs[stream].units])


def _turned_deg(first, last) -> np.ndarray:
    """Angle swept between a block's start and end readings (the chord over the mean's length),
    degrees; the bias is included, so it is close when the field dominates the bias."""
    chord = np.linalg.norm(last - first, axis=1)
    radius = np.linalg.norm(first + last, axis=1) / 2
    return np.degrees(2 * np.arcsin(np.clip(chord / (2 * radius), 0.0, 1.0)))
