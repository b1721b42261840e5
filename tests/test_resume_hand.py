"""`station resume` for the still-pose protocols (iron, free-static): a session interrupted after
pose k - Ctrl-C at the technician's prompt, or the IMU unplugged (the twin's pty closed) - keeps
its k poses, the resume asks for the others on the same bench (profile, real serial driver,
virtual hand bench), and the calibration equals that of an uninterrupted session of the same unit
within the noise of the two."""

import json

import numpy as np
import pytest
from scipy import stats
from test_record_hand import CASES, FAMILY_FALSE_ALARM, _profile

from station import cli
from station.acquire.bench import BenchProfile, record, resume
from station.calfiles.calfile import load
from station.errors import RecordingError
from station.session import Session
from station.twin.hand_bench import HandBench

SEED = 8
POSES = 12  # both cases: static poses = 12; iron 2 mountings x 6 faces
INTERRUPTIONS = [  # (kind, how, the instruction at which it happens, poses kept)
    ("static", "ctrl-c", "pose 6/", 5),
    ("static", "unplug", "pose 9/", 8),
    ("iron", "ctrl-c", "pose 4/", 3),  # within a mounting: the resume goes on with its faces
    ("iron", "unplug", "mounting 2/2", 6),  # between mountings: the resume asks to re-mount
]


class Interrupting:
    """The bench's technician, interrupted when asked to do `cue`: Ctrl-C at the prompt, or the
    IMU's cable pulled (the technician then does nothing; the station finds the IMU gone)."""

    def __init__(self, bench: HandBench, how: str, cue: str):
        self.bench, self.how, self.cue = bench, how, cue
        self.fired = False

    def prompt(self, text):
        self.bench.technician.prompt(text)

    def confirm(self, question):
        return self.bench.technician.confirm(question)

    def wait(self, instruction):
        if not self.fired and instruction.text.startswith(self.cue):
            self.fired = True
            if self.how == "ctrl-c":
                raise KeyboardInterrupt
            self.bench.twin.unplug()
            return
        self.bench.technician.wait(instruction)


def _bench(kind: str) -> HandBench:
    case = CASES[kind]
    return HandBench(seed=SEED, layout=case["layout"], mountings=case["mountings"],
                     period=20.0, placement_deg=case["placement_deg"])


def _solve(path):
    assert cli.main(["solve", str(path), "--json"]) == 0
    return load(path.with_suffix(".cal.json"))


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Uninterrupted sessions of the same units: {kind: calibration}."""
    out = {}
    for kind in CASES:
        tmp = tmp_path_factory.mktemp(f"ref-{kind}")
        with _bench(kind) as bench:
            record(_profile(tmp, bench, kind, CASES[kind]["extra"]), tmp / "s.h5",
                   bench.technician, clock=bench.clock)
        out[kind] = _solve(tmp / "s.h5")
    return out


@pytest.mark.parametrize("kind, how, cue, kept", INTERRUPTIONS,
                         ids=[f"{k}-{h}-after-{n}" for k, h, _, n in INTERRUPTIONS])
def test_an_interrupted_hand_session_resumes_to_the_uninterrupted_calibration(
        kind, how, cue, kept, reference, tmp_path):
    path = tmp_path / "s.h5"
    with _bench(kind) as bench:
        profile = _profile(tmp_path, bench, kind, CASES[kind]["extra"])
        operator = Interrupting(bench, how, cue)
        with pytest.raises(KeyboardInterrupt if how == "ctrl-c" else RecordingError):
            record(profile, path, operator, clock=bench.clock)
        assert operator.fired
        with Session.open(path) as s:
            assert s.closed_cleanly and s.last_completed_position() == kept - 1
        if how == "unplug":
            bench.twin.plug()
        assert resume(profile, path, bench.technician, clock=bench.clock) == kept
        assert profile.positions == POSES
    with Session.open(path) as s:
        events = s.events()
    resumed = next(e.time for e in events if e.kind == "session_resumed")
    done = [e for e in events if e.kind == "position_done"]
    assert [e.position for e in done] == list(range(POSES))  # each pose once, in order
    assert [e.time < resumed for e in done] == [True] * kept + [False] * (POSES - kept)
    cal, ref = _solve(path), reference[kind]
    m = len(cal.bias)
    i, k = np.triu_indices(m, 1)
    z = np.concatenate([
        (cal.bias - ref.bias) / np.hypot(cal.bias_sigma, ref.bias_sigma),
        (cal.scale_factors - ref.scale_factors)
        / np.hypot(cal.scale_factors_sigma, ref.scale_factors_sigma),
        (cal.axis_angles[i, k] - ref.axis_angles[i, k])
        / np.hypot(cal.axis_angles_sigma[i, k], ref.axis_angles_sigma[i, k])])
    n = z.size * len(INTERRUPTIONS)
    assert np.all(np.abs(z) < stats.norm.isf(FAMILY_FALSE_ALARM / 2 / n)), np.round(z, 1)


def test_station_resume_of_a_completed_hand_session_records_nothing(tmp_path, capsys):
    with _bench("static") as bench:
        _profile(tmp_path, bench, "static", CASES["static"]["extra"])
        record(BenchProfile.load(tmp_path / "bench.toml"), tmp_path / "s.h5", bench.technician,
               clock=bench.clock)
        capsys.readouterr()
        assert cli.main(["resume", str(tmp_path / "s.h5"), "--profile",
                         str(tmp_path / "bench.toml"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["resumed_at"] == summary["positions"] == summary["completed"] == POSES
    with Session.open(tmp_path / "s.h5") as s:
        assert [e.kind for e in s.events()].count("position_done") == POSES
