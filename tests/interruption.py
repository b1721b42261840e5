"""The interruption harness (tests/test_interruptions.py, bench/interruptions.py): `station twin` in
one process, `station record` in another (sharing the twin's lockstep clock), a signal sent to
the recorder the moment the session file holds a chosen protocol event, then `station resume`
with the same bench profile, as a technician would after a Ctrl-C, a `kill` or a crash.

A device can be lost instead (`DEVICES`): the twin is told to unplug the IMU (its pty is closed)
or to silence the table (its Modbus server stops answering) at the event. The technician at
`station record` presses Enter at each reconnection prompt without the cable (the station gives up
after its retries) or answers 'n' when asked whether to go on without the table; once `record` has
ended the device comes back and `station resume` continues.

Per interruption point it returns, for every position's static and rotating window, the samples
found over the samples due, and the Eq. (18) readings with their 1-sigma, to compare with an
uninterrupted session of the same twin.
"""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from station.reduce.rotary import position_windows, rotary_readings
from station.reduce.timeline import sample_times, segment_breaks
from station.session import Session

STATION = [sys.executable, "-m", "station"]
POSITIONS = 3
SEED = 3
TABLE_REPLY = 5.0
"""Wall seconds `station record` waits for each reply of the table (`station twin --table-reply`):
a silent table is found after 3 tries of it (the default, 30 s in lockstep, would take minutes);
a hang guard for the replies of a table that answers, whose replies take no clock time."""
WAIT = 1800.0
"""Wall seconds a step may take before the harness calls it hung: a hang guard only (the twin runs
in lockstep time, so a busy host makes the session slower, never different)."""
STATES = ("position_start", "static_start", "static_end", "rotate_start", "rotate_end",
          "position_done")
"""Protocol events after which the recorder is interrupted: mounting, static window, spin-up,
rotating window, spin-down, completed position."""
DEVICES = {"imu": "SIGUSR1", "table": "SIGUSR2"}
"""Devices the twin loses (and brings back) on these signals (`station twin`)."""
LOSSES = {"imu": ("static_start", "rotate_end"), "table": ("static_start", "rotate_start")}
"""Events after which each device is lost: the IMU with the table at rest and right after the
rotating window (the position is then complete), the table at rest and while it turns."""
RETRIES = 3
"""`RotarySettings.retries` of the twin's profile: reconnections tried before `record` gives up."""


def _twin(workdir: Path):
    """A running `station twin` process in lockstep time and its bench profile."""
    profile = workdir / "twin.toml"
    twin = subprocess.Popen(
        [*STATION, "twin", "--positions", str(POSITIONS), "--seed", str(SEED), "--profile-out",
         str(profile), "--table-reply", str(TABLE_REPLY), "--lifetime", str(WAIT), "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    json.loads(twin.stdout.readline())  # the twin is serving
    return twin, profile


def _stop(twin) -> None:
    twin.send_signal(signal.SIGINT)
    try:
        twin.communicate(timeout=600)
    except subprocess.TimeoutExpired:
        twin.kill()
        twin.communicate()


def _events(path: Path) -> list:
    """(kind, position) of the events flushed so far; [] while the file is not readable yet."""
    try:
        with Session.open(path) as s:
            return [(e.kind, e.position) for e in s.events()]
    except Exception:  # noqa: BLE001 - the writer may not have created the file yet
        return []


def _answers(interrupt) -> str:
    """What the technician types into `station record` (the twin's fixture mounts the unit: no
    key press at the mountings): after a lost device, Enter at each reconnection prompt (the
    cable still out) or 'n' to going on without the table."""
    if interrupt is None or interrupt[0] not in DEVICES:
        return ""
    return "\n" * (RETRIES + 2) if interrupt[0] == "imu" else "n\nn\n"


def _table_running(profile: Path) -> bool:
    """Is the twin's table turning? (read over Modbus; the driver stops it when closed)"""
    from drivers.clock import WallClock
    from drivers.rotary_table import RotaryTable
    from station.acquire.bench import BenchProfile

    bench = BenchProfile.load(profile)
    with RotaryTable(bench.table_host, bench.table_port, bench.table_map,
                     clock=WallClock()) as table:
        return table.state().running


def record(workdir: Path, interrupt=None) -> dict:
    """One session on a fresh twin; interrupt = (signal name or device, event kind, position) or
    None. Returns the exits of record and resume, per-window sample ratios, readings and sigma;
    after a lost device also whether the table still turned when `record` had ended."""
    workdir.mkdir(parents=True, exist_ok=True)
    session = workdir / "session.h5"
    twin, profile = _twin(workdir)
    try:
        enters = workdir / "enter.txt"  # the technician's answers
        enters.write_text(_answers(interrupt))
        with enters.open() as stdin:
            rec = subprocess.Popen([*STATION, "record", "--profile", str(profile), "--out",
                                    str(session), "--json"], stdin=stdin,
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        out = {"interrupt": list(interrupt) if interrupt else None}
        if interrupt is not None:
            name, kind, position = interrupt
            deadline = time.monotonic() + WAIT
            while (kind, position) not in _events(session):
                if rec.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"record ended before {kind} of position {position + 1}: "
                                       f"{rec.stderr.read()[-500:]}")
                time.sleep(0.01)
            target = twin if name in DEVICES else rec
            target.send_signal(getattr(signal, DEVICES.get(name, name)))
        _, err = rec.communicate(timeout=WAIT)
        out["record_exit"], out["record_stderr"] = rec.returncode, err.strip()[-300:]
        out["record"] = _kinds(session)
        if interrupt is not None and interrupt[0] in DEVICES:
            twin.send_signal(getattr(signal, DEVICES[interrupt[0]]))  # the device is back
            out["table_running"] = _table_running(profile)
        if interrupt is not None:
            res = subprocess.run([*STATION, "resume", str(session), "--json"],
                                 input="\n" * POSITIONS, capture_output=True, text=True,
                                 timeout=WAIT)
            out["resume_exit"], out["resume_stderr"] = res.returncode, res.stderr.strip()[-300:]
    finally:
        _stop(twin)
    return {**out, **measure(session)}


def _kinds(path: Path) -> dict:
    """What `record` left: the file closed cleanly, and its fault, pause and abort events."""
    with Session.open(path) as s:
        kinds = [e.kind for e in s.events()]
        return {"clean": s.closed_cleanly,
                **{k: kinds.count(k) for k in ("fault", "pause", "abort")}}


def measure(path: Path) -> dict:
    """Samples found / due per window, and the Eq. (18) readings and their 1-sigma."""
    with Session.open(path) as s:
        events, data = s.events(), s.stream("imu")
        rate = data.spec.rate_hz
        t = sample_times(data.seq, data.host_time, rate, segment_breaks(events))
        ratios = [[float(np.sum((t >= a) & (t <= b)) / ((b - a) * rate))
                   for a, b in (w["static"], w["rotating"])]
                  for _, w in sorted(position_windows(events).items())]
        reduced = rotary_readings(s)
    return {"ratios": ratios, "M": reduced.M.tolist(), "sigma": reduced.sigma.tolist()}


def deviation(run: dict, reference: dict) -> np.ndarray:
    """(M - M_ref) / sqrt(sigma^2 + sigma_ref^2): independent noise of two sessions of one twin."""
    m, s = np.array(run["M"]), np.array(run["sigma"])
    m0, s0 = np.array(reference["M"]), np.array(reference["sigma"])
    return (m - m0) / np.sqrt(s**2 + s0**2)
