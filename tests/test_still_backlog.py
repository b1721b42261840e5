"""A pose held still is taken even when a busy host receives its samples late, in one burst that
already holds the technician's next turn (CI: the metronome technician of `station twin` turned
on while a loaded host was still draining a pose; the station called the pose "moved", took the
next one in its place and timed out at the last)."""

import io

import numpy as np

from drivers.clock import ScaledClock
from drivers.samples import SampleBlock
from station.acquire.operator import ConsoleOperator
from station.acquire.recorder import Recorder
from station.protocols.still import PoseWatcher, StillSettings, StreamTap
from station.session import SessionWriter, StreamSpec

RATE = 200.0
LSB = 1e-3  # m/s^2 per count
SIGMA = 0.01  # m/s^2 white noise
STILL = (3.0, 12.0)  # clock s: the pose is held between the turns
STALL = (7.5, 14.5)  # clock s: the host receives nothing, then all that is due at once


def _reading(t: np.ndarray, rng) -> np.ndarray:
    """(k, 3) counts of a triad turned by hand before 3 s and between 12 and 14 s, still
    otherwise (gravity along z, then along x)."""
    turning = (t < STILL[0]) | ((t >= STILL[1]) & (t < STILL[1] + 2.0))
    g = np.where((t >= STILL[1])[:, None], [9.8, 0.0, 0.0], [0.0, 0.0, 9.8])
    g = g + turning[:, None] * 3.0 * np.sin(7.0 * t)[:, None]
    return np.round((g + SIGMA * rng.standard_normal(g.shape)) / LSB).astype(np.int64)


class BackloggedImu:
    """An IMU driver whose samples reach the host on time, except in `STALL` (see above)."""

    def __init__(self, clock):
        self.clock, self.next = clock, 0
        self.rng = np.random.default_rng(4)

    def read_block(self, timeout: float = 0.0):
        now = self.clock.now()
        if STALL[0] <= now < STALL[1]:
            return None
        due = int(now * RATE)
        if due <= self.next:
            return None
        seq = np.arange(self.next, due)
        self.next = due
        return SampleBlock(_reading(seq / RATE, self.rng), seq, np.full(len(seq), np.nan),
                           np.full(len(seq), now), ("a1", "a2", "a3"))


def test_a_pose_drained_late_with_the_next_turn_in_the_burst_is_taken(tmp_path):
    clock = ScaledClock(10.0)
    spec = StreamSpec(("a1", "a2", "a3"), "m/s^2", 1 / LSB, RATE)
    imu = BackloggedImu(clock)
    tap = StreamTap(imu, RATE, spec.counts_per_unit)
    said = io.StringIO()
    settings = StillSettings(gravity=9.8)
    with SessionWriter.create(tmp_path / "s.h5", {"protocol": "static", "unit_serial": "T"},
                              {"imu": spec}, clock=clock) as writer, \
            Recorder(writer, tap, clock=clock) as recorder:
        watcher = PoseWatcher(settings, clock, ConsoleOperator(io.StringIO(), said), recorder,
                              tap)
        watcher.request()
        start = watcher.settle("asking for pose 1")
        held = watcher.hold(0)
    assert STILL[0] < start < STILL[0] + settings.min_still, start
    assert clock.now() >= STALL[1]  # the window's samples came in the burst, with the next turn
    assert held is not None, said.getvalue()
    mean, _ = held
    # 5 s at 200 Hz: the mean's standard error is 0.01 / sqrt(1000) = 3.2e-4 m/s^2
    np.testing.assert_allclose(mean, [0.0, 0.0, 9.8], atol=5 * SIGMA / np.sqrt(1000) + LSB)
