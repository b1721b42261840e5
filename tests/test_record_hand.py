"""`station record` and `station solve` for the still-pose protocols (iron, free-static) through
the bench profile, the real serial driver and the virtual hand bench; bench profile checks."""

import io
import json

import numpy as np
import pytest
from scipy import stats

from drivers.profile import ProfileError
from station import cli
from station.acquire.bench import BenchProfile, record
from station.calfiles.calfile import load
from station.session import Session
from station.twin.hand_bench import ACC4, TRIAD, HandBench

FAMILY_FALSE_ALARM = 1e-3


def _profile(tmp_path, bench: HandBench, protocol: str, extra: str = "") -> BenchProfile:
    """A bench profile for `bench` (a lockstep bench's clock is passed to `record` itself)."""
    m = bench.layout.shape[1]
    speed = f"clock_speed = {bench.clock.speed!r}\n" if bench.clock.realtime else ""
    text = (f'[bench]\nunit_serial = "SN-HAND"\n{speed}\n'
            f'[imu]\nlink = "serial"\nprofile = "acc{m}_serial"\nport = "{bench.twin.port}"\n\n'
            f'[protocol]\nkind = "{protocol}"\ngravity = {bench.gravity!r}\n{extra}')
    (tmp_path / "bench.toml").write_text(text)
    return BenchProfile.load(tmp_path / "bench.toml")


LAYOUT4 = "layout = " + json.dumps(ACC4.tolist()) + "\n"

CASES = {
    "static": {"layout": TRIAD, "mountings": [np.eye(3)], "placement_deg": 5.0,
               "extra": "poses = 12\n"},
    "iron": {"layout": ACC4, "mountings": 2, "placement_deg": 0.0002,
             "extra": "mountings = 2\n" + LAYOUT4},
}


@pytest.fixture(scope="module", params=sorted(CASES))
def solved(request, tmp_path_factory):
    """A session recorded by `station record`'s path with the bench's technician as operator,
    then `station solve --json`: (protocol, truth, session path, calibration, summary)."""
    kind, case = request.param, CASES[request.param]
    tmp = tmp_path_factory.mktemp(kind)
    with HandBench(seed=8, layout=case["layout"], mountings=case["mountings"],
                   period=20.0, placement_deg=case["placement_deg"]) as bench:
        profile = _profile(tmp, bench, kind, case["extra"])
        summary = record(profile, tmp / "s.h5", bench.technician, clock=bench.clock)
        truth = bench.truth()
    assert summary["protocol"] == kind and summary["positions_done"] == profile.positions
    code = cli.main(["solve", str(tmp / "s.h5"), "--json"])
    assert code == 0
    return kind, truth, tmp / "s.h5", load(tmp / "s.cal.json")


def test_the_calibration_file_matches_the_truth(solved):
    kind, truth, _, cal = solved
    m = truth.a.shape[1]
    i, k = np.triu_indices(m, 1)
    u = truth.a / np.linalg.norm(truth.a, axis=0)
    angles = np.arccos(np.clip(u.T @ u, -1, 1))
    z = np.concatenate([(cal.bias - truth.bias) / cal.bias_sigma,
                        (cal.scale_factors - np.linalg.norm(truth.a, axis=0))
                        / cal.scale_factors_sigma,
                        (cal.axis_angles[i, k] - angles[i, k]) / cal.axis_angles_sigma[i, k]])
    assert np.all(np.abs(z) < stats.norm.isf(FAMILY_FALSE_ALARM / 2 / z.size)), (kind, z)
    assert cal.frame == "nominal" and cal.units == ("m/s^2",) * m
    assert cal.sensors == tuple(f"a{j + 1}" for j in range(m))
    assert cal.fit["bias_source"].startswith("estimated with the calibration")


def test_the_session_records_the_protocol_and_the_bench(solved):
    kind, _, path, _ = solved
    with Session.open(path) as s:
        assert s.protocol == kind and s.unit_serial == "SN-HAND"
        assert s.metadata["bench"]["tables"]["protocol"]["kind"] == kind
        assert "imu" in s.metadata["profiles"] and "table" not in s.metadata["profiles"]
        assert s.events()[-1].kind == "position_done"


@pytest.mark.parametrize("extra, message", [
    ('kind = "spin"', "kind"),
    ('kind = "static"\nposes = 5', "poses must be a whole number from 12"),
    ('kind = "static"\n[table]\nhost = "x"\nport = 1', "uses no rotary table"),
    ('kind = "iron"\nfaces = ["+x", "up"]', "faces must be"),
    ('kind = "static"\nlayout = [[1, 0], [0, 1]]', "layout: must be 3 lists of 3 numbers"),
    ('kind = "static"\nlayout = [[1, 0, 0], [0, 1, 0], [1, 1, 0]]', "must span 3 dimensions"),
    ('kind = "static"\nspeed = 3', "unknown keys ['speed']"),
])
def test_bench_profile_errors_name_the_problem(tmp_path, extra, message):
    text = ('[bench]\nunit_serial = "S"\n[imu]\nlink = "serial"\nprofile = "acc3_serial"\n'
            f'port = "/dev/null"\n[protocol]\n{extra}\n')
    (tmp_path / "b.toml").write_text(text)
    with pytest.raises(ProfileError, match=message.replace("[", r"\[").replace("]", r"\]")):
        BenchProfile.load(tmp_path / "b.toml")


def test_a_redundant_unit_needs_its_layout(tmp_path):
    (tmp_path / "b.toml").write_text('[bench]\nunit_serial = "S"\n[imu]\nlink = "serial"\n'
                                     'profile = "acc4_serial"\nport = "/dev/null"\n'
                                     '[protocol]\nkind = "static"\n')
    with pytest.raises(ProfileError, match="layout: missing; the device has 4 accelerometer"):
        BenchProfile.load(tmp_path / "b.toml")
    (tmp_path / "g.toml").write_text('[bench]\nunit_serial = "S"\n[imu]\nlink = "serial"\n'
                                     'profile = "imu12_serial"\nport = "/dev/null"\n'
                                     '[protocol]\nkind = "static"\n')
    with pytest.raises(ProfileError, match="0 accelerometer channels"):
        BenchProfile.load(tmp_path / "g.toml")


def test_live_view_is_refused_for_hand_protocols(tmp_path, capsys):
    (tmp_path / "b.toml").write_text('[bench]\nunit_serial = "S"\n[imu]\nlink = "serial"\n'
                                     'profile = "acc3_serial"\nport = "/dev/null"\n'
                                     '[protocol]\nkind = "static"\n')
    assert cli.main(["record", "--profile", str(tmp_path / "b.toml"), "--live",
                     "--out", str(tmp_path / "x.h5")]) == 2
    assert "live view shows rotary sessions" in capsys.readouterr().err
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.parametrize("protocol", ["static", "iron"])
def test_station_record_against_the_hand_twin_with_a_console_operator(protocol, tmp_path):
    """The twin's technician turns on its own metronome; the console operator only presses Enter:
    the station finds every pose itself and the calibration file matches the truth."""
    from station.acquire.operator import ConsoleOperator
    from station.twin.served import HandTwin

    with HandTwin(protocol, seed=9, poses=12, mountings=1) as twin:
        (tmp_path / "b.toml").write_text(twin.profile_text("SN-TWIN"))
        profile = BenchProfile.load(tmp_path / "b.toml")
        prompts = io.StringIO()
        summary = record(profile, tmp_path / "s.h5", ConsoleOperator(io.StringIO("\n" * 50),
                                                                       prompts))
        truth = twin.truth()
    assert twin.error is None
    assert summary["positions_done"] == profile.positions == (12 if protocol == "static" else 6)
    assert cli.main(["solve", str(tmp_path / "s.h5")]) == 0
    cal = load(tmp_path / "s.cal.json", unit_serial="SN-TWIN")
    a = np.array(truth["a"])
    z = np.concatenate([(cal.bias - truth["bias"]) / cal.bias_sigma,
                        (cal.scale_factors - np.linalg.norm(a, axis=0)) / cal.scale_factors_sigma])
    assert np.all(np.abs(z) < stats.norm.isf(FAMILY_FALSE_ALARM / 2 / z.size)), z
    assert "press Enter when done" in prompts.getvalue()
