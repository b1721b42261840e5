"""The temperature model: the thermal fit's tempcos and their sigmas, the order selection, the
model applied between the soaks, and the fit's refusals (docs/solvers.md, "Temperature")."""

import dataclasses

import numpy as np
import pytest
from scipy.stats import binom, kstest, norm
from scipy.stats import t as t_dist
from thermalsim import (
    BETWEEN,
    GYRO_TRUTH,
    SOAKS,
    TRUE_LINEAR,
    TRUE_QUADRATIC,
    G,
    direct_calibration,
    magnitude_errors,
    probe,
    rotary_fit,
    thermal_fit,
    z_scores,
)

from station.calfiles.calfile import Calibration, loads
from station.errors import CalibrationInputError, InputError
from station.model.effects.temperature import Temperature
from station.model.temperature import Soak
from station.reduce.still import StillReadings
from station.reduce.stillness import detect_still
from station.sim.layouts import accelerometer_triad
from station.sim.profile import RotaryTiming
from station.sim.static import simulate_static
from station.sim.thermal import simulate_soaks, soak_recordings, unit_at
from station.solve.temperature import FALSE_ALARM, fit_temperature, still_soak

ALPHA = 0.01
"""False-alarm probability of each statistical check below."""


def spread_bounds(n: int) -> tuple:
    """Two-sided ALPHA bounds of the sample standard deviation of n N(0, 1) values (its standard
    error is 1 / sqrt(2 n) for large n)."""
    half = norm.isf(ALPHA / 2) / np.sqrt(2 * n)
    return 1 - half, 1 + half


def test_tempcos_are_recovered_within_their_sigmas_over_50_seeds():
    z = np.ravel([z_scores(thermal_fit(seed, orders={"bias": 1, "scale": 1})[1], TRUE_LINEAR)
                  for seed in range(50)])
    low, high = spread_bounds(z.size)
    bonferroni = norm.isf(ALPHA / (2 * z.size))  # all |z| below it with probability 1 - ALPHA
    print(f"z spread {z.std():.3f} (bounds {low:.3f} .. {high:.3f}), mean {z.mean():.3f}, "
          f"max |z| {np.abs(z).max():.2f} (bound {bonferroni:.2f})")
    assert low < z.std() < high
    assert np.abs(z).max() < bonferroni
    assert abs(z.mean()) < norm.isf(ALPHA / 2) / np.sqrt(z.size / 6)  # 6 correlated per seed


@pytest.mark.parametrize("truth, expected", [(TRUE_LINEAR, {"bias": 1, "scale": 1}),
                                             (TRUE_QUADRATIC, {"bias": 2, "scale": 2})])
def test_the_order_is_chosen_by_the_evidence(truth, expected):
    seeds = 30
    right = sum(thermal_fit(1000 + seed, truth)[1].model.orders == expected
                for seed in range(seeds))
    # a linear truth is over-fitted with probability <= FALSE_ALARM (one step beyond it; the
    # quadratic's size is far above its noise): at most `allowed` misses but with prob. ALPHA
    allowed = int(binom.isf(ALPHA, seeds, FALSE_ALARM))
    print(f"{truth.bias2 and 'quadratic' or 'linear'}: {right}/{seeds} right "
          f"({right / seeds:.0%}), misses allowed {allowed}")
    assert seeds - right <= allowed


def test_applied_between_the_soaks_it_is_as_good_as_a_calibration_made_there():
    model_errors, direct_errors = [], []
    for seed in range(8):
        unit, fit = thermal_fit(seed)
        cal = loads(Calibration.from_temperature_fit(fit, "SN1", ("ax", "ay", "az"), "m/s^2")
                    .dumps())  # through the file
        assert cal.fit["temperature"]["soaks_K"] == list(SOAKS)
        assert [step["accepted"] for step in cal.fit["temperature"]["selection"]][:2] == \
            [True, True]  # the tempcos, far above the noise, found
        rng = np.random.default_rng(100 + seed)
        for temp in BETWEEN:
            z, _ = probe(unit, temp, TRUE_LINEAR, rng)
            model_errors.append(magnitude_errors(cal.apply_at(z, temp)))
            direct_errors.append(magnitude_errors(direct_calibration(unit, temp, TRUE_LINEAR)
                                                  .apply(z)))
    ratio = np.sqrt(np.mean(np.square(model_errors)) / np.mean(np.square(direct_errors)))
    print(f"RMS magnitude error, model / calibration at that temperature: {ratio:.3f}")
    assert ratio <= 1.2
    # and without the model (the reference calibration applied at every temperature) it is not
    unit, fit = thermal_fit(0)
    z, _ = probe(unit, BETWEEN[0], TRUE_LINEAR, np.random.default_rng(5))
    stale = np.sqrt(np.mean(magnitude_errors(fit.reference.apply(z)) ** 2))
    assert stale > 5 * np.sqrt(np.mean(np.square(direct_errors)))


def t_spread(dof: int) -> float:
    """sd of Student's t of `dof` degrees of freedom."""
    return float(np.sqrt(dof / (dof - 2)))


def test_the_rotary_gyro_path_recovers_its_tempcos():
    """A 12-gyro unit's rotary sessions at 4 soaks through the Eq. 18 reduction (`rotary_fit`):
    the linear tempcos' z over 15 seeds. The scale z are N(0, 1) (sigmas from thousands of
    samples). The bias sigmas are the scatter of 20 static means per soak pooled over the 4
    soaks (`pooled_static_bias`, 76 dof): a bias z is t(76), sd 1.013."""
    z_bias, z_scale = (np.ravel(z) for z in zip(*(z_scores(rotary_fit(seed), GYRO_TRUTH)
                                                  for seed in range(15)), strict=True))
    low, high = spread_bounds(z_scale.size)
    print(f"gyro z spread: scale {z_scale.std():.3f}, bias {z_bias.std():.3f} (bounds {low:.3f} "
          f".. {high:.3f}, bias up to {high - 1 + t_spread(76):.3f}); max |z| "
          f"{np.abs(z_scale).max():.2f}, {np.abs(z_bias).max():.2f}")
    assert low < z_scale.std() < high
    assert low < z_bias.std() < high - 1 + t_spread(76)
    assert np.abs(z_scale).max() < norm.isf(ALPHA / (2 * z_scale.size))
    assert np.abs(z_bias).max() < t_dist.isf(ALPHA / (2 * z_bias.size), 76)


def test_pooled_static_bias_makes_a_short_campaigns_bias_z_students_t():
    """The thermal campaign's short soaks (8 positions, 5 s static windows, 1 rad/s, 100 Hz, as
    the thermal twin's profile): each soak's own scatter has 7 dof, and weighting the soaks by
    those estimated sigmas spread the bias tempcos' z to 1.19 (2400 values). Pooled over the 4
    soaks (28 dof) the z of 50 seeds x 12 gyros are t(28): their mean square is 28/26 within its
    ALPHA bound (the variance of t^2 is E t^4 - (E t^2)^2, E t^4 = 3 nu^2 / ((nu - 2)(nu - 4))),
    and a Kolmogorov-Smirnov test against t(28) passes at ALPHA."""
    timing = RotaryTiming(rate=1.0, static=5.0, moving=12.0)
    z = np.ravel([z_scores(rotary_fit(seed, positions=8, timing=timing, fs=100.0),
                           GYRO_TRUTH)[0] for seed in range(50)])
    nu = 4 * 7
    mean_sq = nu / (nu - 2)
    var_sq = 3 * nu**2 / ((nu - 2) * (nu - 4)) - mean_sq**2
    bound = norm.isf(ALPHA / 2) * np.sqrt(var_sq / z.size)
    print(f"bias z mean square {np.mean(z**2):.3f} (t({nu}): {mean_sq:.3f} +- {bound:.3f})")
    assert abs(np.mean(z**2) - mean_sq) < bound
    assert kstest(z, t_dist(nu).cdf).pvalue > ALPHA


def test_hysteresis_moves_the_bias_by_its_width_between_heating_and_cooling():
    unit = accelerometer_triad(np.random.default_rng(3))
    p = Temperature(bias=1e-3, hysteresis=(4e-3, 0.0, 1e-3), t_ref=300.0)
    heated, cooled = unit_at(unit, 320.0, True, p), unit_at(unit, 320.0, False, p)
    assert np.allclose(heated.bias - cooled.bias, [4e-3, 0.0, 1e-3], rtol=0, atol=1e-15)
    assert np.allclose(heated.bias - unit.bias, 20 * 1e-3 + np.array([2e-3, 0.0, 5e-4]),
                       rtol=0, atol=1e-15)
    soaks = simulate_soaks(unit, (310.0, 290.0), p, poses=12, start=300.0)
    assert [s.temperature for s in soaks] == [310.0, 290.0]


def soaks_at(temps, seed=0):
    return simulate_soaks(accelerometer_triad(np.random.default_rng(seed)), temps, TRUE_LINEAR,
                          poses=12)


@pytest.mark.parametrize("temps, orders, message", [
    ((300.0,), None, "1 soak.*at least 2"),
    ((300.0, 302.0, 304.0), None, "span 4 K.*too close to resolve a slope"),
    ((25.0, 45.0, 65.0), None, "looks like degC"),
    ((263.15, 303.15), {"bias": 2, "scale": 1}, "order 2 needs 3 distinct soak temperatures"),
    ((263.15, 263.5, 303.15), {"bias": 1, "scale": 2}, "needs 3 distinct"),
    ((263.15, 283.15, 303.15), {"bias": 3, "scale": 1}, "order 3 is not in 0..2"),
])
def test_impossible_fits_are_refused_naming_the_problem(temps, orders, message):
    soaks = soaks_at(np.clip(temps, 200.0, None))
    soaks = [Soak(t, s.readings, s.sigma) for t, s in zip(temps, soaks, strict=True)]
    with pytest.raises(InputError, match=message):
        fit_temperature(soaks, G, orders=orders)


def test_a_non_finite_temperature_is_refused():
    soaks = soaks_at((263.15, 303.15))
    with pytest.raises(InputError, match="non-finite"):
        fit_temperature([soaks[0], Soak(float("nan"), soaks[1].readings, soaks[1].sigma)], G)


def test_a_soak_the_solver_refuses_is_named():
    soaks = soaks_at((263.15, 303.15))
    few = Soak(303.15, soaks[1].readings[:, :6], soaks[1].sigma[:, :6])
    with pytest.raises(CalibrationInputError, match="the soak at 303.15 K"):
        fit_temperature([soaks[0], few], G)


def test_the_selection_stops_at_what_the_soaks_resolve():
    """Two soaks: at most linear, whatever the data; the tests say so."""
    fit = fit_temperature(soaks_at((263.15, 323.15)), G)
    assert fit.model.orders == {"bias": 1, "scale": 1}
    assert fit.dof == 0 and [t[:2] for t in fit.tests] == [("bias", 1), ("scale", 1)]
    assert (fit.model.t_min, fit.model.t_ref, fit.model.t_max) == (263.15, 293.15, 323.15)


def test_the_free_static_path_from_detected_still_poses():
    """Each soak's recording through the stillness detector and the still-pose reduction's
    readings (as `station solve` gets them), then the fit: the tempcos within 4.5 sigma (all 6
    below it with probability 1 - 4e-5)."""
    unit = accelerometer_triad(np.random.default_rng(11))
    soaks = []
    sims = soak_recordings(unit, SOAKS, TRUE_LINEAR, simulate_static)  # 4 s poses: the detector's
    for temp, sim in zip(SOAKS, sims, strict=True):
        found = detect_still(sim.arrays["y"][0] * sim.arrays["lsb"], unit.fs)
        p = len(found.mean)
        readings = StillReadings(found.mean.T, found.stderr.T, np.zeros((p, 2)),
                                 np.zeros(p, np.int64))
        soaks.append(still_soak(temp, readings))
    assert all(s.readings.shape == (3, 20) for s in soaks)  # every pose found
    fit = fit_temperature(soaks, G, orders={"bias": 1, "scale": 1})
    assert np.abs(z_scores(fit, TRUE_LINEAR)).max() < 4.5


def test_a_hysteresis_the_model_lacks_makes_the_calibration_suspect():
    """1 mg of hysteresis, soaks visited up and down: chi2 far beyond its dof; without it the
    same soaks pass (a false alarm has probability CHI2_P / 2 = 5e-4 per fit)."""
    temps = (233.15, 318.15, 273.15, 358.15)
    for hysteresis, suspect in ((0.0, False), (1e-2, True)):
        truth = dataclasses.replace(TRUE_LINEAR, hysteresis=hysteresis)
        unit = accelerometer_triad(np.random.default_rng(4))
        fit = fit_temperature(simulate_soaks(unit, temps, truth), G)
        cal = Calibration.from_temperature_fit(fit, "SN1", ("ax", "ay", "az"), "m/s^2")
        assert bool(fit.problems) == suspect
        assert cal.fit["status"] == ("suspect" if suspect else "good")
    assert "hysteresis" in cal.fit["status_reasons"][0]
