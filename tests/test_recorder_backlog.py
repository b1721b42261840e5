"""A recorder that starts behind its device catches up, so that its samples' instants are right
(issue 16: a resumed session of three units came out with a rotating window seconds off).

The sampling instants of a segment come from its least-delayed sample
(`station.reduce.timeline.arrival_offset`): if no sample of the segment arrives promptly, every
instant is late by the smallest delay. A segment starts with a backlog when the port was opened
before the recorder reads it (the device, flow-controlled, holds back what the port cannot take);
the recorder used to wait `interval` after every block, and a port hands over at most its buffer a
read (a pty: 4 KB, 70 frames of 58 bytes), so a stream that brings more than a buffer an interval
was never caught up with. The virtual device knows each frame's true instant (the shared clock), so
the test compares the recorded instants with it. No mocks: a pty twin and the serial driver.
"""

import dataclasses

import numpy as np

from drivers import open_imu
from drivers.clock import ScaledClock
from drivers.profile import SerialImuProfile
from drivers.twins.serial import SerialTwin
from station.acquire.recorder import Recorder
from station.reduce.timeline import sample_times
from station.session import Session, SessionWriter, StreamSpec

BASE = SerialImuProfile.load("imu12_serial")
PROFILE = dataclasses.replace(BASE, imu=dataclasses.replace(BASE.imu, rate_hz=200.0))
SPEED = 2.0
"""Clock speed: 200 Hz on it is 400 frames (23 KB) a wall second: a reader starved by a busy host
(an eighth of a core) still reads them many times over (at 10x, 2000 frames a wall second, one
beside 6 CPU hogs and a whole test suite never caught up: every instant 4.7 s late)."""
INTERVAL = 0.25
"""The recorder's pause (wall s): one pty buffer (70 frames) a pause carries 280 frames a wall
second, fewer than the device sends, so only a reader that reads on while blocks come catches up,
however fast the host; and a full buffer is more than half what a pause brings (50 frames), so the
reader does read on (`Recorder._read`)."""
BACKLOG = 3.0
"""Clock seconds the port is open before the recorder reads it."""


def zeros(times):
    """The device's counts: the instants are what is tested, not the values."""
    return np.zeros((len(times), len(PROFILE.imu.channels)), np.int64)


def test_a_recorder_that_starts_behind_catches_up_and_times_its_samples_right(tmp_path):
    clock = ScaledClock(SPEED)
    twin = SerialTwin(PROFILE, zeros, clock=clock, max_lag=np.inf)  # flow control: no frame lost
    spec = StreamSpec.from_profile(PROFILE.imu)
    with twin, open_imu("serial", twin.port, PROFILE, clock) as imu:
        clock.sleep(BACKLOG)  # the port is open, nobody reads it: the device holds frames back
        with SessionWriter.create(tmp_path / "s.h5", {"protocol": "rotary", "unit_serial": "T"},
                                  {"imu": spec}, clock=clock) as writer, \
                Recorder(writer, imu, clock=clock, interval=INTERVAL) as recorder:
            started = clock.now()
            clock.sleep(20.0)
            recorder.check(stale=1e9)
    with Session.open(tmp_path / "s.h5") as session:
        data = session.stream("imu", columns=("seq", "host_time"))
    assert data.seq[0] < (started - twin.start_time - 1.0) * PROFILE.imu.rate_hz  # the backlog
    error = sample_times(data.seq, data.host_time, PROFILE.imu.rate_hz) - twin.time_of(data.seq)
    # Caught up, the newest frame of a read is at most the twin's 2 ms write period plus the
    # reader's wake-up old; 20 wall ms (0.2 clock s) is ten times that. Never caught up, every
    # instant is late by the backlog: 3 clock s and more (the recorder before the fix: 3.45 s).
    assert np.all(np.abs(error) < 0.2), (error.min(), error.max())
