"""Each named effect against its theoretical signature, on noise-free simulated rotary sessions."""

import numpy as np
import pytest

from station.model.earth import normal_gravity
from station.model.effects import parse, parse_all
from station.model.effects.earth_rate import EarthRate
from station.model.unit import SensorUnit
from station.reduce.eq18 import reduce_arrays
from station.sim.layouts import A_MODEL, perturbed
from station.sim.profile import RotaryTiming
from station.sim.rotary import random_orientations, simulate_rotary

LSB = 1e-6
TIMING = RotaryTiming(rate=np.pi / 2, max_accel=1.0, static=2.0, moving=14.0, settle=0.5)
N = 6


@pytest.fixture(scope="module")
def setup():
    rng = np.random.default_rng(11)
    return perturbed(A_MODEL, 0.01, rng), random_orientations(N, rng)


def run(setup, effects=(), seed=0, **unit_kw):
    """Noise-free session (quantised at 1e-6) with the given effect specs; (arrays, truth, unit)."""
    a, c = setup
    params = {"bias": 0.02, "counts_per_unit": 1 / LSB, "fs": 100.0}
    params.update(unit_kw)
    unit = SensorUnit(a, rng=seed, **params)
    sim = simulate_rotary(unit, c, TIMING, effects=parse_all(effects))
    return sim.arrays, sim.truth, unit


def si(arrays):
    return arrays["y"] * LSB


def test_no_effect_reduces_to_a_transpose_v(setup):
    arrays, truth, unit = run(setup)
    red = reduce_arrays(arrays)
    assert np.abs(red.M - unit.a.T @ np.array(truth["v"])).max() < 2 * LSB


def test_earth_rate_moves_static_means_by_the_projected_earth_rate(setup):
    a, c = setup
    p = EarthRate(latitude_deg=40.0, heading_deg=30.0, rate=0.01)
    base, _, _ = run(setup)
    arrays, _, _ = run(setup, ["earth_rate=latitude_deg=40,heading_deg=30,rate=0.01"])
    north, up = p.rate * np.cos(np.radians(40)), p.rate * np.sin(np.radians(40))
    per_position = TIMING.rate * (TIMING.moving - TIMING.ramp)  # trapezoid area, rad
    h = np.radians(30) - per_position * np.arange(N)  # table turns counter-clockwise
    earth_table = np.stack([north * np.cos(h), north * np.sin(h), np.full(N, up)], 1)
    earth_unit = np.einsum("nij,nj->ni", c, earth_table)  # (N, 3)
    s0, s1 = reduce_arrays(base), reduce_arrays(arrays)
    assert np.abs((s1.static_mean - s0.static_mean) - a.T @ earth_unit.T).max() < 3 * LSB
    # over whole turns only the vertical part survives: M loses the horizontal projection
    vertical = up * c[:, :, 2]
    assert np.abs((s1.rotating_mean - s0.rotating_mean) - a.T @ vertical.T).max() < 3e-5
    shift = np.linalg.lstsq(a.T, s1.M - s0.M, rcond=None)[0]  # (3, N) change of v_j
    along_axis = np.einsum("in,ni->n", shift, c[:, :, 2])
    assert np.abs(along_axis).max() < 3e-5  # |v_j| unchanged to first order
    assert np.allclose(np.linalg.norm(shift, axis=0), north, rtol=0.01)


def test_g_sensitivity_moves_every_window_by_a_transpose_g_f(setup):
    a, c = setup
    g_true = np.arange(9.0).reshape(3, 3) * 1e-4 - 4e-4
    spec = "g_sensitivity=matrix=" + ":".join(f"{x:g}" for x in g_true.ravel())
    base, _, _ = run(setup)
    arrays, _, _ = run(setup, [spec])
    f = normal_gravity(52.2) * c[:, :, 2]  # (N, 3) gravity up the table axis, unit frame
    s0, s1 = reduce_arrays(base), reduce_arrays(arrays)
    assert np.abs((s1.static_mean - s0.static_mean) - a.T @ g_true @ f.T).max() < 3 * LSB
    assert np.abs(s1.M - s0.M).max() < 3 * LSB  # a bias per position: M is unchanged


def test_rate_error_scales_the_readings(setup):
    base, _, _ = run(setup)
    arrays, truth, _ = run(setup, ["rate_error=scale=0.02,spread=0.005"])
    factors = np.array(truth["rate_factors"])
    assert 0.001 < np.std(factors) < 0.01 and abs(np.mean(factors) - 1.02) < 0.01
    m0, m1 = reduce_arrays(base).M, reduce_arrays(arrays).M
    assert np.allclose(m1, m0 * factors, atol=2e-4)  # cut by the reported angle: tiny leftover
    assert np.allclose(np.linalg.norm(m1, axis=0) / np.linalg.norm(m0, axis=0), factors, rtol=1e-4)


def test_rate_error_with_an_encoder_shows_in_the_recorded_angle(setup):
    from station.diagnose.data import from_arrays

    echo, _, _ = run(setup, ["rate_error=scale=0.02,spread=0.005"])
    arrays, truth, _ = run(setup, ["rate_error=scale=0.02,spread=0.005,encoder=1"])
    # the command's angle: 1 to rounding, well inside the diagnosis' ENCODER_TOL
    assert np.abs(from_arrays(echo).rate_factors - 1).max() < 1e-12
    # the angle's slope over whole turns is the true rate: factors to rounding
    assert np.allclose(from_arrays(arrays).rate_factors, truth["rate_factors"], rtol=1e-12)
    assert truth["effects"]["rate_error"]["encoder"] is True


def test_axis_wobble_adds_a_tone_and_changes_the_mean_at_second_order(setup):
    a, c = setup
    beta = np.radians(2.0)
    base, _, _ = run(setup)
    arrays, _, _ = run(setup, ["axis_wobble=angle_deg=2"])
    m0, m1 = reduce_arrays(base).M, reduce_arrays(arrays).M
    assert np.abs(m1 - np.cos(beta) * m0).max() < 2e-5
    assert np.abs(m1 - m0).max() > 10 * 2e-5  # the second-order change is visible
    i0, i1 = arrays["seg_rotating"]
    theta = arrays["angle"][0, i0:i1]
    revs = (theta[-1] - theta[0]) // (2 * np.pi)
    stop = np.searchsorted(theta - theta[0], 2 * np.pi * revs)
    x = si(arrays)[:, i0 : i0 + stop] - si(arrays)[:, i0 : i0 + stop].mean(1, keepdims=True)
    th = theta[:stop]
    amp = (
        2
        * np.hypot(np.einsum("nkm,k->nm", x, np.cos(th)), np.einsum("nkm,k->nm", x, np.sin(th)))
        / stop
    )
    pq = np.einsum("dm,ndj->nmj", a, c[:, :, :2])  # a_i . p, a_i . q per position
    expected = TIMING.rate * np.sin(beta) * np.linalg.norm(pq, axis=2)
    assert np.allclose(amp, expected, rtol=1e-3, atol=1e-5)


def test_latency_shows_antisymmetric_residuals_on_spin_up_and_down(setup):
    a, c = setup
    delay = np.arange(12) * 1e-3
    base, _, _ = run(setup)
    arrays, _, _ = run(setup, ["latency=delay=" + ":".join(map(str, delay))])
    res = si(arrays) - si(base)
    lag = 2 + int(np.ceil(delay.max() * 100))  # samples touched by the corner of the ramp
    expected = TIMING.max_accel * delay * (c[:, :, 2] @ a)  # alpha * delay_i * (a_i . u_j)
    for name, sign in (("seg_spinup", -1), ("seg_spindown", +1)):
        i0, i1 = arrays[name]
        window = res[:, i0 + lag : i1 - 2]
        assert np.abs(window - sign * expected[:, None, :]).max() < 3 * LSB
    for name in ("seg_static", "seg_rotating"):
        i0, i1 = arrays[name]
        assert np.abs(res[:, i0 + lag : i1]).max() < 2 * LSB


def test_saturation_piles_samples_on_the_rail(setup):
    free = run(setup, output_range=1.0, noise_density=1e-3)[0]["y"]
    y = run(setup, ["saturation"], output_range=1.0, noise_density=1e-3)[0]["y"]
    rail = round(1.0 / LSB)
    assert y.max() == rail and y.min() == -rail
    at_rail = np.sum(np.abs(y) == rail)
    near = np.sum((np.abs(y) < rail) & (np.abs(y) >= rail - 100))  # the 100 counts below
    assert at_rail == np.sum(np.abs(free) >= rail)  # every sample beyond the range is on the rail
    assert at_rail > 100 * max(near, 1)


def test_scale_nonlinearity_adds_the_quadratic_term(setup):
    a, _ = setup
    base, truth, _ = run(setup)
    arrays, _, _ = run(setup, ["scale_nonlinearity=k2=0.01"])
    s = a.T @ np.array(truth["v"])
    red0, red1 = reduce_arrays(base), reduce_arrays(arrays)
    assert np.abs((red1.M - red0.M) - 0.01 * s**2).max() < 3 * LSB
    assert np.abs(red1.static_mean - red0.static_mean).max() < 2 * LSB


def test_bias_drift_warm_up_follows_the_exponential(setup):
    base, _, _ = run(setup)
    arrays, _, _ = run(setup, ["bias_drift=warmup=0.05,warmup_tau=100"])
    i0, i1 = arrays["seg_static"]
    t1, t2 = arrays["t0"] + i0 / 100, arrays["t0"] + i1 / 100  # samples at t0 + i / fs
    shift = (reduce_arrays(arrays).static_mean - reduce_arrays(base).static_mean)[0]
    t = arrays["t0"][:, None] + np.arange(i0, i1) / 100
    assert np.allclose(shift, 0.05 * np.exp(-t / 100).mean(1), atol=2 * LSB)
    expected_continuous = 0.05 * 100 / (t2 - t1) * (np.exp(-t1 / 100) - np.exp(-t2 / 100))
    assert np.allclose(shift, expected_continuous, rtol=0.01)


def test_bias_drift_heating_rises_while_spinning_and_cools_at_rest(setup):
    base, _, _ = run(setup)
    arrays, _, _ = run(setup, ["bias_drift=heating=0.01,heating_tau=1"])
    d = si(arrays) - si(base)
    i0, i1 = arrays["seg_static"]
    assert np.abs(d[0, i0:i1]).max() < 2 * LSB  # nothing has spun yet
    r1 = arrays["seg_rotating"][1]
    assert np.allclose(d[:, r1 - 1], 0.01 * TIMING.rate, atol=0.01 * TIMING.rate * 1e-3)
    assert np.abs(d[1:, i0:i1]).max() < 0.01 * TIMING.rate * np.exp(-20)  # 30 s gap cooled it


def test_effects_compose_and_are_deterministic_from_the_seed(setup):
    specs = [
        "bias_drift=warmup=0.01",
        "scale_nonlinearity=k2=0.001",
        "rate_error=spread=0.001",
        "earth_rate",
        "axis_wobble=angle_deg=0.5,freq=0.3",
        "latency=delay=0.002",
        "saturation",
    ]
    one = run(setup, specs, seed=5, noise_density=1e-3, output_range=30.0)[0]["y"]
    two = run(setup, specs, seed=5, noise_density=1e-3, output_range=30.0)[0]["y"]
    other = run(setup, specs, seed=6, noise_density=1e-3, output_range=30.0)[0]["y"]
    assert np.array_equal(one, two) and not np.array_equal(one, other)


@pytest.mark.parametrize(
    "spec, message",
    [
        ("wobble", "unknown effect"),
        ("latency=lag=1", "bad parameter"),
        ("latency=delay=x", "not a number"),
        ("bias_drift=warmup_tau=0", "must be positive"),
        ("g_sensitivity=matrix=1:2", "give 9"),
    ],
)
def test_bad_effect_specs_are_refused_with_advice(spec, message):
    with pytest.raises(ValueError, match=message):
        parse(spec)


def test_none_is_no_effect_and_an_effect_given_twice_is_refused():
    assert parse_all(["none"]) == {}
    with pytest.raises(ValueError, match="given twice"):
        parse_all(["latency=delay=0.2", "latency=delay=0.1"])


@pytest.mark.parametrize("spec", ["latency", "bias_drift", "bias_drift=warmup_tau=10",
                                  "rate_error=encoder=1", "axis_wobble", "scale_nonlinearity",
                                  "g_sensitivity"])
def test_an_effect_of_size_zero_is_refused_naming_its_size(spec):
    with pytest.raises(ValueError, match="changes nothing; give its size, e.g. --effect"):
        parse(spec)
    assert parse("earth_rate")[1] is not None and parse("saturation")[1] is not None
