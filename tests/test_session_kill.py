"""kill -9 of a process writing a session: every sample it reported flushed survives, the file
opens, and `SessionWriter.resume` continues it; ten kills at random moments on one file. And a
Ctrl-C at any place of the main thread's event write: the session stays whole."""

import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import numpy as np
from signal_places import interrupted_at

import station.session
from drivers.samples import SampleBlock
from station.session import Session, SessionWriter, StreamSpec

# The writer process: creates (or resumes) the session, appends 12-channel blocks whose counts are a
# known function of the sequence number, one table state per block and a position_done event every
# 10 blocks, and prints "flushed <imu rows> <table rows> <events>" whenever the durable row counts
# change. It never ends by itself: the test kills it.
WRITER = """
import sys, time
import numpy as np
from drivers.samples import SampleBlock
from station.session import SessionWriter, StreamSpec

def counts(seq):
    return (seq[:, None] * 7919 + np.arange(12) * 104729) % (2**32 - 1) - 2**31 + 1

path, mode = sys.argv[1], sys.argv[2]
if mode == "create":
    spec = StreamSpec([f"g{i}" for i in range(12)], "rad/s", 1e6, 2000.0)
    w = SessionWriter.create(path, {"protocol": "kill-test", "unit_serial": "K1"}, {"imu": spec},
                             flush_interval=0.1)
else:
    w = SessionWriter.resume(path, flush_interval=0.1)
seq0 = w.flushed["imu"]
position = -1 if w.last_completed_position is None else w.last_completed_position
reported = None
for i in range(10**9):
    seq = np.arange(seq0 + 20 * i, seq0 + 20 * (i + 1))
    w.append("imu", SampleBlock(counts(seq), seq, seq * 5e-4, seq * 5e-4 + 7.0))
    w.append_table(type("S", (), dict(time=float(seq[0]), rate=1.0, angle=0.5, rate_setpoint=1.0,
                                      running=True, ready=True, moving=True, at_rate=True,
                                      fault=False)))
    if i % 10 == 9:
        position += 1
        w.event("position_done", position, {"seq": int(seq[-1])})
    now = w.flushed
    if now != reported:
        reported = now
        print("flushed", now["imu"], now["table"], now["events"], flush=True)
    time.sleep(0.002)
"""


def expected_counts(seq):
    return (seq[:, None] * 7919 + np.arange(12) * 104729) % (2**32 - 1) - 2**31 + 1


def run_and_kill(path, mode, rng):
    """Start the writer, SIGKILL it at a random moment after its first flush; the last durable
    row counts it reported (imu, table, events)."""
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path), mode],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    watchdog = threading.Timer(60.0, proc.kill)  # a writer that never flushes fails, not hangs
    watchdog.start()
    first = proc.stdout.readline()
    watchdog.cancel()
    assert first.startswith("flushed"), proc.stderr.read()
    time.sleep(rng.uniform(0.0, 0.4))
    proc.send_signal(signal.SIGKILL)
    rest, _ = proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    return [int(x) for x in (first + rest).splitlines()[-1].split()[1:]]


def test_every_reported_sample_survives_ten_kills_and_resume_continues(tmp_path):
    rng = random.Random(20240901)
    path = tmp_path / "killed.h5"
    for trial in range(10):
        imu, table, events = run_and_kill(path, "resume" if trial else "create", rng)
        with Session.open(path) as s:  # the killed file opens
            d = s.stream("imu")
            assert len(d.seq) >= imu, f"trial {trial}: lost flushed samples"
            # every row present is the right one: no gap, no garbage, resumes append in sequence
            assert np.array_equal(d.seq, np.arange(len(d.seq)))
            assert np.array_equal(d.counts, expected_counts(d.seq))
            assert np.array_equal(d.host_time, d.seq * 5e-4 + 7.0)
            assert len(s.table().time) >= table
            ev = s.events()
            assert len(ev) >= events
            done = [e for e in ev if e.kind == "position_done"]
            assert [e.position for e in done] == list(range(len(done)))
            assert all(e.detail["seq"] < len(d.seq) for e in done)
            assert s.last_completed_position() == (len(done) - 1 if done else None)
            assert [e.kind for e in ev].count("session_resumed") == trial
    with SessionWriter.resume(path) as w:  # a final resume and a clean close
        assert w.last_completed_position == len(done) - 1
    with Session.open(path) as s:
        assert s.closed_cleanly and len(s.stream("imu").seq) >= imu


def _interrupted_event(path, k: int) -> str | None:
    """A session with 50 samples and position 1 started, a Ctrl-C at the k-th place of its
    `static_start` event (`signal_places.interrupted_at`; the writer's, h5py's and the locks'
    code), then the abort recorded and the file closed, as the protocol does; checked: the file
    opens, closed cleanly, every sample and every event in it, `static_start` at most once.
    Where the Ctrl-C landed (None: the event was written first)."""
    spec = StreamSpec(("a1", "a2", "a3"), "m/s^2", 1000.0, 100.0)
    seq = np.arange(50)
    writer = SessionWriter.create(path, {"protocol": "kill-test", "unit_serial": "K1"},
                                  {"imu": spec})
    writer.append("imu", SampleBlock(np.ones((50, 3), np.int64), seq, np.full(50, np.nan),
                                     10.0 + seq / 100.0))
    writer.event("position_start", 0)
    code = (str(Path(station.session.__file__).parent), str(Path(h5py.__file__).parent),
            threading.__file__)
    landed = interrupted_at(k, lambda: writer.event("static_start", 0), code)
    writer.event("abort", 0, {"error": f"KeyboardInterrupt at {landed}"})
    writer.close()
    with Session.open(path) as session:
        kinds = [e.kind for e in session.events()]
        assert session.closed_cleanly, f"not closed cleanly after a Ctrl-C at {landed}"
        assert len(session.stream("imu").seq) == 50, f"samples lost after a Ctrl-C at {landed}"
    assert kinds in (["session_start", "position_start", "abort"],
                     ["session_start", "position_start", "static_start", "abort"]), (
        f"events {kinds} after a Ctrl-C at {landed}")
    return landed


def test_a_ctrl_c_at_any_place_of_an_event_leaves_the_session_whole(tmp_path):
    """The protocol records its events from the main thread, where a Ctrl-C or `kill` lands
    between any two bytecodes: at every one of about 1,300 places of an event's write (the
    writer, h5py, the locks) the abort after it is recorded and nothing recorded is lost."""
    k, path = 1, tmp_path / "session.h5"
    while _interrupted_event(path, k):
        path.unlink()
        k += 1
    assert k > 500  # the sweep went through h5py's writes
