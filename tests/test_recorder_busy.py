"""A recorder whose samples lag behind says which option to use (issue: the demo on a busy host
failed with "host too busy" and no advice)."""

import pytest

from drivers.clock import ScaledClock, WallClock
from station.acquire.recorder import Recorder
from station.errors import RecordingError
from station.session import SessionWriter, StreamSpec


class Silent:
    """An IMU that is open but delivers nothing (the samples are stuck behind a busy host)."""

    def read_block(self, timeout: float = 0.0):
        return None


@pytest.mark.parametrize("clock, advice", [(ScaledClock(40.0), "give --speed 10"),
                                           (WallClock(), "close other programs")])
def test_lagging_samples_name_the_option_that_helps(tmp_path, clock, advice):
    spec = StreamSpec(("g1", "g2", "g3"), "rad/s", 1000.0, 200.0)
    metadata = {"protocol": "rotary", "unit_serial": "T"}
    with SessionWriter.create(tmp_path / "s.h5", metadata, {"imu": spec}, clock=clock) as writer, \
            Recorder(writer, Silent(), clock=clock, drain_timeout=0.2) as recorder, \
            pytest.raises(RecordingError, match=f"too busy.*{advice}"):
        recorder.drain(clock.now() + 1.0, stale=1e9)
