"""Issue 32: a bias random walk in the diagnosis' noise model (station.diagnose.coloured).

- The covariance of window means under a walk is that of a sampled random walk.
- With the unit's walk in the noise model, the gaps of an effect-free walking unit are white
  again (static means, spin-up and spin-down means, the readings M), and `station diagnose
  --noise CAL.cal.json` says nothing is unexplained where white noise alone leaves the static
  gap open; a file that cannot give the walk is refused with what to do.
The rates over 10 seeds per case are `bench/diagnose.py --coloured --noise-model`
(docs/diagnose.md).
"""

import dataclasses
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
from test_calfile import make

from station import cli
from station.calfiles.calfile import NoiseFigures
from station.diagnose import coloured, gap, model
from station.imports import npz
from station.sim.rotary import simulate_rotary

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("bench_diagnose", ROOT / "bench" / "diagnose.py")
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)


def test_window_means_of_a_walk_have_the_covariance_of_a_sampled_random_walk():
    fs = 100.0
    windows = [(0, 50), (120, 200), (180, 260), (400, 401)]  # apart, overlapping, one sample
    samples = np.arange(401)
    exact_walk = (np.minimum.outer(samples, samples) + 1) / fs  # unit steps of variance 1 / fs
    rows = np.zeros((len(windows), len(samples)))
    for i, (a, z) in enumerate(windows):
        rows[i, a:z] = 1.0 / (z - a)
    exact = rows @ exact_walk @ rows.T
    spans = np.array([[a / fs, (z - 1) / fs + 1.0 / fs] for a, z in windows])
    ours = coloured.mean_covariance(spans, spans)
    contrast = np.array([[1.0, -1, 0, 0], [0, 1, -1, 0], [-1, 0, 0, 1]])  # the start drops out
    # a mean of N samples against the uniform mean over their span: Var differs by about
    # 1 / (6 N fs) per window (the sums of i^2 against the integral of t^2)
    n_min = min(z - a for a, z in windows)
    assert np.abs(contrast @ (ours - exact) @ contrast.T).max() < 1.0 / (2 * n_min * fs)
    big = [w for w in windows if w[1] - w[0] >= 50]
    pick = [windows.index(w) for w in big]
    sub = contrast[:2][:, :3]  # contrasts of the long windows only
    assert np.abs(sub @ (ours - exact)[np.ix_(pick, pick)] @ sub.T).max() < 1.0 / (2 * 50 * fs)
    assert coloured.mean_covariance(np.array([[0.0, 3.0]]), np.array([[0.0, 3.0]]))[0, 0] == \
        pytest.approx(1.0)  # E min(U, V) of two uniforms on [0, L] is L / 3


def test_an_effect_free_walking_unit_has_white_gaps_with_the_walk_in_the_noise_model():
    m, seeds = 12, 8
    gaps, plain = [], []
    for seed in range(seeds):
        d, _ = bench.session("none_walk", m, 9100 + seed)
        walking = dataclasses.replace(d, random_walk=np.full(m, bench.WALK))
        gaps.append([gap.statistics(walking, model.nominal(walking))[s]
                     for s in ("static", "transients", "averaged")])
        plain.append(gap.statistics(d, model.nominal(d))["static"])
    dof = np.array([19 * m, 2 * 20 * m, 20 * m])  # static (n - 1) m, transients 2 n m, M ~n m
    sd_of_mean = np.sqrt(2.0 / dof / seeds)  # gap x dof ~ chi2(dof) under the model
    assert np.all(np.abs(np.mean(gaps, 0) - 1.0) < 3 * sd_of_mean), np.mean(gaps, 0)
    assert np.mean(plain) > 3.0  # the walk is there: white noise alone leaves it far open


def _walking_session(path: Path, seed: int) -> Path:
    """A 3-gyro rotary session of the bench's `none_walk` case written as .npz."""
    rng = np.random.default_rng(seed)
    unit = bench.gyro_array(rng, bench.LAYOUTS[3], fs=100.0, bias_walk=bench.WALK)
    sim = simulate_rotary(unit, 20, bench.SHORT, a_nominal=bench.LAYOUTS[3])
    npz.write(path, sim)
    return path


def _noise_file(path: Path, walk, sensors=3) -> Path:
    """A calibration file of the unit's gyros holding noise figures with the walk `walk`."""
    white = np.full(sensors, np.radians(0.01))
    cal = make(a=np.eye(3)[:, :sensors] if sensors <= 3 else None).with_noise(NoiseFigures(
        white, white / 20, white / 2, white / 20,
        None if walk is None else np.full(sensors, walk),
        None if walk is None else np.full(sensors, walk / 10), rate_hz=100.0, seconds=1300.0))
    cal.save(path)
    return path


def _diagnose(capsys, *args) -> tuple[int, str]:
    code = cli.main(["diagnose", *map(str, args)])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


def test_diagnose_with_the_units_noise_figures_leaves_no_walk_unexplained(tmp_path, capsys):
    session = _walking_session(tmp_path / "walk.npz", 3500)
    code, out = _diagnose(capsys, session, "--json")
    plain = json.loads(out)
    assert code == 0 and "static" in [u["statistic"] for u in plain["unexplained"]]
    assert plain["noise_model"]["random_walk"] is None
    cal = _noise_file(tmp_path / "unit.cal.json", bench.WALK)
    code, out = _diagnose(capsys, session, "--json", "--noise", cal)
    doc = json.loads(out)
    assert code == 0 and doc["effects"] == [] and doc["unexplained"] == []
    assert doc["noise_model"]["random_walk"] == pytest.approx([bench.WALK] * 3)
    assert doc["fit_test"]["statistics"]["static"]["gap"] < 2.0
    code, out = _diagnose(capsys, session, "--noise", cal)
    assert "noise model: white noise and bias random walk" in out


@pytest.mark.parametrize("walk, sensors, said", [
    (None, 3, "holds no bias random walk"),
    (3e-5, 4, "the session has 3 gyro(s)"),
])
def test_a_noise_file_that_cannot_give_the_walk_is_refused(tmp_path, capsys, walk, sensors,
                                                          said):
    session = _walking_session(tmp_path / "walk.npz", 3501)
    cal = _noise_file(tmp_path / "unit.cal.json", walk, sensors)
    code, out = _diagnose(capsys, session, "--noise", cal)
    assert code != 0 and said in out
