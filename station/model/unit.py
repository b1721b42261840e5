"""A simulated sensor unit: m single-axis sensors with a true sensitivity matrix (conventions.md).

Output of sensor i for the SI stimulus v: z_i = a_i . v + b_i + walk_i(t) + noise, quantised to
integer counts with `counts_per_unit` (counts per SI unit). White noise is given as a noise
density N (units/sqrt(Hz)); sampled at fs its standard deviation is N sqrt(fs), so the mean over
T seconds has standard deviation N / sqrt(T). The bias random walk `bias_walk` is the standard
deviation of the bias change after one second (units/sqrt(s)).

A live twin's samples (`sample` with their times) draw their noise and walk steps from streams
indexed by the sample instant (`indexed_normals`): the same instant gets the same draws whatever
blocks the host's timing cut the stream into, so a seeded twin repeats its samples.
"""

import numpy as np

from station.model import measurement, sensing

NOISE_CHUNK = 4096
"""Samples per block of the indexed noise streams (`SensorUnit.indexed_normals`)."""


def _per_sensor(value, m: int, name: str) -> np.ndarray:
    """Broadcast a scalar or an (m,) sequence to (m,) floats, refusing other shapes."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        return np.full(m, float(arr))
    if arr.shape != (m,):
        raise ValueError(
            f"{name} must be a scalar or have one value per sensor ({m}), got shape {arr.shape}"
        )
    return arr


class SensorUnit(measurement.Sensitivity):
    """m single-axis sensors; `a` is d x m in output SI units per stimulus SI unit (1 = nominal).

    Parameters
    ----------
    a : (d, m) true sensitivity matrix.
    bias : scalar or (m,) biases, output SI units.
    noise_density : scalar or (m,) white-noise density, units/sqrt(Hz).
    fs : sample rate, Hz.
    counts_per_unit : scalar or (m,) quantisation scale, counts per SI unit.
    output_range : scalar or (m,) full scale +-range, SI units (used by the `saturation` effect).
    bias_walk : scalar or (m,) bias random walk, units/sqrt(s).
    rng : numpy Generator (or seed) for the noise.
    """

    def __init__(
        self,
        a,
        bias=0.0,
        noise_density=0.0,
        fs=200.0,
        counts_per_unit=1e4,
        output_range=np.inf,
        bias_walk=0.0,
        rng=None,
    ):
        self.a = np.array(a, dtype=float, ndmin=2)
        if self.a.ndim != 2 or not np.all(np.isfinite(self.a)):
            raise ValueError(
                f"sensitivity a must be a finite d x m matrix, got shape {self.a.shape}"
            )
        if not fs > 0:
            raise ValueError(f"sample rate fs must be positive (Hz), got {fs!r}")
        m = self.m
        self.bias = _per_sensor(bias, m, "bias")
        self.noise_density = _per_sensor(noise_density, m, "noise_density")
        self.counts_per_unit = _per_sensor(counts_per_unit, m, "counts_per_unit")
        self.output_range = _per_sensor(output_range, m, "output_range")
        self.bias_walk = _per_sensor(bias_walk, m, "bias_walk")
        if np.any(self.counts_per_unit <= 0) or np.any(self.noise_density < 0):
            raise ValueError("counts_per_unit must be positive and noise_density non-negative")
        self.fs = float(fs)
        self.rng = np.random.default_rng(rng)
        self._chunks = {}  # indexed stream -> (block number, its normals)
        self._walk = np.zeros(m)
        self._last_time = None

    @property
    def sigma(self) -> np.ndarray:
        """(m,) standard deviation of one sample's white noise, N sqrt(fs)."""
        return self.noise_density * np.sqrt(self.fs)

    @property
    def lsb(self) -> np.ndarray:
        """(m,) SI units per count."""
        return 1.0 / self.counts_per_unit

    def mean_sigma(self, samples) -> np.ndarray:
        """(m,) standard deviation of the mean of `samples` quantised samples.

        White noise plus the quantisation error (uniform, lsb^2 / 12, independent from sample to
        sample when the noise spans several counts).
        """
        return np.sqrt((self.sigma**2 + self.lsb**2 / 12) / np.asarray(samples, float))

    def project(self, v: np.ndarray) -> np.ndarray:
        """Noise-free sensed signals a^T v for stimuli v (..., d) -> (..., m)."""
        return np.asarray(v, float) @ self.a

    def noise(self, shape: tuple) -> np.ndarray:
        """White noise of shape (..., m) with the unit's per-sample standard deviation."""
        out = self.rng.standard_normal(shape)
        out *= self.sigma
        return out

    def walk(self, n: int, k: int, gaps=None) -> np.ndarray:
        """(n, k, m) bias random walk over n recordings of k samples, continuing from the last call.

        `gaps` (n,) are the seconds elapsed before each recording starts (the walk keeps going
        while nobody records); the walk state carries over to the next call.
        """
        if not np.any(self.bias_walk):
            return np.zeros((n, k, self.m))
        step = self.bias_walk / np.sqrt(self.fs)
        inc = self.rng.standard_normal((n, k, self.m)) * step
        if gaps is not None:
            inc[:, 0, :] = (
                self.rng.standard_normal((n, self.m))
                * self.bias_walk
                * np.sqrt(np.maximum(np.asarray(gaps, float), 0.0))[:, None]
            )
        out = self._walk + np.cumsum(inc.reshape(n * k, self.m), axis=0).reshape(n, k, self.m)
        self._walk = out[-1, -1].copy()
        return out

    def indexed_normals(self, times, stream: int) -> np.ndarray:
        """(k, m) standard normals for the samples at `times` (s): sample index i = round(t fs)
        takes row i mod NOISE_CHUNK of block i // NOISE_CHUNK of stream `stream`, drawn from its
        own SeedSequence (the unit's seed entropy, spawn key (stream, block)); the same instant
        gets the same value whatever the calls' block sizes."""
        index = np.rint(np.asarray(times, float) * self.fs).astype(np.int64)
        out = np.empty((index.size, self.m))
        blocks = index // NOISE_CHUNK
        for block in np.unique(blocks):
            here = blocks == block
            out[here] = self._chunk(stream, int(block))[index[here] % NOISE_CHUNK]
        return out

    def _chunk(self, stream: int, block: int) -> np.ndarray:
        """Block `block` of indexed stream `stream` (the last one drawn is kept)."""
        kept = self._chunks.get(stream)
        if kept is None or kept[0] != block:
            seed = self.rng.bit_generator.seed_seq
            key = (*seed.spawn_key, stream, block + 2**62)  # spawn keys are non-negative
            sequence = np.random.SeedSequence(seed.entropy, spawn_key=key)
            kept = (block, np.random.default_rng(sequence).standard_normal((NOISE_CHUNK, self.m)))
            self._chunks[stream] = kept
        return kept[1]

    def quantise(self, z: np.ndarray) -> np.ndarray:
        """Integer counts round(z * counts_per_unit) as int32 (saturating at the int32 limits)."""
        info = np.iinfo(np.int32)
        c = np.multiply(z, self.counts_per_unit)
        np.rint(c, out=c)
        np.clip(c, info.min, info.max, out=c)
        return c.astype(np.int32)

    def sample(self, v_si: np.ndarray, times=None, effects=None) -> np.ndarray:
        """Counts (k, m) for the stimulus v_si (k, d) in SI units, for the live serial/CAN twins:
        the sensor output chain (station.model.sensing.sense) on one block of samples.

        `times` (k,) are the sample times in session seconds (default: consecutive samples at fs
        from 0); noise, bias and bias walk are included, the walk stepping by the actual time
        between samples and continuing from call to call; with `times`, the noise and the walk's
        steps are the indexed streams' (`indexed_normals`). `effects` {name: parameters} are named
        sensor effects (station.model.effects) a live twin can apply block by block
        (sensing.LIVE_EFFECTS).
        """
        v = np.asarray(v_si, float)
        if v.ndim != 2 or v.shape[1] != self.d:
            raise ValueError(f"stimulus must have shape (k, {self.d}), got {v.shape}")
        effects = effects or {}
        sensing.refuse_batch_effects(effects)
        k = v.shape[0]
        t = np.arange(k) / self.fs if times is None else np.asarray(times, float)
        noise = None if times is None else (lambda: (self.indexed_normals(t, 0) * self.sigma)[None])
        return sensing.sense(self, self.project(v)[None], t, np.zeros(1), np.zeros((1, k)),
                             effects, walk=lambda: self._live_walk(k, times)[None],
                             noise=noise)[0]

    def _live_walk(self, k: int, times) -> np.ndarray:
        """(k, m) bias walk at the sample times, continuing from the previous call."""
        if times is None:
            dt = np.full(k, 1.0 / self.fs)
        else:
            t = np.asarray(times, float)
            prev = t[0] - 1.0 / self.fs if self._last_time is None else self._last_time
            dt = np.maximum(np.diff(t, prepend=prev), 0.0)
            self._last_time = t[-1]
        steps = (self.rng.standard_normal((k, self.m)) if times is None
                 else self.indexed_normals(times, 1))
        out = self._walk + np.cumsum(steps * self.bias_walk * np.sqrt(dt)[:, None], axis=0)
        self._walk = out[-1].copy()
        return out
