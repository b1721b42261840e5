"""A technician pressing Ctrl-C twice: the second interrupt lands anywhere in the handling of
the first (a still-pose protocol's `run_states`: its `except` block, the abort event's write in
the session writer and h5py), and still the abort is recorded, the file closes whole and the
first interrupt is what the protocol raises (`station.acquire.interrupts.handling`). A real
SIGINT each time, through the station's installed handler."""

import contextlib
import os
import signal
import threading
from pathlib import Path

import h5py
import numpy as np
from signal_places import interrupted_at

import station.session
from drivers.samples import SampleBlock
from station.acquire import interrupts
from station.protocols import still
from station.session import Session, SessionWriter, StreamSpec


class Pose:
    """A still-pose protocol whose pose is interrupted by Ctrl-C (a real SIGINT)."""

    position = 0

    def __init__(self):
        self.state, self.interrupted = None, False
        self.handlers = {"pose": self.pose}

    def pose(self) -> str:
        self.interrupted = True
        os.kill(os.getpid(), signal.SIGINT)  # the installed handler raises here
        return "done"


def second_ctrl_c_at(k: int, path: Path) -> str | None:
    """Run the protocol into a new session with a second SIGINT at the k-th place after the
    first; check what must hold; where the second landed (None: the handling ended first)."""
    spec = StreamSpec(("a1", "a2", "a3"), "m/s^2", 1000.0, 100.0)
    writer = SessionWriter.create(path, {"protocol": "shield-test", "unit_serial": "K1"},
                                  {"imu": spec})
    seq = np.arange(20)
    writer.append("imu", SampleBlock(np.ones((20, 3), np.int64), seq, np.full(20, np.nan),
                                     10.0 + seq / 100.0))
    writer.event("position_start", 0)
    protocol, raised = Pose(), []

    def run():
        try:
            still.run_states(protocol, writer, "pose")
        except BaseException as exc:  # noqa: BLE001 - what the protocol raised is checked below
            raised.append(exc)

    code = (still.__file__, interrupts.__file__, contextlib.__file__, threading.__file__,
            str(Path(station.session.__file__).parent), str(Path(h5py.__file__).parent))
    landed = interrupted_at(k, run, code, send=signal.SIGINT, armed=lambda: protocol.interrupted)
    interrupts.handled()  # as the command's end does (`restore`): a second Ctrl-C after the
    writer.close()  # handling raised in its stead, the shield up until then
    with Session.open(path) as session:
        kinds = [e.kind for e in session.events()]
        assert session.closed_cleanly, f"not closed cleanly after a second Ctrl-C at {landed}"
    assert kinds.count("abort") == 1, f"events {kinds} after a second Ctrl-C at {landed}"
    assert len(raised) == 1 and isinstance(raised[0], KeyboardInterrupt), (raised, landed)
    assert "interrupted (Ctrl-C)" in str(raised[0])
    return landed


def test_a_second_ctrl_c_anywhere_in_the_abort_leaves_it_recorded(tmp_path):
    previous = interrupts.install()
    try:
        k = 1
        while second_ctrl_c_at(k, tmp_path / f"session{k}.h5"):
            k += 1
    finally:
        interrupts.restore(previous)
    assert k > 300  # the sweep went through the abort's write in h5py
