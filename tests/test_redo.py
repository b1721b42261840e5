"""Redo, do not warn (issue 30, station.protocols.redo): a position whose window the live check
flags is recorded again at once, up to the profile's redo_limit, then the session stops with a
clear error; the superseded attempt stays in the file and the reduction takes the redo. The flags
come from the virtual bench's fault knob (`spikes`, station.sim.spikes), in lockstep time."""

import json
import os
import signal
import subprocess
import sys
import textwrap
from dataclasses import replace

import numpy as np
import pytest

from station.acquire.bench import BenchProfile
from station.calfiles.calfile import load
from station.cli import main
from station.errors import InputError, RedoLimitError
from station.model.two_axis import position_angles
from station.protocols.iron import IronProtocol, IronSettings
from station.protocols.redo import Redo
from station.protocols.rotary import RotarySettings, suggested_axes
from station.protocols.still import record_poses
from station.protocols.thermal import ROOM
from station.reduce.rotary import check_samples, position_windows, rotary_readings
from station.reduce.still import pose_windows
from station.reduce.timeline import sample_times
from station.replay import ReplaySettings, solve_recorded
from station.report.session import build
from station.session import Session
from station.sim.spikes import DENSITY, SIZE, SpikySource
from station.twin.hand_bench import ACC4, HandBench
from station.twin.rotary_bench import VirtualBench, record_rotary, resume_rotary
from station.twin.thermal import TRUTH, ThermalTwin

FAST = RotarySettings(rate=1.0, revolutions=1, static=3.0, rest=0.5, guard=0.5, steady=0.5)
POSITIONS = 6
SPOILED = [2, 4]
"""Positions (1-based) whose first attempt the bench spikes."""


def _attempts(events) -> dict:
    """{position (0-based): [position_start details in order]}."""
    starts = {}
    for e in events:
        if e.kind == "position_start":
            starts.setdefault(e.position, []).append(e.detail)
    return starts


def _counts(session, t0: float, t1: float):
    """The gyro counts of the samples whose instants lie in [t0, t1]."""
    data = session.stream("imu")
    t = sample_times(data.seq, data.host_time, data.spec.rate_hz)
    return data.counts[(t >= t0) & (t <= t1)]


def _superseded_windows(events, position: int) -> list:
    """The (static_start, static_end) times of `position`'s attempts before its last one."""
    windows, start = [], None
    for e in events:
        if e.position != position:
            continue
        if e.kind == "static_start":
            start = e.time
        elif e.kind == "static_end":
            windows.append((start, e.time))
    return windows[:-1]


def test_spiked_positions_are_recorded_again_and_the_session_solves(tmp_path):
    path = tmp_path / "redo.h5"
    with VirtualBench(seed=3, remount_time=1.0, spikes=SPOILED) as bench:
        record_rotary(bench, path, FAST, suggested_axes(POSITIONS))
        said = bench.technician.messages
        truth = bench.truth()
    with Session.open(path) as s:
        events = s.events()
        attempts = _attempts(events)
        # every spoiled position twice: the flagged attempt, then the redo naming its flags
        assert {j: len(a) for j, a in attempts.items()} == {
            j: 2 if j + 1 in SPOILED else 1 for j in range(POSITIONS)}
        for j in SPOILED:
            redo = attempts[j - 1][-1]
            assert redo["redo"] == 1 and redo["again"] is True
            assert any("beyond 8 standard deviations" in f for f in redo["flags"]), redo
            assert any(m.startswith(f"position {j}: ") and "recording it again (redo 1 of at "
                       "most 2)" in m for m in said)
        assert [e.position for e in events if e.kind == "position_done"] == list(range(POSITIONS))
        # the superseded windows are in the file, spiky, and not those the reduction takes
        windows = position_windows(events)
        for j in SPOILED:
            (old,) = _superseded_windows(events, j - 1)
            with pytest.raises(InputError, match="beyond 8 standard deviations"):
                check_samples(j - 1, "static", _counts(s, *old))
            assert windows[j - 1]["static"][0] > old[1]
        readings = rotary_readings(s)
        _, result = solve_recorded(s, ReplaySettings())
    assert readings.M.shape == (12, POSITIONS)
    # the readings are the true stimuli through the true unit (c = 1 rad/s): every residual
    # within 6 of its 1-sigma, the spiked positions included
    expected = truth.a.T @ truth.v(FAST.rate)
    assert np.all(np.abs(readings.M - expected) < 6 * readings.sigma), \
        np.abs(readings.M - expected) / readings.sigma
    assert result.refined
    report = build(path)  # the session report lists the redos with their flags
    assert report.summary["redos"] == len(SPOILED)
    page = report.html()
    assert page.count("<td>redo</td>") == len(SPOILED) and "beyond 8 standard deviations" in page


def test_a_two_axis_session_redoes_a_spiky_cone_position_and_solves(tmp_path):
    """Two-axis table (the station sets each orientation through the position axis, lockstep):
    the same rule; position 3 on the cone is spiked, recorded again, and the session solves."""
    path = tmp_path / "two_axis.h5"
    with VirtualBench(seed=4, two_axis=True, spikes=[3]) as bench:
        record_rotary(bench, path, FAST, phis=position_angles(6), spins=1)
    with Session.open(path) as s:
        attempts = _attempts(s.events())
        assert {j: len(a) for j, a in attempts.items()} == {j: 2 if j == 2 else 1
                                                            for j in range(7)}
        assert attempts[2][-1]["redo"] == 1 and "phi" not in attempts[2][-1]  # not re-set
        _, result = solve_recorded(s, ReplaySettings())
    assert result.refined


def test_past_the_redo_limit_the_session_stops_naming_the_position_and_resumes(tmp_path):
    """redo_limit 0: the first flagged window stops the session with the position, the flag and
    what to do; the file keeps what was recorded (the completed position, the flagged attempt's
    samples, the abort) and is resumed to a session that solves."""
    path = tmp_path / "limit.h5"
    settings = replace(FAST, redo_limit=0)
    with VirtualBench(seed=4, remount_time=1.0, spikes=[2]) as bench, \
            pytest.raises(RedoLimitError) as info:
        record_rotary(bench, path, settings, suggested_axes(4))
    message = str(info.value)
    assert message.startswith("position 2 was flagged on each of its 1 attempts (last: the "
                              "static window holds"), message
    assert "redo_limit is 0" in message and "raise [protocol] redo_limit" in message
    assert "station resume" in message and "mounting" in message
    with Session.open(path) as s:
        events = s.events()
        assert s.last_completed_position() == 0
        (abort,) = [e for e in events if e.kind == "abort"]
        assert abort.position == 1 and "RedoLimitError" in abort.detail["error"]
        static = [e.time for e in events if e.position == 1 and e.kind in ("static_start",
                                                                          "static_end")]
        assert len(_counts(s, *static)) >= FAST.static * 200  # the flagged window is kept
    assert resume_rotary(path, spikes=None) == 1
    with Session.open(path) as s:
        assert [e.position for e in s.events() if e.kind == "position_done"] == [0, 1, 2, 3]
        assert rotary_readings(s).M.shape == (12, 4)


KILLER = textwrap.dedent("""
    import os, signal, sys
    from station.protocols.rotary import RotarySettings, suggested_axes
    from station.twin.rotary_bench import VirtualBench, record_rotary

    path, at = sys.argv[1], sys.argv[2]
    settings = RotarySettings(rate=1.0, revolutions=1, static=3.0, rest=0.5, guard=0.5,
                              steady=0.5)

    def watch(writer):
        event, redo = writer.event, []

        def kill_in_redo(kind, position=None, detail=None, **kw):
            out = event(kind, position, detail, **kw)
            redo.extend([1] if kind == "position_start" and (detail or {}).get("redo") else [])
            if redo and kind == at:
                os.kill(os.getpid(), signal.SIGKILL)
            return out
        writer.event = kill_in_redo

    with VirtualBench(seed=5, remount_time=1.0, spikes=[2]) as bench:
        record_rotary(bench, path, settings, suggested_axes(6), watch=watch)
""")


@pytest.mark.parametrize("at", ["position_start", "static_end", "rotate_end"])
def test_a_kill_during_a_redo_resumes_to_a_solvable_session(at, tmp_path):
    """SIGKILL of the recording process right after an event of a redo (its position_start, its
    static window, its rotating window): `resume` records the position again from its start and
    the session solves, the superseded attempts still in the file."""
    path = tmp_path / "killed.h5"
    run = subprocess.run([sys.executable, "-c", KILLER, str(path), at], capture_output=True,
                         text=True, timeout=600, env={**os.environ, "PYTHONPATH": os.getcwd()})
    assert run.returncode == -signal.SIGKILL, run.stderr[-2000:]
    with Session.open(path) as s:
        assert s.last_completed_position() == 0
        assert sum(1 for e in s.events() if e.kind == "position_start" and e.position == 1) == 2
    assert resume_rotary(path, spikes=None) == 1
    with Session.open(path) as s:
        events = s.events()
        assert [e.position for e in events if e.kind == "position_done"] == list(range(6))
        assert len(_superseded_windows(events, 1)) == (2 if at != "position_start" else 1)
        assert rotary_readings(s).M.shape == (12, 6)
        _, result = solve_recorded(s, ReplaySettings())
    assert result.refined


def test_the_redo_rule_counts_each_position_against_its_limit():
    redo = Redo(2)
    assert redo.attempt(4, ["the static window was not still"]) == {
        "again": True, "redo": 1, "flags": ["the static window was not still"]}
    assert redo.attempt(4, ["x"])["redo"] == 2
    assert redo.attempt(5, ["y"])["redo"] == 1  # each position its own count
    with pytest.raises(RedoLimitError, match=r"^position 5 was flagged on each of its 3 attempts "
                                             r"\(last: z\) and redo_limit is 2\."):
        redo.attempt(4, ["z"])


@pytest.mark.parametrize("value", [-1, 11, 1.5, "2"])
def test_a_bad_redo_limit_is_refused_naming_the_key(value, tmp_path):
    with pytest.raises(InputError, match="redo_limit must be a whole number from 0"):
        RotarySettings(redo_limit=value)
    with pytest.raises(InputError, match="redo_limit must be a whole number from 0"):
        RotarySettings(redo_limit=True)
    with pytest.raises(ValueError, match="redo_limit"):  # ProfileError
        BenchProfile.load(_bench_profile(tmp_path, repr(value).replace("'", '"')))


def test_the_redo_limit_comes_from_the_profile(tmp_path):
    assert BenchProfile.load(_bench_profile(tmp_path, "5")).settings.redo_limit == 5


def _bench_profile(tmp_path, redo_limit: str):
    """A rotary bench profile whose [protocol] redo_limit is the TOML text `redo_limit`."""
    profile = tmp_path / "bench.toml"
    profile.write_text(textwrap.dedent(f"""
        [bench]
        unit_serial = "SN1"
        [imu]
        link = "serial"
        profile = "imu12_serial"
        port = "/dev/null"
        [table]
        host = "127.0.0.1"
        port = 5020
        [protocol]
        positions = 6
        redo_limit = {redo_limit}
        """))
    return profile


THERMAL_SPOILED = [2, 9, 16]
"""The campaign's positions (soak s, position j: 6 (s - 1) + j) whose first attempt is spiky:
position 2 at the first setpoint, 3 at the second, 4 at the third."""


def test_a_thermal_campaign_with_spiky_windows_redoes_them_and_ends_solvable(tmp_path, capsys):
    """The thermal twin (lockstep, 6 positions at 3 setpoints) spikes the first attempt at three
    positions: each is recorded again, the campaign solves, and the 24 linear tempcos lie within
    4 of their reported 1-sigma of the truth."""
    profile = tmp_path / "bench.toml"
    with ThermalTwin(seed=2, positions=6, setpoints=(263.15, 298.15, 333.15),
                     spikes=THERMAL_SPOILED) as twin:
        profile.write_text(twin.profile_text())
        assert main(["record", "--profile", str(profile), "--out", str(tmp_path / "camp"),
                     "--solve", "--json"]) == 0
        assert twin.error is None
    summary = json.loads(capsys.readouterr().out)
    redone, flags = [], []
    for k, soak in enumerate(summary["soaks"]):
        with Session.open(tmp_path / "camp" / soak["file"]) as s:
            events = s.events()
        assert [e.position for e in events if e.kind == "position_done"] == list(range(6))
        for e in events:
            if e.kind == "position_start" and e.detail.get("redo"):
                redone.append(6 * k + e.position + 1)
                flags += e.detail["flags"]
    # every spoiled position recorded again (and nothing else flagged by the live check)
    assert sorted(redone) == THERMAL_SPOILED, redone
    assert all("standard deviations" in f or "not still" in f for f in flags), flags
    model = load(tmp_path / "camp" / "campaign.cal.json").temperature
    z_bias = (model.bias[:, 0] - TRUTH.bias) / model.bias_sigma[:, 0]
    z_scale = (model.scale[:, 0] - np.asarray(TRUTH.scale)) / model.scale_sigma[:, 0]
    print(f"\nthermal campaign: {len(redone)} position(s) flagged and redone {sorted(redone)}; "
          f"tempco errors in sigma: bias max |z| {np.abs(z_bias).max():.2f} (rms "
          f"{np.sqrt(np.mean(z_bias**2)):.2f}), scale max |z| {np.abs(z_scale).max():.2f} (rms "
          f"{np.sqrt(np.mean(z_scale**2)):.2f}); orders {model.orders}")
    assert np.all(np.abs(z_bias) < 4) and np.all(np.abs(z_scale) < 4), (z_bias, z_scale)


class SpikedPoses:
    """The hand rig's counts (`station.twin.hand_bench.HandRig`, the bench's `source`) with a
    spike of `size` counts on channel 1 every `every` s for `span` s after the end of the turns
    `turns` (1-based, re-mountings included): single readings far beyond the noise that the
    stillness detector lets pass (one in each of its 1 s windows) and the live check flags."""

    def __init__(self, rig, turns, rate_hz: float, size: int, every: float = 2.0,
                 span: float = 4.0):
        self.rig, self.turns, self.rate_hz, self.size = rig, turns, rate_hz, size
        self.every, self.span = every, span

    def __call__(self, times):
        times = np.atleast_1d(np.asarray(times, float))
        counts = np.array(self.rig(times))
        for k in self.turns:
            if k < len(self.rig._turns):
                after = times - (self.rig._turns[k][0] + self.rig.turn_time)
                tick = np.round(after * self.rate_hz).astype(int) % round(self.every * self.rate_hz)
                counts[(after >= 0) & (after < self.span) & (tick == 0), 0] += self.size
        return counts


def test_a_spiky_hand_pose_is_held_again_and_the_session_solves(tmp_path):
    """Iron protocol, one mounting (6 faces), lockstep hand bench: the first window of faces 2 and
    4 holds spikes; the technician is asked to hold the unit still, the next window is taken, the
    superseded one stays in the file and the reduction takes the redo."""
    path = tmp_path / "iron.h5"
    bench = HandBench(seed=2, speed=None, period=20.0)
    size = round(20 * bench.unit.sigma[0] * bench.profile.imu.scale[0])  # 20 sigma
    bench.source = SpikedPoses(bench.rig, [3, 5], bench.stream_spec.rate_hz, size)  # faces 2, 4
    with bench, bench.driver() as imu:
        protocol = IronProtocol(bench.technician, bench.clock, ACC4,
                                IronSettings(gravity=bench.gravity, mountings=1))
        record_poses(protocol, imu, bench.stream_spec, bench.clock, path,
                     {**protocol.metadata(), "unit_serial": "T"})
        said = bench.technician.messages
    assert sum("hold the unit still" in m for m in said) == 2
    with Session.open(path) as s:
        events = s.events()
        attempts = _attempts(events)
        assert {j: len(a) for j, a in attempts.items()} == {0: 1, 1: 2, 2: 1, 3: 2, 4: 1, 5: 1}
        for j in (1, 3):
            redo = attempts[j][-1]
            assert redo["redo"] == 1 and redo["face_asked"] == attempts[j][0]["face_asked"]
            assert len(redo["flags"]) == 1, redo
            assert redo["flags"][0].startswith("the still window holds ")
            assert redo["flags"][0].endswith(" beyond 8 standard deviations of its own noise "
                                             "(channels 1)"), redo
        ends = [e for e in events if e.kind == "static_end"]
        windows, _ = pose_windows(events)
        for j in (1, 3):
            old, new = [e.detail["window"] for e in ends if e.position == j]
            with pytest.raises(InputError, match="beyond 8 standard deviations"):
                check_samples(j, "still", _counts(s, *old))
            assert windows[j].tolist() == new
        _, result = solve_recorded(s, ReplaySettings())
    assert result.refined


@pytest.mark.parametrize("args", [["--spikes", "2,x"], ["--spikes", "1.5"], ["--spikes", "0"],
                                  ["--protocol", "iron", "--spikes", "2"],
                                  ["--units", "2", "--spikes", "2"]])
def test_a_bad_spikes_knob_is_refused_naming_the_option(args, tmp_path, capsys):
    assert main(["twin", *args, "--profile-out", str(tmp_path / "t.toml")]) == 2
    assert "--spikes" in capsys.readouterr().err
    assert not (tmp_path / "t.toml").exists()


class TurnTwice:
    """A `MountedUnit` stand-in for `SpikySource`: 12 channels of zero counts, one placement,
    its table turning at 1 rad/s over [3, 5) s and again over [8, 10) s (the first
    attempt, then a redo)."""

    class Table:
        @staticmethod
        def true_rates(times):
            t = np.asarray(times)
            return np.where(((t >= 3) & (t < 5)) | ((t >= 8) & (t < 10)), 1.0, 0.0)

    class Unit:
        m = 12

    table, unit, inner = Table(), Unit(), None

    @staticmethod
    def placement(times):
        return np.zeros(len(times), int)

    def __call__(self, times):
        return np.zeros((len(times), 12), np.int64)


@pytest.mark.parametrize("cut", [1, 333, 777])
def test_spikes_fall_in_the_first_attempt_whatever_the_blocks(cut):
    """Position 1 (the one placement, the table turned at it) spiked from its placement to the end
    of its first turn, the redo clean, the samples the same however the twin's host
    cuts the stream into blocks."""
    times = np.arange(1200) / 100.0
    whole = SpikySource(TurnTwice(), TurnTwice(), [1], 1e6, seed=3)(times)
    source = SpikySource(TurnTwice(), TurnTwice(), [1], 1e6, seed=3)
    parts = np.vstack([source(times[:cut]), source(times[cut:])])
    assert np.array_equal(whole, parts)
    hit = np.flatnonzero(whole.any(axis=1))
    assert hit.size > 0.5 * DENSITY * 500 and times[hit].max() < 5.0
    assert set(np.unique(np.abs(whole[whole != 0]))) == {round(SIZE * 1e6)}
    assert not SpikySource(TurnTwice(), TurnTwice(), [2], 1e6)(times).any()  # no position 2


def test_a_campaign_past_its_redo_limit_stops_safe_and_resumes(tmp_path, capsys):
    """redo_limit 0 in the bench profile: the campaign's first spiky window stops it (exit 3)
    naming the position and the flag, the table stopped and the chamber at its safe setpoint;
    `station resume DIR` records that position again (the twin spikes first attempts only) and
    the campaign solves."""
    profile, camp = tmp_path / "bench.toml", tmp_path / "camp"
    with ThermalTwin(seed=3, positions=6, setpoints=(283.15, 313.15), spikes=[2]) as twin:
        profile.write_text(twin.profile_text().replace("[protocol]\n",
                                                       "[protocol]\nredo_limit = 0\n"))
        assert main(["record", "--profile", str(profile), "--out", str(camp)]) == 3
        err = capsys.readouterr().err
        assert "position 2 was flagged on each of its 1 attempts" in err
        assert "beyond 8 standard deviations" in err and "redo_limit is 0" in err
        assert not twin.bench.table.state().running and twin.physics.setpoint == ROOM
        assert main(["resume", str(camp)]) == 0
    assert main(["solve", str(camp)]) == 0
    with Session.open(camp / "soak_1_283K.h5") as s:
        starts = [e.position for e in s.events() if e.kind == "position_start"]
    assert starts.count(1) == 2  # the flagged attempt and the resumed one, both kept
