"""The diagnose candidate `temperature` (station.diagnose.effects.temperature): biases that follow
the unit's recorded temperature are told from biases that drift with time, and the candidate is
offered only when the session records a temperature that moves."""

import numpy as np
import pytest
from scipy.stats import norm

from station.diagnose import data as session_data
from station.diagnose import diagnose
from station.diagnose.effects import temperature as candidate
from station.errors import InputError
from station.model.effects.bias_drift import BiasDrift
from station.model.effects.temperature import Temperature
from station.sim.layouts import TRIAD, gyro_array
from station.sim.profile import RotaryTiming
from station.sim.rotary import simulate_rotary
from station.sim.warm_rotary import chamber_hump, simulate_warm_rotary, slow_ramp

ALPHA = 0.01
"""False-alarm probability of each statistical check, over the values it checks (Bonferroni)."""
SHORT = RotaryTiming(static=4.0, moving=10.0)
TEMPCO = (1e-4, -1.3e-4, 0.8e-4)
"""rad/s per K (0.005-0.007 deg/s/K, a MEMS gyro's size)."""
DRIFT = BiasDrift(warmup=0.004, heating=0.0006)
"""The time-driven drift of bench/diagnose.py's bias_drift case."""


NO_TEMPCO = Temperature()


def _session(seed, history, tempco=NO_TEMPCO, effects=None):
    unit = gyro_array(np.random.default_rng(seed), TRIAD, fs=100.0)
    sim = simulate_warm_rotary(unit, 20, SHORT, history, tempco, effects=effects,
                               a_nominal=TRIAD)
    return session_data.from_arrays(sim.arrays), sim.truth


def test_heat_driven_drift_is_named_temperature_with_its_tempcos():
    # a chamber 3 K up and back down: not monotone in time, so no warm-up fits it
    d, truth = _session(3001, chamber_hump(3.0), Temperature(bias=TEMPCO))
    result = diagnose(d)
    assert result.effects[:1] == ["temperature"] and "bias_drift" not in result.effects, \
        result.effects
    fitted = result.final.fitted["temperature"]
    z = (fitted.value("bias") - np.asarray(TEMPCO)) / fitted.sigma["bias"]
    # least squares on a regressor known to millikelvin: z ~ N(0, 1) per sensor (the noise of
    # the smoothed temperature attenuates the slopes by (2 mK / 1 K)^2, far below 1 sigma)
    assert np.all(np.abs(z) < norm.isf(ALPHA / (2 * len(TEMPCO)))), z
    assert abs(fitted.values["t_ref"] - truth["temperature_true"].mean()) < 0.01


def test_time_driven_drift_is_not_named_temperature():
    # warm-up and heating drift while the recorded temperature rises 1 K, unrelated to it
    d, _ = _session(3002, slow_ramp(1.0), effects={"bias_drift": DRIFT})
    result = diagnose(d)
    assert "temperature" in result.steps[0].evidence  # offered: the temperature moves
    assert result.effects[:1] == ["bias_drift"] and "temperature" not in result.effects, \
        result.effects


def test_without_a_recorded_temperature_the_candidate_is_not_offered():
    unit = gyro_array(np.random.default_rng(3003), TRIAD, fs=100.0)
    sim = simulate_rotary(unit, 20, SHORT, effects={"bias_drift": DRIFT}, a_nominal=TRIAD)
    d = session_data.from_arrays(sim.arrays)
    assert d.temperature is None and not candidate.available(d)
    result = diagnose(d)
    assert result.effects[:1] == ["bias_drift"]
    assert all("temperature" not in step.evidence for step in result.steps)


def test_a_flat_temperature_is_too_small_to_offer_the_candidate():
    # flat: the sensor's noise (0.02 K) and quantisation only, smoothed to millikelvin
    d, _ = _session(3004, slow_ramp(0.0))
    assert d.temperature is not None and not candidate.available(d)
    d, _ = _session(3004, slow_ramp(2 * candidate.MIN_EXCURSION))
    assert candidate.available(d)


def test_a_temperature_in_degc_is_refused():
    unit = gyro_array(np.random.default_rng(3005), TRIAD, fs=100.0)
    sim = simulate_rotary(unit, 4, SHORT, a_nominal=TRIAD)
    n, k, _ = sim.arrays["y"].shape
    with pytest.raises(InputError, match="degC"):
        session_data.from_arrays({**sim.arrays, "temperature": np.full((n, k), 25.0)})
    with pytest.raises(InputError, match="shape"):
        session_data.from_arrays({**sim.arrays, "temperature": np.full((n, k + 1), 298.0)})


def test_an_array_file_carries_the_temperature_to_the_diagnosis(tmp_path):
    unit = gyro_array(np.random.default_rng(3006), TRIAD, fs=100.0)
    sim = simulate_warm_rotary(unit, 20, SHORT, chamber_hump(1.0), NO_TEMPCO, a_nominal=TRIAD)
    np.savez(tmp_path / "s.npz", **sim.arrays)
    loaded = session_data.load(tmp_path / "s.npz")
    assert np.array_equal(loaded.temperature, sim.arrays["temperature"])
    np.savez(tmp_path / "bad.npz", **{**sim.arrays, "temperature": sim.arrays["temperature"][1:]})
    with pytest.raises(InputError, match="temperature has shape"):
        session_data.load(tmp_path / "bad.npz")
