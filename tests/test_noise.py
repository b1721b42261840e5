"""Noise characterisation (issue 19): the Allan variance of simulated streams against the IEEE 952
theory, the fit of N, B, K and the honesty of its sigmas, terms the data cannot resolve, pooling
of static windows, and `station noise` on sessions recorded by the simulator."""

import json
import math

import allantools
import numpy as np
import pytest

from drivers.samples import SampleBlock
from station.calfiles.calfile import NoiseFigures
from station.cli import main
from station.errors import CalibrationInputError
from station.reduce.noise import session_noise
from station.session import Session, SessionWriter, StreamSpec
from station.sim.noise import simulated_noise
from station.solve import noise
from station.solve.allan_covariance import correlation, stretch_covariance, transfer
from station.solve.noise import allan_curve, design, fit_noise, pooled

RATE = 100.0
LN2 = math.log(2.0)


def curve_of(y, rate=RATE):
    return allan_curve(np.asarray(y)[:, None], rate)


def test_simulated_terms_have_the_allan_variance_ieee_952_gives():
    """White N: N^2 / tau; Kasdin-Walter flicker of B: 2 ln 2 h_-1 with h_-1 = B^2 / pi (NIST
    SP 1065 Table 5), i.e. (2 ln 2 / pi) B^2; random walk K: K^2 tau / 3. Mean over 4 seeds at
    taus of >= 500 terms: relative error sd <= sqrt(2 / edf) / 2 < 0.05, so 0.15 is 3 sd."""
    k = 2**17
    for term, kw in enumerate(({"white": 1e-3}, {"bias_instability": 1e-3},
                               {"random_walk": 1e-4})):
        avar = np.mean([curve_of(simulated_noise(k, RATE, rng=np.random.default_rng(s), **kw))
                        .avar[:, 0] for s in range(4)], axis=0)
        c = curve_of(np.zeros(k) + np.arange(k) % 2)  # the same taus
        theory = design(c.m, RATE)[:, term] * next(iter(kw.values())) ** 2
        mid = (c.m >= 16) & (c.terms >= 500 * c.m)
        assert mid.sum() >= 2
        np.testing.assert_allclose(avar[mid], theory[mid], rtol=0.15)
    flicker = curve_of(simulated_noise(k, RATE, bias_instability=1.0,
                                       rng=np.random.default_rng(9)))
    floor = np.sqrt(flicker.avar[(flicker.m >= 16) & (flicker.m <= 1024), 0])
    assert np.all(np.abs(floor / math.sqrt(2 * LN2 / math.pi) - 1) < 0.15)


def test_the_fit_finds_known_n_b_k_within_its_band():
    """2.9 h at 100 Hz of N = B = 2e-4, K = 2e-5 (each dominating 1-2 decades of tau): every term
    resolved and within 3 of its sigmas of the truth (fixed seed), the sigmas small enough to
    mean something (N to 1 %, B to 10 %, K to 50 %)."""
    true = np.array([2e-4, 2e-4, 2e-5])
    y = simulated_noise(2**20, RATE, white=true[0], bias_instability=true[1],
                        random_walk=true[2], rng=np.random.default_rng(3))
    fit = fit_noise(curve_of(y))
    assert fit.resolved.all()
    assert np.all(np.abs(fit.value[:, 0] - true) <= 3 * fit.sigma[:, 0]), (fit.value, fit.sigma)
    assert np.all(fit.sigma[:, 0] / true < [0.01, 0.1, 0.5])


def test_white_noise_sigma_is_honest_over_seeds():
    """40 white-noise streams of 2^14 samples: the z-scores (N_fit - N) / sigma have sample
    standard deviation 1 within 3 of its standard errors (1 / sqrt(2 x 39) = 0.11) and mean 0
    within 3 / sqrt(40)."""
    z = []
    for seed in range(40):
        y = simulated_noise(2**14, RATE, white=1e-3, rng=np.random.default_rng(seed))
        fit = fit_noise(curve_of(y))
        z.append((fit.value[0, 0] - 1e-3) / fit.sigma[0, 0])
    assert abs(np.std(z, ddof=1) - 1) < 3 / math.sqrt(78), np.std(z, ddof=1)
    assert abs(np.mean(z)) < 3 / math.sqrt(40)


@pytest.mark.parametrize("true", [(2e-4, 2e-4, 0.0), (1e-3, 0.0, 8e-4)])
def test_the_sigmas_of_two_terms_are_honest_over_seeds(true):
    """300 streams of 2^15 samples (328 s) of white noise with flicker (B dominates above 2.3
    s), or with a random walk (above 2.2 s): for each of the two terms, resolved in at least
    99 % of the seeds, the z-scores (fit - true) / sigma have standard deviation 1 within 3 of
    its standard errors (1 / sqrt(2 x 299) = 0.041) and mean 0 within 3 / sqrt(300); the +-2
    sigma band holds the truth in 95.4 % of the seeds within 3 binomial standard errors
    (sqrt(0.954 x 0.046 / 300) = 0.012). On these seeds the old likelihood (independent
    estimates) gave the random walk a spread of 1.27 and 87 % coverage, and its measured
    widening factors gave N and B of the first mix spreads of 0.87 and 0.88: both fail here."""
    true = np.array(true)
    seeds, terms = 300, np.flatnonzero(true)
    z = np.array([(fit.value[:, 0] - true) / fit.sigma[:, 0] for fit in (
        fit_noise(curve_of(simulated_noise(2**15, RATE, white=true[0], bias_instability=true[1],
                                           random_walk=true[2],
                                           rng=np.random.default_rng(100 + s))))
        for s in range(seeds))])[:, terms]
    assert np.isfinite(z).mean(axis=0).min() >= 0.99
    spread, mean = np.nanstd(z, axis=0, ddof=1), np.nanmean(z, axis=0)
    assert np.all(np.abs(spread - 1) < 3 / math.sqrt(2 * (seeds - 1))), spread
    assert np.all(np.abs(mean) < 3 / math.sqrt(seeds)), mean
    inside = (np.abs(z) <= 2).mean(axis=0)
    assert np.all(np.abs(inside - 0.954) < 3 * math.sqrt(0.954 * 0.046 / seeds)), inside


def test_a_short_stream_leaves_bias_instability_and_random_walk_unresolved():
    """20 s of white noise with a random walk far below it: N is fitted, B and K are reported
    not resolved (NaN here, None in the calibration file), never as a number."""
    y = simulated_noise(2000, RATE, white=1e-3, random_walk=1e-6, rng=np.random.default_rng(1))
    fit = fit_noise(curve_of(y))
    assert fit.resolved.tolist() == [[True], [False], [False]]
    assert np.isnan(fit.value[1:]).all() and np.isnan(fit.sigma[1:]).all()
    assert abs(fit.value[0, 0] - 1e-3) < 3 * fit.sigma[0, 0]
    figures = NoiseFigures.from_fit(fit, RATE, 20.0)
    assert figures.bias_instability is None and figures.random_walk_sigma is None
    assert figures.white.tolist() == fit.value[0].tolist()


def test_counts_with_their_scale_give_the_si_curve():
    rng = np.random.default_rng(2)
    counts = rng.integers(-500, 500, (4000, 2)).astype(np.int32)
    scale = np.array([1e3, 16.0])
    direct = allan_curve(counts / scale, RATE)
    assert np.allclose(allan_curve(counts, RATE, scale).avar, direct.avar, rtol=1e-12)


def test_the_allan_variance_is_allantools_oadev_channel_by_channel(monkeypatch):
    """Every channel of a stretch (raw counts with their scales, a slow drift in one) against
    allantools.oadev of that channel alone, at every averaging factor; also when the stretch is
    converted to floats a few channels at a time (BLOCK smaller than the stretch)."""
    rng = np.random.default_rng(7)
    k = 5000
    counts = rng.integers(-2000, 2000, (k, 5)) + np.arange(k)[:, None] * [0, 0, 3, 0, 0]
    scale = np.array([1e3, 16.0, 2.5, 1.0, 7e4])
    whole = allan_curve(counts, RATE, scale)
    monkeypatch.setattr(noise, "BLOCK", 2 * k)
    np.testing.assert_allclose(allan_curve(counts, RATE, scale).avar, whole.avar, rtol=1e-12)
    for c in range(5):
        y = counts[:, c] / scale[c]
        _, dev, _, _ = allantools.oadev(y - y.mean(), rate=RATE, data_type="freq",
                                        taus=whole.m / RATE)
        np.testing.assert_allclose(whole.avar[:, c], dev ** 2, rtol=1e-9)


def test_pooling_weights_each_window_by_its_terms():
    """A window pooled with itself is itself; a short window adds to the short taus only, in
    proportion to its terms (k - 2m + 1)."""
    rng = np.random.default_rng(4)
    long, short = curve_of(rng.normal(size=4000)), curve_of(rng.normal(size=300))
    same = pooled([long, long])
    np.testing.assert_allclose(same.avar, long.avar, rtol=1e-14)
    assert same.terms.tolist() == (2 * long.terms).tolist() and same.seconds == 80.0
    both = pooled([long, short])
    t = len(short.m)
    w_long, w_short = long.terms[:t], short.terms
    np.testing.assert_allclose(both.avar[:t, 0], (w_long * long.avar[:t, 0] + w_short
                                                   * short.avar[:, 0]) / (w_long + w_short))
    np.testing.assert_array_equal(both.avar[t:], long.avar[t:])


@pytest.mark.parametrize("stretch, problem", [
    (np.zeros((10, 3)), "too short"),
    (np.full((500, 1), np.nan), "not finite"),
    (np.zeros(500), "too short"),  # one-dimensional: not (samples, channels)
])
def test_bad_stretches_are_refused(stretch, problem):
    with pytest.raises(CalibrationInputError, match=problem):
        allan_curve(stretch, RATE)


def test_nothing_to_pool_is_refused():
    with pytest.raises(CalibrationInputError, match="no static stretch"):
        pooled([])


# ------------------------------------------------------------------------------ sessions


def rest_session(path, seconds: float, noise: float = 1e-3, rate: float = RATE) -> float:
    """A session without protocol events (an import's shape): one gyro triad at rest for
    `seconds`, white noise of density `noise` rad/s sqrt(s), in counts of 1e-6 rad/s."""
    k = round(seconds * rate)
    spec = StreamSpec(("gx", "gy", "gz"), "rad/s", 1e6, rate)
    rng = np.random.default_rng(7)
    y = np.column_stack([simulated_noise(k, rate, white=noise, rng=rng) for _ in range(3)])
    with SessionWriter.create(path, {"protocol": "import", "unit_serial": "R1"},
                              {"gyro": spec}) as w:
        seq = np.arange(k)
        w.append("gyro", SampleBlock(np.round(y * 1e6).astype(np.int64), seq,
                                     seq / rate, seq / rate))
    return noise


def test_a_long_rest_without_events_is_found_and_measured(tmp_path):
    path = tmp_path / "rest.h5"
    true = rest_session(path, 120.0)
    with Session.open(path) as s:
        found = session_noise(s, "gyro")
    assert found.source.startswith("still intervals detected")
    assert found.curve.seconds > 100
    n, sigma = found.fit.value[0], found.fit.sigma[0]
    assert np.all(np.abs(n - true) < 3 * sigma) and np.all(sigma / true < 0.05)


def white_density(truth: dict, path) -> np.ndarray:
    """The white-noise density the simulated session's readings carry: the sensor's
    (noise_density) and the quantisation's, a uniform error of one count (lsb^2 / 12 a sample,
    Widrow), added in variance."""
    with Session.open(path) as s:
        spec = s.specs["imu"]
    lsb = 1.0 / np.asarray(spec.counts_per_unit)
    return np.sqrt(np.asarray(truth["noise_density"]) ** 2 + lsb**2 / (12 * spec.rate_hz))


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """A 6-position rotary session of the simulator's 12-gyro unit (`station simulate`, imported
    with `station import npz`) and its truth."""
    where = tmp_path_factory.mktemp("sim")
    assert main(["simulate", "--out", str(where / "x.npz"), "--positions", "6", "--seed",
                 "4"]) == 0
    assert main(["import", "npz", str(where / "x.h5"), str(where / "x.npz"), "--unit-serial",
                 "SN7"]) == 0
    return where / "x.h5", json.loads((where / "x.truth.json").read_text())


def test_station_noise_on_a_simulated_session(simulated, tmp_path, capsys):
    """The simulated white-noise density (`white_density`) within 3 sigma for each gyro; B and K
    not resolved in 10 s static windows; the plot is a PNG."""
    path, truth = simulated
    plot = tmp_path / "allan.png"
    assert main(["noise", str(path), "--json", "--plot", str(plot)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["windows"] == 6 and out["source"] == "static windows of the protocol"
    assert len(out["channels"]) == 12
    for channel, density in zip(out["channels"], white_density(truth, path), strict=True):
        white = channel["white"]
        assert abs(white["value"] - density) < 3 * white["sigma"], (channel, density)
        assert white["unit"] == "rad/s sqrt(s)"
        assert channel["random_walk"]["value"] is None
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["noise", str(path)]) == 0
    text = capsys.readouterr().out
    assert "not resolved" in text and "g12" in text


def test_station_solve_stores_the_noise_figures(simulated, tmp_path):
    from station.calfiles.calfile import load

    path, truth = simulated
    out = tmp_path / "x.cal.json"
    assert main(["solve", str(path), "--out", str(out)]) == 0
    cal = load(out)
    assert cal.noise is not None and cal.noise.rate_hz == 200.0
    assert np.all(np.abs(cal.noise.white - white_density(truth, path))
                  < 3 * cal.noise.white_sigma)
    assert cal.noise.random_walk is None and cal.noise.bias_instability is None


@pytest.mark.parametrize("args, problem", [
    (["--stream", "gyro"], "no stream 'gyro'"),
    (["--plot", "allan.pdf"], "must name a .png"),
])
def test_station_noise_refuses_bad_input(simulated, args, problem, capsys):
    path, _ = simulated
    assert main(["noise", str(path), *args]) == 2
    assert problem in capsys.readouterr().err


def test_station_noise_says_when_there_is_too_little_static_data(tmp_path, capsys):
    path = tmp_path / "short.h5"
    rest_session(path, 0.5)
    assert main(["noise", str(path), "--stream", "gyro"]) == 2
    err = capsys.readouterr().err
    assert "too little static data" in err and "long rest" in err


def test_the_report_shows_the_allan_deviation(simulated, tmp_path):
    from station.report import session as report

    path, _ = simulated
    built = report.build(path)
    assert "allan-imu" in [p.name for p in built.plots]
    assert built.summary["noise"]["imu"]["windows"] == 6
    assert "white noise N" in built.html()


def test_a_channel_that_does_not_vary_is_refused():
    y = np.column_stack([np.random.default_rng(0).normal(size=1000), np.full(1000, 7.0)])
    with pytest.raises(CalibrationInputError, match="channel\\(s\\) 2 do not vary"):
        fit_noise(allan_curve(y, RATE))



# ------------------------------------------------------- covariance across taus (theory)


def allan_filter(m: int) -> np.ndarray:
    """The 2m taps of u_t = (ybar_{t+m} - ybar_t) / sqrt(2) (station.solve.allan_covariance)."""
    return np.r_[-np.ones(m), np.ones(m)] / (m * math.sqrt(2.0))


@pytest.mark.parametrize("m", [4, 16, 64])
def test_the_transfer_function_is_the_filter_allantools_applies(m):
    """|H_m(nu)|^2 is |DFT of the 2m taps|^2 (exact), and allantools' overlapping Allan variance
    of a unit cosine of period P samples is |H_m(1/P)|^2 / 2 (its power 1/2 through the filter)
    when the M = k - 2m + 1 terms span whole periods (the mean of cos^2 is then exactly 1/2)."""
    nu = np.linspace(0.001, 0.5, 997)
    dft = np.abs(np.exp(-2j * np.pi * np.outer(nu, np.arange(2 * m))) @ allan_filter(m)) ** 2
    np.testing.assert_allclose(transfer(nu, m), dft, rtol=1e-9, atol=1e-14)
    for period in (3 * m, 10 * m + 1):
        k = 50 * period + 2 * m - 1
        y = np.cos(2 * np.pi * np.arange(k) / period + 0.3)
        _, dev, _, _ = allantools.oadev(y, rate=1.0, data_type="freq", taus=[m])
        assert dev[0] ** 2 == pytest.approx(transfer(1 / period, m) / 2, rel=1e-9)


def test_the_covariance_of_white_noise_is_the_chi2_variance_and_parseval():
    """White noise of density 1 at rate 1: the diagonal is 2 AVAR^2 / edf with AVAR = 1 / m and
    edf = 3 M / (2 m) x 4 m^2 / (4 m^2 + 5), the large-N limit of the overlapping white-FM edf
    (NIST SP 1065 Table 12; the limit is what the large-M covariance is); off the diagonal,
    2 / max(M_i, M_j) times the sum over lags of the squared cross-covariance of the two filters
    (Parseval, computed here in the time domain). The quadrature's error is far below 1e-6."""
    k = 2**14
    m = np.array([4, 16, 64, 256])
    terms = k - 2 * m + 1
    cov = stretch_covariance(m, k, [1.0, 0.0, 0.0], 1.0)
    nu = 3 * terms / (2 * m) * 4 * m**2 / (4 * m**2 + 5)
    np.testing.assert_allclose(np.diag(cov), 2 / m**2 / nu, rtol=1e-6)
    for i, j in ((0, 1), (1, 2), (0, 2), (2, 3)):
        r = np.correlate(allan_filter(m[j]), allan_filter(m[i]), "full")
        assert cov[i, j] == pytest.approx(2 * np.sum(r**2) / max(terms[i], terms[j]), rel=1e-6)
        assert cov[j, i] == cov[i, j]


@pytest.mark.parametrize("kind, theta", [("white", [1.0, 0.0, 0.0]),
                                         ("flicker", [0.0, 1.0, 0.0]),
                                         ("random walk", [0.0, 0.0, 1e-4])])
def test_neighbouring_estimates_correlate_as_the_model_says(kind, theta):
    """3000 seeded streams of 4096 samples (white, flicker, random walk): the sample correlation
    of the estimates at m = 4 and 16 (and 16 and 64) is the model's within 3 standard errors of
    Fisher's z (1 / sqrt(2997) = 0.018), and at least 6 of them from 0, what independent
    estimates (the old likelihood's assumption) would give. The large-M form errs by O(m / M)
    < 2 % of the correlation, inside."""
    k, seeds = 4096, 3000
    n, b, w = np.sqrt(theta)
    avar = np.array([curve_of(simulated_noise(k, 1.0, white=n, bias_instability=b, random_walk=w,
                                              rng=np.random.default_rng(s)), 1.0).avar[:3, 0]
                     for s in range(seeds)])
    model = correlation(stretch_covariance([4, 16, 64], k, theta, 1.0))
    for i, j in ((0, 1), (1, 2)):
        r = np.corrcoef(avar[:, i], avar[:, j])[0, 1]
        assert abs(math.atanh(r) - math.atanh(model[i, j])) < 3 / math.sqrt(seeds - 3), \
            (kind, i, j, r, model[i, j])
        assert model[i, j] > 6 / math.sqrt(seeds - 3)  # distinguishable from independence
