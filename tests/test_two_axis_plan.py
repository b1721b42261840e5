"""Issue 16, item 4 on the two-axis table of item 5: the [plan] section of a two-axis bench
profile, the plan of the position axis' angles and spins
(`station.protocols.planned.two_axis_plan`), `station plan` on it, and `station record` setting
the planned positions."""

import io
import json

import numpy as np
import pytest
from layouts import A_MODEL
from scipy import stats
from twinproc import station_run

import station
from drivers.profile import ProfileError
from station.acquire.bench import BenchProfile, record
from station.acquire.operator import ConsoleOperator
from station.commands.solve import solve_session
from station.errors import CalibrationInputError, InputError
from station.model.two_axis import position_angles, rate_axis, spin_axes
from station.protocols.planned import PlanSpec, two_axis_plan
from station.protocols.rotary import RotaryProtocol, RotarySettings
from station.reduce.rotary import rotary_readings
from station.session import Session
from station.solve.identifiability import check_design, gram_design
from station.solve.plan import expected_eps
from station.solve.uncertainty import eps_tail_probability
from station.twin.served import BenchTwin

DENSITY = float(np.radians(0.01))  # rad/s/sqrt(Hz): the twin gyros (sim.layouts.gyro_array)
SETTINGS = RotarySettings()  # rate 1 rad/s, 2 revolutions, static 10 s
# one position's Eq. (18) reading: the mean over 2 turns at 1 rad/s (4 pi s) minus the mean of the
# 10 s static window, white noise of density N: sigma^2 = N^2 (1 / (4 pi) + 1 / 10)
SIGMA = DENSITY * np.sqrt(1 / (4 * np.pi) + 1 / 10)
ALARM = 1e-4

pytestmark = pytest.mark.usefixtures("quiet_pymodbus")


def bound_eps(axes, a=A_MODEL, sigma=SIGMA, rate=1.0) -> float:
    """sqrt(trace CRLB) of Eq. (19) (`station.crlb`) for unit-frame spin axes (n, 3)."""
    return float(np.sqrt(np.trace(station.crlb(a, rate * np.asarray(axes).T, sigma))))


@pytest.fixture(scope="module")
def default_plan():
    return two_axis_plan(PlanSpec(A_MODEL, DENSITY), SETTINGS, 40)


def test_the_plan_identifies_g_through_its_spins_and_not_without_them(default_plan):
    plan = default_plan
    assert plan.spins >= 1 and len(plan.phis) >= 5
    assert np.all(np.diff(plan.phis) >= 0) and np.all((plan.phis >= 0) & (plan.phis < 2 * np.pi))
    steps = np.degrees(plan.phis) / 5.0  # on the 5-degree grid
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)
    axes = plan.axes()
    np.testing.assert_allclose(axes, spin_axes(plan.phis, plan.spins))
    check_design(gram_design(axes.T)[0])  # Eq. (7): raises when g is not determined
    cone = rate_axis(plan.phis)
    with pytest.raises(CalibrationInputError, match="quadric cone"):
        check_design(gram_design(cone.T)[0])
    # the bound agrees: without the spins the layout is not identified at all
    assert expected_eps(A_MODEL, cone, SIGMA, 1.0) == np.inf
    # the expected eps is the bound of the planned angles and spins, and the noise is Eq. (18)'s
    assert plan.sigma == pytest.approx(SIGMA, rel=1e-12)
    assert plan.eps == pytest.approx(bound_eps(axes), rel=1e-6)
    assert plan.expected[-1] >= plan.eps * (1 - 1e-9)  # the exchanges never make it worse
    assert len(plan.expected) == len(plan.phis) + plan.spins <= 40


def test_the_expected_eps_holds_against_monte_carlo(default_plan):
    """Readings a^T (rate u_j) + N(0, sigma^2) at the planned stimuli for the 12-gyro nominal
    layout, solved by `station.calibrate` (closed form + ML, as bench/plan.py does): the RMS eps
    of `trials` sessions against the expected eps.

    Tolerance: the RMS of n squared errors has a relative standard error of at most 1 / sqrt(2 n)
    (a single chi-square component; eps^2 sums many, which only narrows it), 4 of them; plus the
    most by which ML's eps^2 exceeded trace(CRLB) in docs/solvers.md's efficiency table (1.029 at
    n = 100, 0.987 +- 0.014 at n = 20), i.e. 1.5 % in eps."""
    trials = 400  # 3 ms each on an idle core, up to 70 ms on the loaded host (BLAS threads)
    plan = default_plan
    v = SETTINGS.rate * plan.axes().T
    rng = np.random.default_rng(2026)
    eps = []
    for _ in range(trials):
        readings = A_MODEL.T @ v + plan.sigma * rng.standard_normal((12, v.shape[1]))
        fit = station.calibrate(readings, SETTINGS.rate, sigma=plan.sigma)
        eps.append(station.eps(A_MODEL, fit.a))
    rms = float(np.sqrt(np.mean(np.square(eps))))
    tolerance = 4 / np.sqrt(2 * trials) + 0.015
    assert abs(rms / plan.eps - 1) < tolerance, (rms, plan.eps, tolerance)


@pytest.mark.parametrize("n", [5, 8, 17])
def test_evenly_spread_positions_on_the_magic_angle_cone_are_isotropic(n):
    # cos^2 54.74 deg = 1/3: each direction's share along the cone's axis is that across it
    v = rate_axis(position_angles(n))
    np.testing.assert_allclose(v.T @ v, n / 3 * np.eye(3), atol=1e-12)


@pytest.mark.parametrize("count", [10, 20])
def test_the_plan_is_as_good_as_evenly_spread_angles_with_their_best_spins(count):
    """The cone is isotropic, so the planner cannot beat evenly spread angles by much; what it
    chooses is the number of spins (the quadric direction of Eq. 7 is seen only by them)."""
    plan = two_axis_plan(PlanSpec(A_MODEL, DENSITY, threshold=0.0), SETTINGS, count)
    assert len(plan.phis) + plan.spins == count
    even = {k: bound_eps(spin_axes(position_angles(count - k), k)) for k in range(1, 5)}
    best = min(even.values())
    assert 0.98 < plan.eps / best < 1.02, (plan.eps, even)
    assert plan.eps < 1.02 * even[1]  # never worse than evenly spread angles and one spin


# -- the profile and `station plan` ---------------------------------------------------------------

BASE = ('[bench]\nunit_serial = "SN-2AX"\n[imu]\nlink = "serial"\nport = "/dev/null"\n'
        'profile = "imu12_serial"\n[table]\nhost = "127.0.0.1"\nport = 5020\n'
        'profile = "{table}"\n[protocol]\n{protocol}')
PLAN = f"[plan]\nlayout = {json.dumps(A_MODEL.tolist())}\nnoise_density = {DENSITY!r}\n"


def write(tmp_path, table="table_two_axis", protocol="", plan=PLAN):
    path = tmp_path / "bench.toml"
    path.write_text(BASE.format(table=table, protocol=protocol) + plan)
    return path


def test_station_plan_tells_the_angles_spins_and_expected_eps(tmp_path):
    path = write(tmp_path)
    run = station_run("plan", "--profile", path, "--json")
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout)
    phis, spins = np.array(got["phis_rad"]), got["spins"]
    np.testing.assert_allclose(np.radians(got["phis_deg"]), phis, rtol=1e-12)
    assert spins >= 1 and got["positions"] == len(phis) + spins == len(got["steps"]) <= 40
    assert got["expected_eps"] == pytest.approx(bound_eps(spin_axes(phis, spins)), rel=1e-6)
    assert got["reading_sigma"] == pytest.approx(SIGMA, rel=1e-12)
    by_count = got["expected_eps_by_count"]
    assert by_count[0] is None and by_count[-1] >= got["expected_eps"] * (1 - 1e-9)
    text = station_run("plan", "--profile", path)
    assert text.returncode == 0, text.stderr
    n = got["positions"]
    assert f"position 1/{n}: position axis to {got['phis_deg'][0]:.1f} deg, the rate axis " \
           "spins" in text.stdout
    assert f"position {n}/{n}: the position axis spins" in text.stdout
    assert f"expected eps {got['expected_eps']:.3g}" in text.stdout


def test_a_two_axis_profile_without_a_plan_section_says_what_to_add(tmp_path):
    run = station_run("plan", "--profile", write(tmp_path, protocol="positions = 8\n", plan=""))
    assert run.returncode == 2
    assert "without a [plan] section: add one (layout, noise_density" in run.stderr


@pytest.mark.parametrize("table, protocol, plan, words", [
    ("table_modbus", "", PLAN, "remove the \\[plan\\] section"),
    ("table_two_axis", "spins = 2\n", PLAN, "spins: only a two-axis table"),
    ("table_two_axis", "", "[plan]\nnoise_density = 1e-4\n", "layout: missing"),
    ("table_two_axis", "", PLAN + "wedge = true\n", "unknown keys \\['wedge'\\]"),
    ("table_two_axis", "", PLAN.replace(f"{DENSITY!r}", "-1.0"), "noise_density must be"),
    ("table_two_axis", "", PLAN.replace(f"{DENSITY!r}", "inf"), "noise_density must be"),
    ("table_two_axis", "", PLAN.replace("[[1.0,", "[[nan,"), "layout: must be finite"),
    ("table_two_axis", "", PLAN + PLAN.replace("[plan]", "[fixture]") + "wedge = true\n",
     "remove the \\[plan\\] section"),
])
def test_a_plan_section_that_cannot_serve_is_refused(tmp_path, table, protocol, plan, words):
    with pytest.raises(ProfileError, match=words):
        BenchProfile.load(write(tmp_path, table, protocol, plan))


def test_a_plan_section_sets_the_largest_count_and_leaves_the_spins_to_the_plan(tmp_path):
    bench = BenchProfile.load(write(tmp_path))
    assert bench.positions == 40 and bench.spins == 0
    np.testing.assert_array_equal(bench.plan.layout, A_MODEL)
    assert bench.plan.threshold == 0.025
    plain = BenchProfile.load(write(tmp_path, protocol="positions = 8\n", plan=""))
    assert plain.plan is None and plain.spins == 1 and plain.positions == 8


# -- a session on the two-axis twin ---------------------------------------------------------------

def test_record_sets_the_planned_angles_and_spins_and_the_session_solves(tmp_path):
    """`record` on the in-process two-axis twin whose profile has a [plan] (`BenchTwin(plan=
    True)`, at most 6 positions): the plan's expected eps told first, the position axis set to
    the planned angles, then the spin; the metadata keeps phis and spins (what `station resume`
    rebuilds the protocol from); every reading is a^T (w u_j) at the planned stimuli and the
    calibration is consistent with their bound and the twin's truth."""
    most = 6
    with BenchTwin(seed=11, positions=most, two_axis=True, plan=True) as twin:
        (tmp_path / "b.toml").write_text(twin.profile_text())
        bench = BenchProfile.load(tmp_path / "b.toml")
        said = io.StringIO()
        summary = record(bench, tmp_path / "s.h5", ConsoleOperator(io.StringIO(), said))
        truth = twin.truth()
    np.testing.assert_array_equal(bench.plan.layout, A_MODEL)  # the twin's unit, nominal
    assert bench.plan.noise_density == pytest.approx(DENSITY)
    told = two_axis_plan(bench.plan, bench.settings, most)  # what `station plan` tells
    assert len(told.phis) + told.spins == most and told.spins >= 1
    assert summary["positions_done"] == summary["positions_planned"] == most
    assert said.getvalue().startswith(f"plan: {len(told.phis)} positions on the cone and "
                                      f"{told.spins} spin(s) of the position axis, expected eps")
    with Session.open(tmp_path / "s.h5") as s:
        metadata = s.metadata
        starts = [e for e in s.events() if e.kind == "position_start"]
        reduced = rotary_readings(s)
    assert metadata["phis"] == pytest.approx(told.phis.tolist(), abs=1e-12)
    assert metadata["spins"] == told.spins
    assert metadata["plan"]["expected_eps"] == pytest.approx(told.eps, rel=1e-12)
    assert [e.detail.get("phi") for e in starts[:len(told.phis)]] == \
        pytest.approx(told.phis.tolist(), abs=1e-12)
    assert [e.detail.get("spin") for e in starts[len(told.phis):]] == ["position"] * told.spins
    resumed = RotaryProtocol.from_metadata(json.loads(json.dumps(metadata)), None, None, None)
    np.testing.assert_allclose(resumed.phis, told.phis)
    assert resumed.spins == told.spins
    # the twin's unit turned about the planned axes: each reading within its sigma's quantile
    a, axes = np.array(truth["a"]), told.axes()
    np.testing.assert_allclose(truth["axes"], axes, atol=1e-12)
    k = stats.norm.ppf(1 - ALARM / (2 * reduced.M.size))
    assert np.all(np.abs(reduced.M - a.T @ axes.T) < k * reduced.sigma)
    cal = solve_session(tmp_path / "s.h5")
    assert eps_tail_probability(station.eps(a, cal.a),
                                station.crlb(a, axes.T, reduced.sigma)) > ALARM


def test_the_twin_refuses_a_plan_without_a_two_axis_table(tmp_path):
    with pytest.raises(InputError, match="--plan plans the positions of a two-axis table"):
        BenchTwin(positions=6, plan=True)
    for protocol in ("rotary", "static"):
        refused = station_run("twin", "--plan", "--protocol", protocol, "--profile-out",
                              tmp_path / "p.toml", timeout=600)
        assert refused.returncode == 2, refused.stderr
        assert "--plan plans the positions of a two-axis table: give --two-axis" in \
            refused.stderr
    assert not (tmp_path / "p.toml").exists()
