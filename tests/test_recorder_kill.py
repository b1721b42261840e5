"""kill -9 of a process recording a rotary session on the virtual bench, ten times at random moments
on one session file: every sample, table state and event the process reported flushed is readable
afterwards, each resumed run continues from the last completed position, and the session finally
completed by `station resume` calibrates as well as an uninterrupted one."""

import json
import os
import random
import signal
import subprocess
import sys

import numpy as np
from scipy import stats

import station
from station.protocols.rotary import suggested_axes
from station.reduce.rotary import rotary_readings
from station.session import Session
from station.solve.uncertainty import eps_tail_probability
from station.twin.rotary_bench import VirtualBench

POSITIONS, SEED, RATE_HZ = 10, 5, 100.0
POSITION_ROWS = int(15.0 * RATE_HZ)  # a position: 16.75 s of clock (remount, windows, a turn)
# The bench runs in lockstep time (its default): the session is the same on any host, so the kills
# are placed by the session's progress (IMU rows flushed), not by wall seconds.
# The recording process: creates the session (or resumes it with the same code as `station
# resume`) and prints "flushed <imu rows> <table rows> <events>" whenever the durable row counts
# change, then "done" if it was not killed first. It sends itself SIGKILL once it has flushed
# ROWS more IMU rows than at its first report: a kill from the test after reading that report
# lands later the busier the host (beside 6 CPU hogs the session once ended first).
WORKER = f"""
import os, signal, sys, threading, time
from station.protocols.rotary import RotarySettings, suggested_axes
from station.twin.rotary_bench import VirtualBench, record_rotary, resume_rotary

def watch(writer):
    def report():
        last = first = None
        while True:
            try:
                now = writer.flushed
            except ValueError:  # closed
                return
            if now != last:
                last = now
                print("flushed", now["imu"], now["table"], now["events"], flush=True)
                first = now["imu"] if first is None else first
                if now["imu"] - first >= ROWS:
                    os.kill(os.getpid(), signal.SIGKILL)
            time.sleep(0.01)
    threading.Thread(target=report, daemon=True).start()

path, mode, ROWS = sys.argv[1], sys.argv[2], int(sys.argv[3])
if mode == "create":
    settings = RotarySettings(rate=1.0, revolutions=1, static=3.0, rest=0.5, guard=0.5, steady=0.5)
    with VirtualBench(seed={SEED}, rate_hz={RATE_HZ}, remount_time=1.0) as bench:
        record_rotary(bench, path, settings, suggested_axes({POSITIONS}), watch=watch)
else:
    resume_rotary(path, watch=watch)
print("done", flush=True)
"""


def run_and_kill(path, mode, rows):
    """Run the worker, which kills itself (SIGKILL) once it has flushed `rows` more IMU rows than
    at its first report (unless it finished first). Returns (last reported flushed counts,
    finished). The worker's temporary files (its twin's pty directory, which a killed process
    cannot remove) go beside the session file."""
    proc = subprocess.run([sys.executable, "-c", WORKER, str(path), mode, str(rows)],
                          capture_output=True, text=True,
                          env={**os.environ, "TMPDIR": str(path.parent)})
    assert proc.returncode in (0, -signal.SIGKILL), f"worker failed: {proc.stderr}"
    lines = [line.split() for line in proc.stdout.splitlines(keepends=True)
             if line.endswith("\n")]  # a line cut by the kill is left out
    flushed = [tuple(map(int, w[1:])) for w in lines if w and w[0] == "flushed" and len(w) == 4]
    return flushed[-1], ["done"] in lines


def test_ten_kills_at_random_moments_then_station_resume_completes_the_session(tmp_path):
    path = tmp_path / "killed.h5"
    rng = random.Random(11)
    remaining = POSITIONS
    for trial in range(10):  # each kill at a random moment before the session could end
        rows = int(rng.uniform(0.0, 0.9 * remaining * POSITION_ROWS))
        (imu, table, events), finished = run_and_kill(path, "create" if trial == 0 else "resume",
                                                      rows)
        assert not finished
        with Session.open(path) as f:  # every reported flushed row is readable
            stream = f.stream("imu")
            assert len(stream.seq) >= imu and len(f.table().time) >= table
            assert len(f.events()) >= events
            assert np.all(np.isfinite(stream.host_time)) and np.all(np.diff(stream.host_time) >= 0)
            last = f.last_completed_position()
        remaining = POSITIONS - (0 if last is None else last + 1)
        assert remaining > 0

    done = subprocess.run([sys.executable, "-m", "station", "resume", str(path), "--json"],
                          check=False, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["completed"] == POSITIONS

    with Session.open(path) as f:
        assert f.closed_cleanly
        events = f.events()
        reduced = rotary_readings(f)
    # each resumed run starts with the position after the last one completed before the kill
    done_so_far = -1
    for i, e in enumerate(events):
        if e.kind == "position_done":
            done_so_far = e.position
        if e.kind == "session_resumed":
            assert e.position == (None if done_so_far < 0 else done_so_far)
            following = [x for x in events[i:] if x.kind == "position_start"]
            assert not following or following[0].position == done_so_far + 1
    assert [e.position for e in events if e.kind == "position_done"] == list(range(POSITIONS))

    # Result quality as for an uninterrupted session: eps consistent with the Cramer-Rao bound at a
    # 1e-4 false-alarm level (tests/test_demo.py). The bound uses the suggested axes (the real
    # mountings, 0.5 deg off, died with the killed processes).
    bench = VirtualBench(seed=SEED, rate_hz=RATE_HZ)
    a = bench.unit.a
    result = station.calibrate(reduced.M, 1.0, sigma=reduced.sigma)
    bound = station.crlb(a, suggested_axes(POSITIONS).T, reduced.sigma)
    assert eps_tail_probability(station.eps(a, result.a), bound) > 1e-4
    # no window took samples of a mounting change or a ramp: chi2 of the fit within its law
    assert result.chi2 < stats.chi2.isf(1e-4, result.dof), (result.chi2, result.dof)
    assert np.all(reduced.revolutions == 1)
