"""What users meet (issue 36): outputs that explain themselves, paths without dead ends.

One test per finding of a new user's walk through the README, the docs and `--help`: the demo's
figures explained, the verdict in the HTML report and on the twins, the way to a Kalibr file by
the command line alone (`station noise --store`), Allan plots that draw only what their table
calls resolved, the obvious default stream, bundled profile names, exit 141 on a closed pipe,
unknown options named with their command, a calibration file refused before a recording, not
after it, and the README's test command naming failing tests."""

import dataclasses
import json
import signal
import subprocess
import sys
import time
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_exports import acc_cal, gyro_cal

from station import cli
from station.calfiles.calfile import load
from station.reduce.noise import session_noise
from station.report import noise as noise_report
from station.report import session as session_report
from station.session import Session
from station.sim.noise import simulated_noise

STATION = [sys.executable, "-m", "station"]
ROOT = Path(__file__).resolve().parents[1]
REST_RATE = 100.0
REST_SECONDS = 600.0
ACC_NOISE = (2e-3, 2e-3)  # white N (m/s^2 sqrt(s)) and random walk K (m/s^2 / sqrt(s))
GYRO_NOISE = (1e-3, 1e-3)  # rad/s sqrt(s), rad/s / sqrt(s)


def station(*argv, check: bool = True) -> subprocess.CompletedProcess:
    """`station ARGV` in its own process: what a user's shell sees."""
    done = subprocess.run([*STATION, *map(str, argv)], capture_output=True, text=True,
                          timeout=900, stdin=subprocess.DEVNULL)
    if check:
        assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr and "Warning" not in done.stderr, done.stderr
    return done


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """`station demo --positions 8 --out demo.h5`: (session path, what it printed)."""
    path = tmp_path_factory.mktemp("demo") / "demo.h5"
    done = station("demo", "--positions", 8, "--out", path)
    return path, done.stdout


@pytest.fixture(scope="module")
def rest(tmp_path_factory):
    """A 10-minute rest of an accelerometer and gyro triad (white noise and random walk, the time
    column at 100 Hz as a CSV writes it) imported with `station import csv` as unit SN42."""
    folder = tmp_path_factory.mktemp("rest")
    k = int(REST_RATE * REST_SECONDS)
    rng = np.random.default_rng(36)
    acc = np.column_stack([simulated_noise(k, REST_RATE, white=ACC_NOISE[0],
                                           random_walk=ACC_NOISE[1], rng=rng) for _ in range(3)])
    acc[:, 2] += 9.80665
    gyro = np.column_stack([simulated_noise(k, REST_RATE, white=GYRO_NOISE[0],
                                            random_walk=GYRO_NOISE[1], rng=rng) for _ in range(3)])
    csv = folder / "rest.csv"
    np.savetxt(csv, np.column_stack([np.arange(k) / REST_RATE, acc, gyro]), delimiter=",",
               header="t,ax,ay,az,gx,gy,gz", comments="", fmt="%.9g")
    path = folder / "rest.h5"
    station("import", "csv", path, csv, "--time", "t", "--stream", "acc=ax,ay,az", "--unit",
            "acc=m/s^2", "--stream", "gyro=gx,gy,gz", "--unit", "gyro=rad/s", "--unit-serial",
            "SN42")
    return path


# -- the demo explains its figures -------------------------------------------------------------

def test_the_demo_explains_every_figure_and_what_its_verdict_tested(demo):
    _, printed = demo
    legend = printed[printed.index("what the figures mean:"):]
    for figure in ("1 sigma", "true", "eps", "sqrt(trace CRLB)", "p ", "chi2/dof", "VERDICT"):
        assert f"\n  {figure} " in legend, figure
    assert "ratio: eps / bound" in legend
    assert "tested against the unit type's tolerances: 12 scale factors |k - 1| <= 0.05, 12 " \
           "biases |b| <= 0.03" in printed


# -- the verdict in the HTML report, and on the twins -------------------------------------------

def test_the_report_shows_the_verdict_of_the_calibration_file(demo, tmp_path):
    path, _ = demo
    tolerances = tmp_path / "tolerances.toml"
    tolerances.write_text("[tolerances]\nscale_factor = 0.05\nbias = 0.03\n")
    station("solve", path, "--tolerances", tolerances, "--force")
    built = session_report.build(path)
    assert built.summary["verdict"].startswith(f"PASS (24 parameters tested, {path.stem}.cal.json")
    page = built.html()
    assert "<h2>Verdict: PASS</h2>" in page and "VERDICT: PASS (24 parameters tested" in page


def test_the_twins_profiles_give_a_verdict(tmp_path):
    from station.acquire.bench import BenchProfile
    from station.solve.verdict import Tolerances
    from station.twin.served import BenchTwin, HandTwin

    for k, twin in enumerate((BenchTwin(), HandTwin("static"))):
        profile = tmp_path / f"twin{k}.toml"
        with twin:
            profile.write_text(twin.profile_text())
            BenchProfile.load(profile)  # `station record` takes it, [tolerances] and all
        tolerances = Tolerances.from_table(tomllib.loads(profile.read_text())["tolerances"])
        assert None not in (tolerances.scale_factor, tolerances.bias, tolerances.axis_angle_deg)


# -- Kalibr by the command line alone ----------------------------------------------------------

def test_noise_store_puts_a_rests_figures_where_the_kalibr_export_finds_them(rest, tmp_path):
    acc, gyro = tmp_path / "acc.cal.json", tmp_path / "gyro.cal.json"
    acc_cal().save(acc)
    gyro_cal().save(gyro)
    refused = station("export", acc, "--gyro", gyro, "--to", "kalibr", check=False)
    assert refused.returncode == 2
    assert "`station noise REST.h5 --store CAL.cal.json`" in refused.stderr  # the way out, named
    # ... followed to the letter: the gyro's stream is found from its calibration's sensors
    for cal in (acc, gyro):
        done = station("noise", rest, "--store", cal)
        assert f"noise figures stored in {cal} (white noise, bias instability, random walk)" \
            in done.stdout or f"noise figures stored in {cal} (white noise, random walk" \
            in done.stdout, done.stdout
    out = tmp_path / "imu.yaml"
    station("export", acc, "--gyro", gyro, "--to", "kalibr", "--out", out)
    doc = yaml.safe_load(out.read_text())
    assert doc["update_rate"] == 100.0 and "update_rate: 100.0\n" in out.read_text()
    stored = load(gyro).noise
    assert stored.rate_hz == pytest.approx(REST_RATE) and stored.random_walk is not None
    # the random walk of each sensor within 4 sigma of the simulated one (the fit's own sigma)
    z = (stored.random_walk - GYRO_NOISE[1]) / stored.random_walk_sigma
    assert np.all(np.abs(z) < 4), z
    assert load(gyro).session["noise_source"]["stream"] == "gyro"


def test_noise_store_refuses_another_units_rest(rest, tmp_path):
    cal = tmp_path / "other.cal.json"
    acc_cal(unit_serial="SN7").save(cal)
    done = station("noise", rest, "--store", cal, check=False)
    assert done.returncode == 2 and "records unit 'SN42'" in done.stderr
    assert "--unit-serial" in done.stderr


# -- the obvious default, or the choices listed -------------------------------------------------

def test_noise_picks_the_stream_solve_calibrates(rest):
    done = station("noise", rest, "--json")
    assert json.loads(done.stdout)["stream"] == "acc"  # the import's one stream in m/s^2
    assert "legend: N, the white noise's density" in station("noise", rest).stdout


def test_a_gyro_carried_through_turns_names_its_accelerometer_among_several(tmp_path):
    k = 2000
    t = np.arange(k) / 100.0
    rng = np.random.default_rng(1)
    acc = rng.normal([0, 0, 9.8], 0.01, (k, 3))
    table = np.column_stack([t, acc, acc, rng.normal(0, 0.001, (k, 3))])
    csv = tmp_path / "two.csv"
    np.savetxt(csv, table, delimiter=",", comments="", fmt="%.9g",
               header="t,ax,ay,az,bx,by,bz,gx,gy,gz")
    path = tmp_path / "two.h5"
    station("import", "csv", path, csv, "--time", "t", "--stream", "acc=ax,ay,az",
            "--unit", "acc=m/s^2", "--stream", "acc2=bx,by,bz", "--unit", "acc2=m/s^2",
            "--stream", "gyro=gx,gy,gz", "--unit", "gyro=rad/s")
    refused = station("solve", path, "--stream", "gyro", check=False)
    assert refused.returncode == 2
    assert "are acc, acc2" in refused.stderr and "--accelerometer NAME" in refused.stderr
    chosen = station("solve", path, "--stream", "gyro", "--accelerometer", "acc2", check=False)
    assert chosen.returncode == 2 and "acc, acc2" not in chosen.stderr  # past the choice
    wrong = station("solve", path, "--stream", "gyro", "--accelerometer", "gyro", check=False)
    assert wrong.returncode == 2 and "--accelerometer 'gyro' is not a stream in m/s^2" \
        in wrong.stderr


# -- Allan plots draw what their table calls resolved ------------------------------------------

def legend_labels(figure) -> list:
    return [text.get_text() for ax in figure.axes for text in ax.get_legend().get_texts()]


def test_the_allan_plot_draws_only_the_terms_its_table_resolves(demo):
    path, _ = demo
    with Session.open(path) as session:
        found = session_noise(session, "imu")
    assert not found.fit.resolved[1:].any()  # 8 static windows of 10 s: N only
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figure = noise_report.allan_figure(found)
        labels = legend_labels(figure)
        assert not any(ax.texts for ax in figure.axes)  # named in the legend: nothing overprinted
        # a term fitted below zero: its model is not drawn where negative, and without a warning
        theta = found.fit.theta.copy()
        theta[:, 1] = -abs(theta[:, 0]) * 1e3
        negative = dataclasses.replace(found, fit=dataclasses.replace(found.fit, theta=theta))
        noise_report.allan_figure(negative)
    assert any(label.startswith("slope -1/2: N = ") for label in labels)
    assert not any(": B = " in label or ": K = " in label for label in labels), labels


def test_the_gyro_table_of_a_carried_solve_has_no_nan():
    from station.commands.solve import _text

    # what `station solve SESSION --stream GYRO` summarises: no white-noise-only figures
    summary = {"sensors": ["gyro1", "gyro2", "gyro3"], "scale_factors": [1.0, 1.1, 0.9],
               "scale_factors_sigma": [1e-3] * 3, "scale_factors_sigma_white": None,
               "bias": [0.1, 0.2, 0.3], "bias_sigma": [1e-3] * 3, "bias_sigma_white": None,
               "start": None, "unit_serial": "SN", "positions": 13, "method": "gravity carry",
               "frame": "canonical", "chi2_per_dof": 1.0, "units": "rad/s", "pose_sigma": None,
               "status": "ok", "status_reasons": [], "verdict": None, "noise": None,
               "no_noise_figures": None, "calibration": "x.cal.json", "weakly_determined": []}
    text = _text(summary)
    assert "nan" not in text and "(white)" not in text


# -- bundled profiles, plans that say why -------------------------------------------------------

def test_plan_takes_a_bundled_profile_by_name_and_says_why_poses_repeat(capsys):
    assert cli.main(["plan", "--profile", "bench_cube"]) == 0
    printed = capsys.readouterr().out
    assert "20 positions in 8 distinct poses (6 of them 3 times)" in printed
    assert cli.main(["plan", "--profile", "bench_serial"]) == 2
    assert "the bundled bench_cube has one" in capsys.readouterr().err


# -- the command line ---------------------------------------------------------------------------

def test_apply_into_a_closed_pipe_exits_141(demo, tmp_path):
    path, _ = demo
    cal = tmp_path / "demo.cal.json"
    solved = station("solve", path, "--out", cal)  # its figures explained once, at the end
    assert solved.stdout.splitlines()[-1].startswith("legend: scale factor |a_i| and bias b_i")
    assert "; chi2/dof: the residuals against the readings' noise" in solved.stdout
    apply = subprocess.Popen([*STATION, "apply", str(cal), str(path)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    assert apply.stdout.readline().startswith("time [s],")
    apply.stdout.close()  # `| head -1`: the reader goes; megabytes are still to come
    assert apply.wait(timeout=300) == 141
    assert apply.stderr.read() == ""


def test_an_unknown_option_is_named_with_its_command(capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main(["apply", "a.cal.json", "b.csv", "--bogus"])
    assert stop.value.code == 2
    assert capsys.readouterr().err == ("station apply: unrecognized arguments: --bogus (see "
                                       "station apply --help)\n")


def test_record_solve_refuses_an_existing_calibration_file_before_recording(tmp_path):
    out = tmp_path / "s.h5"
    out.with_suffix(".cal.json").write_text("{}")
    done = station("record", "--profile", "bench_serial", "--out", out, "--solve", check=False)
    assert done.returncode == 2 and not out.exists()  # refused before any device was opened
    assert f"{out.with_suffix('.cal.json')} exists" in done.stderr


def test_the_readme_test_command_names_failing_tests():
    addopts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"][
        "ini_options"]["addopts"]
    assert "-rfE" in addopts.split()


def test_the_docs_say_what_the_autopilot_files_do_with_a_temperature_model():
    cli_md = (ROOT / "docs" / "cli.md").read_text()
    assert "waits for the temperature issue" not in cli_md
    assert "ArduPilot's INS_TCAL" in cli_md


def events(path: Path) -> list:
    """The kinds of the events a running recording has flushed so far ([] before it can be
    read)."""
    try:
        with Session.open(path) as session:
            return [e.kind for e in session.events()]
    except Exception:  # noqa: BLE001 - the writer may not have created the file yet
        return []


def interrupt_when(process, path: Path, ready) -> subprocess.CompletedProcess:
    """Ctrl-C (SIGINT) to `process` once `ready(path)` holds; what it printed."""
    while process.poll() is None and not ready(path):
        time.sleep(0.05)
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=300)
    return subprocess.CompletedProcess(process.args, process.returncode, out, err)


def test_an_interrupted_resume_names_the_command_that_goes_on(tmp_path):
    path = tmp_path / "s.h5"
    demo = subprocess.Popen([*STATION, "demo", "--out", str(path)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    stopped = interrupt_when(demo, path, lambda p: events(p).count("position_done") >= 2)
    assert stopped.returncode == 130, stopped.stderr
    size = path.stat().st_size
    resume = subprocess.Popen([*STATION, "resume", str(path)], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    # resume writing (the file grows): no reader here, which would make resume refuse the file
    stopped = interrupt_when(resume, path, lambda p: p.stat().st_size > size)
    assert stopped.returncode == 130, stopped.stderr
    assert stopped.stderr.strip().endswith(f"{path} keeps the completed positions; go on with "
                                           f"`station resume {path}`"), stopped.stderr


def test_two_commands_given_one_out_keep_the_first_file_and_refuse_in_one_line(demo, tmp_path):
    path, _ = demo
    out = tmp_path / "same.cal.json"
    both = [subprocess.Popen([*STATION, "solve", str(path), "--out", str(out)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for _ in range(2)]
    done = sorted((p.wait(timeout=600), p.stderr.read()) for p in both)
    assert [code for code, _ in done] == [0, 2], done
    assert "Traceback" not in done[1][1]
    assert done[1][1].startswith(f"station solve: {out} exists"), done[1][1]
    load(out)  # the first file, whole


def test_imucals_gyro_solved_from_the_turns_prints_no_nan(tmp_path):
    data = ROOT.parent / "shared" / "data" / "real" / "imucal-ferraris"
    if not data.is_dir():
        pytest.skip("../shared/data/real is absent")
    h5 = tmp_path / "fer.h5"
    station("import", "csv", h5, data / "example_ferraris_session.csv", "--no-time", "--fs",
            "102.4", "--stream", "acc=acc_x,acc_y,acc_z", "--unit", "acc=m/s^2", "--stream",
            "gyro=gyr_x,gyr_y,gyr_z", "--unit", "gyro=deg/s")
    done = station("solve", h5, "--stream", "gyro", "--magnitude", "9.81", "--faces", "--out",
                   tmp_path / "gyro.cal.json")
    assert "nan" not in done.stdout and "(white)" not in done.stdout
    assert "gyro1" in done.stdout


def test_an_autopilot_export_says_it_leaves_the_temperature_model_out(tmp_path):
    from test_temperature_file import model

    acc = tmp_path / "acc.cal.json"
    gyro = tmp_path / "gyro.cal.json"
    acc_cal().save(acc)
    covariance = np.diag(np.r_[np.full(9, 1e-4), np.full(3, 1e-5)] ** 2)
    gyro_cal(covariance=covariance).with_temperature(model()).save(gyro)
    done = station("export", acc, "--gyro", gyro, "--to", "ardupilot", "--json")
    notes = " ".join(json.loads(done.stdout)["notes"])
    assert "ArduPilot: the gyroscope's temperature model is not written" in notes
    assert "T_REF = 300.00 K" in notes and "--c-header` holds the whole model" in notes
