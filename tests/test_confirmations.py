"""Each position or pose is confirmed to the technician as it is captured, with its quality: the
samples found against those due, the noise against the truth of the simulated unit, and a warning
when the window is out of line (station.reduce.window_quality)."""

import re

import numpy as np
import pytest
from scipy import stats

from station.acquire.recorder import Recorder
from station.protocols.iron import IronProtocol, IronSettings
from station.protocols.rotary import RotarySettings, suggested_axes
from station.protocols.still import StreamTap
from station.reduce.rotary import position_windows
from station.reduce.timeline import sample_times
from station.reduce.window_quality import describe, window_quality
from station.session import Session, SessionWriter
from station.twin.hand_bench import ACC4, HandBench
from station.twin.rotary_bench import VirtualBench, record_rotary

FAST = RotarySettings(rate=1.0, revolutions=1, static=3.0, rest=0.5, guard=0.5, steady=0.5)
FALSE_ALARM = 1e-4
"""Chance that a window's measured noise falls outside the chi-square bounds below."""
FIGURES = re.compile(r"(\d+)/(\d+) samples, noise ([0-9.e+-]+) ")


def noise_bounds(sigma, samples: int):
    """(low, high) bounds of the RMS over the channels of the sample standard deviations of
    `samples` samples of white noise of standard deviations `sigma` (m,): the pooled variance is
    sigma^2 chi2(dof) / dof with dof = m (samples - 1), when the channels' sigmas are equal."""
    dof = len(sigma) * (samples - 1)
    q = stats.chi2.ppf([FALSE_ALARM / 2, 1 - FALSE_ALARM / 2], dof) / dof
    return np.sqrt(np.mean(sigma**2) * q)


def white_sigma(unit) -> np.ndarray:
    """(m,) standard deviation of one quantised sample: white noise and lsb^2 / 12."""
    return np.sqrt(unit.sigma**2 + unit.lsb**2 / 12)


def test_rotary_positions_are_confirmed_with_their_samples_and_noise(tmp_path):
    path = tmp_path / "rotary.h5"
    with VirtualBench(seed=3, remount_time=1.0) as bench:
        record_rotary(bench, path, FAST, suggested_axes(3))
        said = [m for m in bench.technician.messages if "captured" in m]
        sigma = white_sigma(bench.unit)
    with Session.open(path) as s:
        data, events = s.stream("imu"), s.events()
    rate = data.spec.rate_hz
    t = sample_times(data.seq, data.host_time, rate)
    assert [m.split(":")[0] for m in said] == [f"position {j}/3 captured" for j in (1, 2, 3)]
    for j, message in enumerate(said):
        static, rotating = FIGURES.findall(message)
        for (found, due, _), (t0, t1) in zip((static, rotating),
                                             position_windows(events)[j].values(), strict=True):
            in_file = int(np.sum((t >= t0) & (t <= t1)))
            assert abs(int(found) - in_file) <= 1, (message, in_file)  # the tap's own timing
            assert int(due) == round((t1 - t0) * rate)
        low, high = noise_bounds(sigma, int(static[0]))
        assert low < float(static[2]) < high, (message, low, high)
        assert "WARNING" not in message
        assert ("as expected" in message) == (j > 0)  # position 1 has no earlier windows


def test_iron_poses_are_confirmed_with_their_samples_and_noise(tmp_path):
    with HandBench(seed=2, period=20.0) as bench, bench.driver() as imu:
        settings = IronSettings(gravity=bench.gravity, mountings=1)
        protocol = IronProtocol(bench.technician, bench.clock, ACC4, settings)
        tap = StreamTap(imu, bench.stream_spec.rate_hz, bench.stream_spec.counts_per_unit)
        writer = SessionWriter.create(tmp_path / "iron.h5",
                                      {**protocol.metadata(), "unit_serial": "T"},
                                      {"imu": bench.stream_spec}, clock=bench.clock)
        with writer, Recorder(writer, tap, clock=bench.clock) as recorder:
            protocol.run(recorder, tap)
        said = [m for m in bench.technician.messages if "captured" in m]
        sigma = white_sigma(bench.unit)
    due = settings.hold * bench.stream_spec.rate_hz
    assert len(said) == 6
    for j, (message, face) in enumerate(zip(said, protocol.labels, strict=True)):
        assert message.startswith(f"pose {j + 1}/6 captured (face {face}): still 5.0 s, ")
        found, shown_due, noise = FIGURES.search(message).groups()
        assert int(shown_due) == due and abs(int(found) - due) <= 1, message
        low, high = noise_bounds(sigma, int(found))
        assert low < float(noise) < high, (message, low, high)
        assert message.endswith("the rest noise, as expected)"), message


def _window(noise, n=2000, rate=200.0, seed=0):
    """Times and readings (n, 3) of a still window at `rate` with per-channel `noise`."""
    rng = np.random.default_rng(seed)
    return np.arange(n) / rate, rng.standard_normal((n, 3)) * noise


def test_a_noisy_or_lossy_window_is_warned_of():
    lsb = 1e-4
    t, z = _window(0.01)
    quiet = window_quality(t, z, (0.0, 10.0), 200.0, lsb, reference=np.full(3, 0.01))
    assert quiet.ok and quiet.found == 2000
    assert "WARNING" not in describe(quiet, "m/s^2") and "as expected" in describe(quiet, "m/s^2")
    # 2.5 times the reference noise: variance ratio 6.25 > the detector's enter (4)
    t, z = _window(0.025)
    noisy = window_quality(t, z, (0.0, 10.0), 200.0, lsb, reference=np.full(3, 0.01))
    assert noisy.noisy and "WARNING: 2.5x" in describe(noisy, "m/s^2", "the rest noise")
    # a fifth of the samples lost: the reduction's coverage check (90 %) would refuse it
    keep = np.arange(2000) % 5 != 0
    lossy = window_quality(t[keep], z[keep], (0.0, 10.0), 200.0, lsb)
    assert not lossy.ok and "1600 samples where 2000 were due" in describe(lossy, "m/s^2")
    # a stuck channel, as the reduction refuses it
    z[:, 1] = 0.02
    stuck = window_quality(t, z, (0.0, 10.0), 200.0, lsb)
    assert "channel(s) 2 kept one value" in (stuck.problem or "")


@pytest.mark.parametrize("n", [0, 1])
def test_a_window_without_samples_is_a_problem_not_a_crash(n):
    t, z = _window(0.01, n=n)
    q = window_quality(t, z, (0.0, 10.0), 200.0, 1e-4, reference=np.full(3, 0.01))
    assert q.problem and f"holds {n} samples" in describe(q, "m/s^2")
