"""Issue 32: coloured noise (a bias random walk, flicker) in the diagnosis' noise model
(station.diagnose.coloured).

- The covariance of window means under a walk is that of a sampled random walk, under flicker
  that of Kasdin-Walter's sampled flicker.
- With the unit's walk in the noise model, the gaps of an effect-free walking unit are white
  again (static means, spin-up and spin-down means, the readings M, slopes and harmonics), and
  `station diagnose --noise CAL.cal.json` says nothing is unexplained where white noise alone
  leaves the static gap open; a free-static walking unit is no drift with its streams' files; a
  file that cannot give the walk is refused with what to do.
The rates over 10 seeds per case are `bench/diagnose.py --coloured --noise-model` and
`bench/diagnose_static.py --noise-model` (docs/diagnose.md).
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
from station.imports.recordings import import_text
from station.sim.rotary import simulate_rotary

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("bench_diagnose", ROOT / "bench" / "diagnose.py")
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)


WINDOWS = [(600, 700), (820, 900), (880, 1000), (1200, 1264)]  # apart, overlapping
CONTRASTS = np.array([[1.0, -1, 0, 0], [0, 1, -1, 0], [-1, 0, 0, 1]])  # weights summing to 0


def _contrast_covariance(sample_cov: np.ndarray, fs: float) -> tuple:
    """(exact, ours): the covariance of CONTRASTS of the means over WINDOWS of a sampled process
    with covariance `sample_cov` between samples, and from `mean_variogram` of a term."""
    rows = np.zeros((len(WINDOWS), len(sample_cov)))
    for i, (a, z) in enumerate(WINDOWS):
        rows[i, a:z] = 1.0 / (z - a)
    spans = np.array([[a / fs, z / fs] for a, z in WINDOWS])
    return CONTRASTS @ rows @ sample_cov @ rows.T @ CONTRASTS.T, spans


def test_window_means_of_a_walk_have_the_covariance_of_a_sampled_random_walk():
    fs = 100.0
    samples = np.arange(1264)
    walk = (np.minimum.outer(samples, samples) + 1) / fs  # unit steps of variance 1 / fs
    exact, spans = _contrast_covariance(walk, fs)
    ours = -CONTRASTS @ coloured.mean_variogram(spans, spans, "random_walk") @ CONTRASTS.T
    # a mean of N samples against the uniform mean over their span: about 1 / (6 N fs) s of
    # variance per window (the sums of i^2 against the integral of t^2)
    assert np.abs(ours - exact).max() < 1.0 / (2 * 64 * fs)
    equal = np.array([[0.0, 3.0]])
    assert coloured.mean_variogram(equal, equal, "random_walk")[0, 0] == pytest.approx(0.5)


def test_window_means_of_flicker_have_the_covariance_of_the_sampled_flicker():
    fs = 100.0
    k = 1264
    h = np.ones(k)  # Kasdin-Walter's filter (1 - z^-1)^(-1/2), station.sim.noise.flicker
    h[1:] = np.cumprod((np.arange(1, k) - 0.5) / np.arange(1, k))
    taps = np.zeros((k, k))  # flicker of unit B: sample i = sum_s h[i - s] w_s, w_s ~ N(0, 1)
    for i in range(k):
        taps[i, : i + 1] = h[i::-1]
    exact, spans = _contrast_covariance(taps @ taps.T, fs)
    ours = -CONTRASTS @ coloured.mean_variogram(spans, spans, "bias_instability") @ CONTRASTS.T
    # the sampled flicker's Allan variance is within 0.04 % of the continuous one from 64 samples
    # a window on (docs/noise.md); the filter starts 600 samples before the first window, and
    # its start-up (the taps decay as lag^-1/2) leaves about 1 %
    assert np.allclose(ours, exact, rtol=0.02, atol=0.02 * np.abs(exact).max()), (ours, exact)
    equal = np.array([[0.0, 4.0]])
    assert coloured.mean_variogram(equal, equal, "bias_instability")[0, 0] == pytest.approx(
        (np.log(4.0) - 1.5) / np.pi)  # E ln|U - V| of two uniforms on [0, L]: ln L - 3 / 2


def test_an_effect_free_walking_unit_has_white_gaps_with_the_walk_in_the_noise_model():
    m, seeds = 12, 8
    gaps, plain = [], []
    for seed in range(seeds):
        d, _ = bench.session("none_walk", m, 9100 + seed)
        walking = dataclasses.replace(d, random_walk=np.full(m, bench.WALK))
        gaps.append([gap.statistics(walking, model.nominal(walking))[s]
                     for s in ("static", "transients", "averaged", "trend", "harmonics")])
        plain.append(gap.statistics(d, model.nominal(d))["static"])
    # static (n - 1) m, transients 2 n m, M about n m, trend 2 n m, harmonics 12 n m
    dof = np.array([19 * m, 2 * 20 * m, 20 * m, 2 * 20 * m, 12 * 20 * m])
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
    """A calibration file of the unit's gyros holding noise figures with the walk `walk` (None:
    not resolved) and no flicker resolved."""
    white = np.full(sensors, np.radians(0.01))
    cal = make(a=np.eye(3)[:, :sensors] if sensors <= 3 else None).with_noise(NoiseFigures(
        white, white / 20, None, None, None if walk is None else np.full(sensors, walk),
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
    (None, 3, "hold(s) no bias random walk or bias instability"),
    (3e-5, 4, "the session has 3 sensor(s) in rad/s"),
])
def test_a_noise_file_that_cannot_give_the_walk_is_refused(tmp_path, capsys, walk, sensors,
                                                          said):
    session = _walking_session(tmp_path / "walk.npz", 3501)
    cal = _noise_file(tmp_path / "unit.cal.json", walk, sensors)
    code, out = _diagnose(capsys, session, "--noise", cal)
    assert code != 0 and said in out


spec_static = importlib.util.spec_from_file_location("bench_diagnose_static",
                                                     ROOT / "bench" / "diagnose_static.py")
bench_static = importlib.util.module_from_spec(spec_static)
spec_static.loader.exec_module(bench_static)
STATIC_WALKS = {"m/s^2": 1e-4, "rad/s": 3e-5}  # bench/diagnose_static.py's `none_walk`


def test_a_free_static_walking_unit_is_no_drift_with_its_walk_in_the_noise_model(tmp_path,
                                                                                  capsys):
    d, _ = bench_static.session("none_walk", 100)
    t = np.arange(len(d.x)) / d.fs
    for name, x in (("acc", d.x[:, :3]), ("gyr", d.x[:, 3:])):
        np.savetxt(tmp_path / f"{name}.txt", np.column_stack([t, x]), fmt="%.9g")
    h5 = import_text(tmp_path / "walk.h5", {"acc": tmp_path / "acc.txt",
                                            "gyr": tmp_path / "gyr.txt"},
                     {"acc": "m/s^2", "gyr": "rad/s"})
    code, out = _diagnose(capsys, h5, "--json")
    assert code == 0 and "bias_drift" in json.loads(out)["effects"]  # white noise: a drift
    files = []
    for unit, walk in STATIC_WALKS.items():
        white = np.full(3, 1e-3)
        cal = make(a=np.eye(3), units=(unit,) * 3).with_noise(NoiseFigures(
            white, white / 20, None, None, np.full(3, walk), np.full(3, walk / 10),
            rate_hz=100.0, seconds=5000.0))
        files.append(tmp_path / f"{unit.replace('/', '_')}.cal.json")
        cal.save(files[-1])
    code, out = _diagnose(capsys, h5, "--json", "--noise", *files)
    doc = json.loads(out)
    assert code == 0 and doc["effects"] == [] and doc["unexplained"] == []
    assert doc["noise_model"]["random_walk"] == pytest.approx([1e-4] * 3 + [3e-5] * 3)
    code, out = _diagnose(capsys, h5, "--noise", files[1], files[1])
    assert code != 0 and "again" in out
