"""Eq. (18) reduction: windows, whole-revolution cut, noise level, and the end-to-end efficiency."""

import numpy as np
import pytest

import station
from station.errors import CalibrationInputError
from station.model.unit import SensorUnit
from station.reduce.eq18 import reduce_arrays, reduce_rotary, whole_revolutions
from station.sim.layouts import A_MODEL, perturbed
from station.sim.rotary import simulate_rotary


def test_rotating_minus_static_mean_in_si_units():
    y = np.zeros((2, 10, 3), int)
    y[:, :4] = [10, 20, 30]
    y[:, 4:] = [[[15, 20, 40]], [[5, 25, 30]]]
    red = reduce_rotary(y, [0.1, 0.2, 0.5], {"static": [0, 4], "rotating": [4, 10]})
    assert np.allclose(red.M, [[0.5, -0.5], [0.0, 1.0], [5.0, 0.0]])
    assert np.allclose(red.sigma, 0.0) and list(red.n_static) == [4, 4]


def test_whole_revolution_cut_removes_a_once_per_turn_signal():
    fs, rate = 100.0, 2.0
    t = np.arange(2000) / fs
    angle = rate * t
    y = (1.0 + 0.3 * np.cos(angle + 0.4))[None, :, None]
    segments = {"static": [0, 10], "rotating": [10, 2000]}
    y_static = y.copy()
    y_static[:, :10] = 0.0
    cut = reduce_rotary(y_static, 1.0, segments, angle=angle)
    uncut = reduce_rotary(y_static, 1.0, segments)
    assert cut.revolutions[0] == int(rate * 19.9 // (2 * np.pi))
    assert abs(cut.M[0, 0] - 1.0) < 0.3 * rate / fs  # one sample's worth of the tone at most
    assert abs(uncut.M[0, 0] - 1.0) > 10 * abs(cut.M[0, 0] - 1.0)


def test_whole_revolutions_picks_the_closest_length():
    angle = np.arange(1000) * 0.01  # 0.01 rad per sample: one turn = 628.3 samples
    stop, turns = whole_revolutions(angle, 0, 1000)
    assert turns == 1 and stop == 628


def test_bad_windows_and_short_rotation_are_refused_with_advice():
    y = np.zeros((2, 100, 3))
    with pytest.raises(CalibrationInputError, match="outside"):
        reduce_rotary(y, 1.0, {"static": [0, 10], "rotating": [50, 101]})
    with pytest.raises(CalibrationInputError, match="integer"):
        reduce_rotary(y, 1.0, {"static": [0.0, 10.0], "rotating": [50, 100]})
    with pytest.raises(CalibrationInputError, match="full revolution"):
        reduce_rotary(
            y, 1.0, {"static": [0, 10], "rotating": [50, 100]}, angle=np.arange(100) * 0.01
        )
    with pytest.raises(CalibrationInputError, match="positions, samples, sensors"):
        reduce_rotary(np.zeros((100, 3)), 1.0, {"static": [0, 10], "rotating": [50, 100]})


def test_window_scatter_matches_the_unit_noise():
    rng = np.random.default_rng(2)
    unit = SensorUnit(
        perturbed(A_MODEL, 0.01, rng),
        noise_density=0.002,
        counts_per_unit=2000.0,
        fs=200.0,
        rng=rng,
    )
    red = reduce_arrays(simulate_rotary(unit, 8).arrays)
    sd = np.sqrt(unit.sigma**2 + unit.lsb**2 / 12)[:, None]  # per sample, with quantisation
    assert np.allclose(red.static_sd, sd, rtol=5 * np.sqrt(0.5 / 2000))
    expected = sd * np.sqrt(1 / red.n_static + 1 / red.n_rotating)
    assert np.allclose(red.sigma, expected, rtol=5 * np.sqrt(0.5 / 2000))


def test_reduced_20_position_12_gyro_sessions_reach_the_cramer_rao_bound():
    """mean(eps^2 / trace(CRLB)) over 200 seeds lies in [0.9, 1.1] (acceptance of issue 3).

    Each seed: a = a_model + N(0, 0.01^2), 20 random positions, 10 s static + 25 s moving at
    200 Hz; the readings' noise per entry is sigma_j = sqrt(s^2 + lsb^2/12) sqrt(1/N_s + 1/N_r)
    with s = noise density * sqrt(fs), from the theory of the unit, not from the data.
    """
    ratios = []
    for seed in range(200):
        rng = np.random.default_rng(seed)
        a = perturbed(A_MODEL, 0.01, rng)
        unit = SensorUnit(
            a,
            bias=0.01 * rng.standard_normal(12),
            noise_density=0.005,
            counts_per_unit=1000.0,
            fs=200.0,
            rng=rng,
        )
        sim = simulate_rotary(unit, 20)
        red = reduce_arrays(sim.arrays)
        sigma = np.sqrt(
            (unit.sigma[0] ** 2 + unit.lsb[0] ** 2 / 12)
            * (1 / red.n_static[0] + 1 / red.n_rotating[0])
        )
        result = station.calibrate(red.M, magnitude=float(sim.arrays["c_cmd"]), d=3, sigma=sigma)
        bound = np.trace(station.crlb(a, sim.truth["v"], sigma))
        ratios.append(station.eps(a, result.a) ** 2 / bound)
    assert 0.9 <= np.mean(ratios) <= 1.1, f"mean eps^2 / trace(CRLB) = {np.mean(ratios):.3f}"
