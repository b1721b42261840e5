"""A fault knob of the virtual rotary benches: spiky windows, as a glitching sensor or a noisy link
gives them (issue 30: a campaign must record such a position again, not keep it).

`SpikySource(source, mounted, spikes, counts_per_unit, seed)` is the IMU twin's sample source
`source` (times -> counts) with spikes added to the first attempt at chosen positions:

- a position is a placement of the unit (`station.sim.live.MountedUnit.placement`: an
  orientation set by the technician, the fixture or a two-axis table's position axis) that the
  table turned at; positions are counted from 1 over the bench's life (a thermal campaign's soak
  s, position j is (s - 1) n + j for n positions a soak); a placement the table never turned at
  is none (its samples, in no window, are spiked as the next position's would be), and a two-axis
  table's spin of its position axis, which keeps the placement of the position before it, is no
  position of its own (never spiked);
- `spikes` chooses them: a list of positions, or a chance per position (a number in [0, 1], each
  position drawn from the seed);
- the first attempt at a position lasts from its placement until the table has turned and come
  to rest again: its static and rotating windows. A redo of the position (the same placement,
  turned again) is clean;
- in it each sample is spiked with probability `DENSITY`: one sensor channel (of the first
  `channels`, not a temperature) gets `SIZE` rad/s of either sign, hundreds of its noise's
  standard deviations.

Deterministic with the seed in lockstep time: each position's spikes come from its own generator
([seed, 31, position]) drawn in the order of the samples, whatever blocks the host asks for.
"""

import numbers

import numpy as np

from station.errors import InputError

DENSITY = 0.02
"""Chance that a sample of a spoiled attempt is a spike."""
SIZE = 0.5
"""SI units (rad/s) a spike adds to its channel."""
MOVING = 0.01
"""rad/s: a table turning faster than this is turning (its rest noise is 1e-4 rad/s)."""


def check_spikes(spikes) -> None:
    """InputError unless `spikes` is None, a chance in [0, 1] or a list of positions (>= 1)."""
    if spikes is None:
        return
    if isinstance(spikes, numbers.Real) and not isinstance(spikes, bool):
        if 0 <= spikes <= 1:
            return
    elif isinstance(spikes, list | tuple) and len(spikes) <= 10_000 and all(
            isinstance(p, int) and not isinstance(p, bool) and p >= 1 for p in spikes):
        return
    raise InputError(f"spikes must be a chance per position from 0 to 1 or a list of positions "
                     f"(whole numbers from 1), got {spikes!r}")


class SpikySource:
    """`times -> counts`: `source`'s counts with spikes in the first attempt at the positions
    `spikes` chooses (module docstring). `mounted`: the `MountedUnit` the source reads (its
    placements, its table's motion); `counts_per_unit` the stream's scale; `channels`: the sensor
    columns that may spike (default: the unit's m)."""

    def __init__(self, source, mounted, spikes, counts_per_unit, seed: int = 1,
                 channels: int | None = None):
        check_spikes(spikes)
        self.source, self.mounted, self.spikes, self.seed = source, mounted, spikes, int(seed)
        self.channels = mounted.unit.m if channels is None else int(channels)
        scale = np.atleast_1d(np.asarray(counts_per_unit, float))
        self.size = SIZE * (np.full(self.channels, scale[0]) if scale.size == 1
                            else scale[: self.channels])
        self.turned = 0  # positions: placements the table turned at, so far
        self._phase = {}  # placement -> 0 not turned yet, 1 turning, 2 first attempt over
        self._position = {}  # placement -> its position (1-based), once seen
        self._rng = {}  # position -> its spikes' generator

    def spoiled(self, position: int) -> bool:
        """Is the first attempt at `position` (1-based) spiky?"""
        if isinstance(self.spikes, list | tuple):
            return position in self.spikes
        draw = np.random.default_rng([self.seed, 30, position]).random()
        return self.spikes is not None and draw < self.spikes

    def __call__(self, times) -> np.ndarray:
        times = np.atleast_1d(np.asarray(times, float))
        counts = np.array(self.source(times), dtype=np.int64)
        which = self.mounted.placement(times)
        moving = self._rates(times) > MOVING
        for k in np.unique(which):
            here = np.flatnonzero(which == k)
            first = self._first_attempt(int(k), moving[here])
            position = self._position[int(k)]
            if first and self.spoiled(position):
                self._spike(counts, here[:first], position)
        return counts

    def _rates(self, times) -> np.ndarray:
        """|rate| of the table (plus a two-axis table's position axis) at `times`, rad/s."""
        rates = np.abs(self.mounted.table.true_rates(times))
        if self.mounted.inner is not None:
            rates = rates + np.abs(self.mounted.inner[0].true_rates(times))
        return rates

    def _first_attempt(self, k: int, moving: np.ndarray) -> int:
        """How many of placement k's samples (in time order, `moving`: the table turning at each)
        belong to its first attempt; counts the position when the table starts turning."""
        if k not in self._position:
            self._position[k] = self.turned + 1
            self._phase[k] = 0
        phase = self._phase[k]
        if phase == 2:
            return 0
        started = np.maximum.accumulate(moving) | (phase == 1)
        if phase == 0 and started.any():
            self.turned += 1
        over = np.flatnonzero(started & ~moving)
        self._phase[k] = 2 if over.size else 1 if started.any() else 0
        return int(over[0]) if over.size else len(moving)

    def _spike(self, counts: np.ndarray, rows: np.ndarray, position: int) -> None:
        """Spike `rows` of `counts` in place, from the position's generator, in sample order."""
        rng = self._rng.setdefault(position, np.random.default_rng([self.seed, 31, position]))
        draw = rng.random((len(rows), 3))
        hit = draw[:, 0] < DENSITY
        channel = np.minimum((draw[hit, 1] * self.channels).astype(int), self.channels - 1)
        sign = np.where(draw[hit, 2] < 0.5, -1.0, 1.0)
        counts[rows[hit], channel] += np.round(sign * self.size[channel]).astype(np.int64)
