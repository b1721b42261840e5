"""Issue 16, items 3-4: the lettered-cube fixture's poses and words, the planner of positions, the
bench profile's [fixture] section, `station plan`, and a session recorded on the twin's cube."""

import io
import json
import subprocess
import sys

import numpy as np
import pytest
from layouts import A_MODEL

import station
from drivers.profile import ProfileError
from station.acquire.bench import BenchProfile, record
from station.acquire.operator import ConsoleOperator
from station.calfiles.calfile import load
from station.commands.record import solve
from station.errors import CalibrationInputError, InputError
from station.model.fixture import Fixture, picture
from station.protocols.planned import FixtureSpec, reading_noise, rotary_plan
from station.protocols.rotary import RotaryProtocol, RotarySettings, suggested_axes
from station.session import Session
from station.solve.plan import expected_eps, plan
from station.solve.uncertainty import eps_tail_probability
from station.twin.served import BenchTwin

STATION = [sys.executable, "-m", "station"]
R = 1 / np.sqrt(2)


# -- the fixture ----------------------------------------------------------------------------------

def test_a_face_down_points_the_opposite_face_up_and_the_front_face_at_the_technician():
    pose = Fixture().pose("F", "A")  # F = -z down, A = +x toward the front
    assert pose.words == "face F down, face A toward the front"
    # bench x (front) = +x, bench z (up) = +z, bench y = z x x = +y in the cube = unit frame
    np.testing.assert_allclose(pose.orientation, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(Fixture().pose("C", "E").up, [0, -1, 0], atol=1e-15)


def test_on_the_wedge_up_lies_between_the_slope_face_and_the_front_face():
    # the slope rises away from the technician: the front face A looks 45 deg down toward them,
    # so up has -cos 45 of A's normal, and +sin 45 from the face opposite the slope (E)
    pose = Fixture(wedge=True).pose("F", "A", wedge=True)
    np.testing.assert_allclose(pose.up, [-R, 0, R], atol=1e-15)
    assert pose.words == "on the wedge: face F on the slope, face A toward the front"
    assert "top: B/E" in picture(pose) and "down: F" in picture(pose)


def test_the_cube_reaches_24_rotations_and_the_wedge_24_more():
    poses = Fixture(wedge=True).poses()
    rotations = np.array([p.orientation for p in poses])
    assert len(poses) == 48
    np.testing.assert_allclose(np.einsum("kji,kjl->kil", rotations, rotations),
                               np.broadcast_to(np.eye(3), (48, 3, 3)), atol=1e-12)
    assert np.allclose(np.linalg.det(rotations), 1.0)
    distinct = np.unique(np.round(rotations.reshape(48, 9), 9), axis=0)
    assert len(distinct) == 48
    ups, _ = Fixture(wedge=True).reachable_up()
    # 6 face normals and 12 edge diagonals (+-e_i +- e_k)/sqrt 2
    assert len(ups) == 18
    assert sorted(np.round(np.abs(ups).sum(axis=1), 9)) == [1.0] * 6 + [round(2 * R, 9)] * 12


def test_the_mounting_turns_every_pose_into_the_unit_frame():
    turn = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], float)  # unit x = cube y, ...
    np.testing.assert_allclose(Fixture(turn).pose("F", "A").up, turn @ [0, 0, 1])
    np.testing.assert_allclose(Fixture(turn).pose("B", "C").up, turn @ [1, 0, 0])


@pytest.mark.parametrize("bad", [np.diag([1.0, 1.0, -1.0]), np.ones((3, 3)), np.eye(2)])
def test_a_mounting_that_is_no_rotation_is_refused(bad):
    with pytest.raises(InputError, match="rotation"):
        Fixture(bad)


def test_opposite_faces_are_no_pose():
    with pytest.raises(InputError, match="neighbouring faces"):
        Fixture().pose("A", "B")


# -- the planner ----------------------------------------------------------------------------------

@pytest.mark.parametrize("bias", [False, True])
def test_the_expected_eps_is_the_square_root_of_the_crlb_trace(bias):
    # the planner adds per-position informations; station.crlb builds the bound of all positions
    # at once and takes an eigen-decomposition pseudo-inverse: two routes to the same number
    up = suggested_axes(15)
    want = np.sqrt(np.trace(station.crlb(A_MODEL, up.T, 0.02, estimate_bias=bias)))
    assert expected_eps(A_MODEL, up, 0.02, 1.0, bias) == pytest.approx(want, rel=1e-9)


def test_a_plan_that_does_not_identify_the_layout_has_infinite_expected_eps():
    # five directions: fewer than Eq. 16's d(d+1)/2 = 6
    assert expected_eps(np.eye(3), suggested_axes(5), 0.01, 1.0) == np.inf


def test_the_greedy_stops_when_one_more_position_gains_less_than_the_threshold():
    up, _ = Fixture(wedge=True).reachable_up()
    result = plan(np.eye(3), up, 0.01, 1.0, threshold=0.03)
    n = len(result.expected)
    assert np.isfinite(result.expected[-1])
    assert 1 - result.expected[-1] / result.expected[-2] >= 0.03
    # no candidate added to the greedy positions gains 3 % (brute force through station.crlb)
    greedy = plan(np.eye(3), up, 0.01, 1.0, threshold=0.0, most=n)
    assert np.allclose(greedy.expected, result.expected)
    base = up[greedy.chosen]  # after the exchanges: at least as good as the greedy
    assert expected_eps(np.eye(3), base, 0.01, 1.0) <= result.expected[-1] * (1 + 1e-9)
    best_next = min(np.sqrt(np.trace(station.crlb(np.eye(3), np.vstack([base, u]).T, 0.01)))
                    for u in up)
    assert 1 - best_next / result.eps < 0.03 + 0.01  # the exchanged set may differ a little


def test_the_plan_is_no_worse_than_random_choices_of_the_same_count():
    up, _ = Fixture(wedge=True).reachable_up()
    result = plan(A_MODEL, up, 0.01, 1.0, threshold=0.0, most=12)
    rng = np.random.default_rng(4)
    random = [expected_eps(A_MODEL, up[rng.choice(len(up), 12)], 0.01, 1.0) for _ in range(50)]
    assert result.eps <= min(random)


def test_the_plan_does_not_depend_on_the_noise_scale_and_its_eps_is_proportional_to_it():
    up, _ = Fixture(wedge=True).reachable_up()
    a, b = plan(A_MODEL, up, 0.01, 1.0), plan(A_MODEL, up, 0.03, 1.0)
    assert list(a.chosen) == list(b.chosen) and b.eps == pytest.approx(3 * a.eps, rel=1e-9)


def test_a_cube_without_wedge_cannot_calibrate_gyros_and_says_to_add_the_wedge():
    up, _ = Fixture().reachable_up()  # +-x, +-y, +-z: three axes, Eq. 16 needs 6 directions
    with pytest.raises(CalibrationInputError, match="wedge"):
        plan(A_MODEL, up, 0.01, 1.0)


def test_the_expected_eps_matches_the_monte_carlo_eps():
    # 300 calibrations of a triad at the default plan's fixture directions: E[eps^2] = trace CRLB
    # for an efficient estimator; eps^2 is a sum of 9 weighted chi2_1, so the mean of 300 has a
    # relative standard error below sqrt(2 / 300) = 8 %, i.e. 4 % on the RMS: 10 % is 2.5 sigma
    up, _ = Fixture(wedge=True).reachable_up()
    result = plan(np.eye(3), up, 0.01, 1.0)
    v = up[result.chosen].T
    rng = np.random.default_rng(16)
    eps = []
    for _ in range(300):
        a = np.eye(3) + 0.01 * rng.standard_normal((3, 3))
        fit = station.calibrate(a.T @ v + 0.01 * rng.standard_normal(v.shape), 1.0, sigma=0.01)
        eps.append(station.eps(a, fit.a))
    assert np.sqrt(np.mean(np.square(eps))) == pytest.approx(result.eps, rel=0.10)


def test_the_reading_noise_is_that_of_two_window_means():
    # white noise of density N: the mean over T s has variance N^2 / T; 2 turns at 0.5 rad/s
    # take 8 pi s, the static window 10 s
    s = RotarySettings(rate=0.5, revolutions=2, static=10.0)
    assert reading_noise(2.0, s) == pytest.approx(2.0 * np.sqrt(1 / (8 * np.pi) + 1 / 10))


# -- the bench profile and `station plan` ---------------------------------------------------------

PROFILE = """[bench]
unit_serial = "SN7"
[imu]
link = "serial"
profile = "imu12_serial"
port = "/dev/null"
[table]
host = "127.0.0.1"
port = 502
[protocol]
rate = 1.0
{protocol}
[fixture]
layout = {layout}
noise_density = 1.7e-4
wedge = {wedge}
"""


def profile(tmp_path, wedge="true", protocol="", layout=None):
    layout = A_MODEL.tolist() if layout is None else layout
    path = tmp_path / "bench.toml"
    path.write_text(PROFILE.format(wedge=wedge, protocol=protocol, layout=json.dumps(layout)))
    return path


def test_a_fixture_makes_the_positions_the_plans_largest_count(tmp_path):
    bench = BenchProfile.load(profile(tmp_path))
    assert bench.positions == 40 and bench.fixture.fixture.wedge
    assert BenchProfile.load(profile(tmp_path, protocol="positions = 12")).positions == 12


@pytest.mark.parametrize("change, message", [
    ({"layout": [[1, 0], [0, 1], [0, 0]]}, "3 lists of 12"),
    ({"wedge": '"yes"'}, "wedge"),
])
def test_a_bad_fixture_section_is_refused_naming_the_key(tmp_path, change, message):
    with pytest.raises(ProfileError, match=message):
        BenchProfile.load(profile(tmp_path, **change))


HAND = ('[bench]\nunit_serial = "S"\n[imu]\nlink = "serial"\nprofile = "{device}"\n'
        'port = "/dev/null"\n[protocol]\nkind = "{kind}"\n{protocol}[fixture]\n'
        "noise_density = 1e-3\nwedge = true\n{fixture}")


def test_a_static_bench_takes_the_fixture_and_the_layout_of_its_protocol_section(tmp_path):
    path = tmp_path / "static.toml"
    path.write_text(HAND.format(device="acc3_serial", kind="static", protocol="", fixture=""))
    np.testing.assert_array_equal(BenchProfile.load(path).fixture.layout, np.eye(3))
    path.write_text(HAND.format(device="acc3_serial", kind="static", protocol="",
                                fixture="layout = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n"))
    with pytest.raises(ProfileError, match="unknown keys \\['layout'\\]"):
        BenchProfile.load(path)


def test_a_fixture_on_an_iron_bench_is_refused(tmp_path):
    path = tmp_path / "iron.toml"
    path.write_text(HAND.format(device="acc4_serial", kind="iron", fixture="", protocol=(
        "layout = [[1, 0, 0, 0.577], [0, 1, 0, 0.577], [0, 0, 1, 0.577]]\n")))
    with pytest.raises(ProfileError, match="remove the \\[fixture\\]"):
        BenchProfile.load(path)


def test_station_plan_prints_the_poses_in_words_and_the_expected_eps(tmp_path):
    path = profile(tmp_path)
    out = subprocess.run([*STATION, "plan", "--profile", str(path), "--json"], check=True,
                         capture_output=True, text=True).stdout
    got = json.loads(out)
    assert got["positions"] == len(got["poses"]) >= 6
    words = [p["words"] for p in got["poses"]]
    assert all(w.startswith(("face ", "on the wedge: face ")) for w in words)
    up = np.array([p["up"] for p in got["poses"]])
    sigma = reading_noise(1.7e-4, RotarySettings())
    assert got["expected_eps"] == pytest.approx(
        np.sqrt(np.trace(station.crlb(A_MODEL, up.T, sigma))), rel=1e-9)
    text = subprocess.run([*STATION, "plan", "--profile", str(path), "--pictures"], check=True,
                          capture_output=True, text=True).stdout
    assert words[0] in text and "+-----+" in text


def test_station_plan_without_a_fixture_says_what_to_add(tmp_path):
    path = tmp_path / "plain.toml"
    path.write_text(PROFILE.split("[fixture]")[0].format(protocol="positions = 8"))
    run = subprocess.run([*STATION, "plan", "--profile", str(path)], capture_output=True,
                         text=True)
    assert run.returncode == 2 and "add a [fixture] section" in run.stderr


def test_a_cube_without_wedge_is_refused_by_station_plan(tmp_path):
    run = subprocess.run([*STATION, "plan", "--profile", str(profile(tmp_path, wedge="false"))],
                         capture_output=True, text=True)
    assert run.returncode == 2 and "wedge" in run.stderr


# -- a session on the twin's cube -----------------------------------------------------------------

def test_record_asks_for_the_planned_poses_and_the_twins_technician_sets_them(tmp_path):
    positions = 8
    with BenchTwin(seed=7, positions=positions, cube=True) as twin:
        (tmp_path / "b.toml").write_text(twin.profile_text())
        bench = BenchProfile.load(tmp_path / "b.toml")
        said = io.StringIO()
        summary = record(bench, tmp_path / "s.h5",
                         ConsoleOperator(stdin=io.StringIO("\n" * positions), stdout=said))
        truth = twin.truth()
        asked = [i.text for i in twin.instructions]
    assert summary["positions_done"] == summary["positions_planned"] == positions
    assert bench.positions == positions  # the twin's [protocol] positions: the plan's largest
    text = said.getvalue()
    assert text.startswith(f"plan: {positions} positions on the fixture, expected eps")
    with Session.open(tmp_path / "s.h5") as s:
        poses = s.metadata["fixture_poses"]
        expected = s.metadata["plan"]["expected_eps"]
        assert [e.kind for e in s.events()].count("position_done") == positions
    # the station's prompts, the session and the twin's technician name the same poses
    assert [t.split("\n")[0].split(": set the cube ")[1] for t in asked] == \
        [p["words"] for p in poses]
    assert all(f"set the cube {p['words']}" in text for p in poses)
    # the technician set each asked orientation (placement error 0.5 deg per axis: the angle
    # is 0.5 deg x a chi with 3 dof, below 5 x 0.5 x sqrt 3 deg but for 1e-9)
    set_ = np.array(truth["orientations"])[:positions]
    angle = [np.degrees(np.arccos(np.clip((np.trace(np.array(p["orientation"]).T @ r) - 1) / 2,
                                          -1, 1))) for p, r in zip(poses, set_, strict=True)]
    assert max(angle) < 5 * 0.5 * np.sqrt(3)
    # the expected eps told before the session is the bound of the planned directions for the
    # twin unit's noise (station.sim.layouts.gyro_array: 0.01 deg/s/sqrt(Hz)) and true layout;
    # the calibration's eps is consistent with that bound
    a = np.array(truth["a"])
    bound = station.crlb(a, set_[:, :, 2].T, reading_noise(np.radians(0.01), RotarySettings()))
    assert expected == pytest.approx(np.sqrt(np.trace(bound)), rel=0.05)
    cal = load(solve(tmp_path / "s.h5", accept_suspect=True)["calibration"])
    assert eps_tail_probability(station.eps(a, cal.a), bound) > 1e-4


def test_a_resumed_session_asks_for_the_fixture_poses_it_recorded():
    # the session metadata keeps the poses (JSON): `station resume` rebuilds the same prompts
    spec = FixtureSpec(Fixture(wedge=True), A_MODEL, 1.7e-4)
    steps = rotary_plan(spec, RotarySettings(), 10).instructions()
    first = RotaryProtocol(None, None, None, fixture_poses=steps)
    again = RotaryProtocol.from_metadata(json.loads(json.dumps(first.metadata())), None, None,
                                         None)
    for j in range(len(steps)):
        asked, resumed = first.instruction(j), again.instruction(j)
        assert asked.text == resumed.text and steps[j]["words"] in asked.text
        np.testing.assert_array_equal(asked.orientation, resumed.orientation)
    np.testing.assert_allclose(again.axes, [np.array(s["orientation"])[:, 2] for s in steps])


def test_a_static_session_on_the_cube_asks_for_each_planned_pose_once(tmp_path):
    # accelerometers: the same cube set still on the table or the wedge, biases estimated; the
    # hand twin's technician sets the planned poses (1 deg off) on its metronome
    from station.twin.served import HandTwin

    with HandTwin("static", seed=9, cube=True) as twin:
        (tmp_path / "b.toml").write_text(twin.profile_text("SN-CUBE"))
        bench = BenchProfile.load(tmp_path / "b.toml")
        said = io.StringIO()
        summary = record(bench, tmp_path / "s.h5", ConsoleOperator(io.StringIO("\n" * 50), said))
        truth = twin.truth()
        asked = [i.text for i in twin.instructions]
    assert twin.error is None
    with Session.open(tmp_path / "s.h5") as s:
        poses, expected = s.metadata["fixture_poses"], s.metadata["plan"]["expected_eps"]
    n = len(poses)
    assert summary["positions_done"] == summary["positions_planned"] == n >= 12
    words = [p["words"] for p in poses]
    assert len(set(words)) == n and asked == [f"set the cube {w}" for w in words]
    assert all(f"pose {j + 1}/{n}: set the cube {w}, and let go" in said.getvalue()
               for j, w in enumerate(words))
    up = np.array(truth["up"])[:n]
    planned = np.array([np.array(p["orientation"])[:, 2] for p in poses])
    assert np.degrees(np.arccos(np.clip(np.sum(up * planned, axis=1), -1, 1))).max() < 5 * 1.0 * 2
    # expected eps: the bound at the true layout and poses, for the twin's accelerometer noise
    # (station.sim.layouts.accelerometer_triad: 100 ug/sqrt(Hz)) averaged over `hold` = 5 s
    sigma = 100e-6 * 9.80665 / np.sqrt(5.0)
    bound = station.crlb(np.array(truth["a"]), truth["gravity"] * up.T, sigma, estimate_bias=True)
    assert expected == pytest.approx(np.sqrt(np.trace(bound)), rel=0.05)
    cal = load(solve(tmp_path / "s.h5")["calibration"])
    z = np.concatenate([(cal.bias - truth["bias"]) / cal.bias_sigma,
                        (cal.scale_factors - np.linalg.norm(truth["a"], axis=0))
                        / cal.scale_factors_sigma])
    assert np.all(np.abs(z) < 4.5), z  # 6 normal deviates: a false alarm below 1e-4


def test_station_plan_of_a_static_bench_uses_each_pose_once(tmp_path):
    path = tmp_path / "static.toml"
    path.write_text(HAND.format(device="acc3_serial", kind="static", protocol="", fixture=""))
    got = json.loads(subprocess.run([*STATION, "plan", "--profile", str(path), "--json"],
                                    check=True, capture_output=True, text=True).stdout)
    up = np.array([p["up"] for p in got["poses"]])
    assert len({p["words"] for p in got["poses"]}) == got["positions"] >= 12
    assert len(np.unique(np.round(up, 9), axis=0)) == got["positions"]
    # a still pose's reading: the mean of hold = 5 s of white noise of density 1e-3
    assert got["reading_sigma"] == pytest.approx(1e-3 / np.sqrt(5.0))
    assert got["expected_eps"] == pytest.approx(np.sqrt(np.trace(station.crlb(
        np.eye(3), 9.80665 * up.T, 1e-3 / np.sqrt(5.0), estimate_bias=True))), rel=1e-9)
