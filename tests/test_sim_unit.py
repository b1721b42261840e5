"""Sensor unit, Earth model and rate profile against closed forms."""

import numpy as np
import pytest

from station.model.earth import OMEGA_EARTH, earth_rate_enu, earth_rate_table, normal_gravity
from station.model.unit import SensorUnit
from station.sim.profile import Profile, RotaryTiming


def test_sample_is_a_transpose_v_plus_bias_in_counts():
    a = np.array([[1.0, 0.0, 0.5], [0.0, 2.0, 0.5], [0.0, 0.0, 0.7]])
    unit = SensorUnit(a, bias=[0.1, -0.2, 0.0], counts_per_unit=100.0, rng=0)
    counts = unit.sample(np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]]))
    assert counts.dtype == np.int32
    assert counts.tolist() == [[110, 380, 360], [10, -20, 0]]


def test_white_noise_has_density_times_sqrt_fs_plus_quantisation():
    unit = SensorUnit(np.eye(3), noise_density=0.01, fs=400.0, counts_per_unit=50.0, rng=1)
    x = unit.sample(np.zeros((20000, 3))) * unit.lsb
    expected = np.sqrt((0.01 * np.sqrt(400.0)) ** 2 + unit.lsb**2 / 12)
    assert np.allclose(x.std(0), expected, rtol=5 * np.sqrt(0.5 / 20000))
    assert np.allclose(unit.mean_sigma(20000), expected / np.sqrt(20000))


def test_bias_walk_variance_grows_linearly_and_continues_across_calls():
    unit = SensorUnit(np.eye(1), bias_walk=0.02, fs=100.0, rng=2)
    w = unit.walk(400, 500)[..., 0]  # 400 recordings of 5 s, chained
    steps = w[:, -1] - w[:, 0]
    expected = 0.02**2 * 499 / 100.0
    assert abs(steps.var() / expected - 1) < 5 * np.sqrt(2 / 400)
    again = unit.walk(1, 2)[0, 0, 0]
    assert abs(again - w[-1, -1]) < 10 * 0.02 / np.sqrt(100.0)  # starts where it stopped


def test_bad_unit_parameters_are_refused_with_the_problem_named():
    with pytest.raises(ValueError, match="one value per sensor"):
        SensorUnit(np.eye(3), bias=[0.0, 1.0])
    with pytest.raises(ValueError, match="sample rate"):
        SensorUnit(np.eye(3), fs=0)
    with pytest.raises(ValueError, match=r"shape \(k, 3\)"):
        SensorUnit(np.eye(3)).sample(np.zeros((4, 2)))


def test_earth_rate_and_gravity_at_known_latitudes():
    assert np.allclose(earth_rate_enu(90.0), [0, 0, OMEGA_EARTH], atol=1e-20)
    assert normal_gravity(0.0) == pytest.approx(9.7803253359)
    assert normal_gravity(90.0) == pytest.approx(9.8321849378, abs=1e-7)
    # heading 90 deg: table x points east, table y points north
    assert np.allclose(earth_rate_table(0.0, np.pi / 2), [0, OMEGA_EARTH, 0], atol=1e-18)


def test_profile_angle_is_the_exact_integral_of_the_rate():
    p = Profile((0.0, 1.0, 3.0, 4.0), (0.0, 2.0, 2.0, -1.0))
    assert p.angle(np.array([0.5, 1.0, 2.0, 4.0, 5.0])) == pytest.approx(
        [0.25, 1.0, 3.0, 5.0 + 0.5, 5.5 - 1.0]
    )


def test_rotary_timing_segments_and_refusal_of_impossible_timing():
    timing = RotaryTiming(rate=np.pi / 2, max_accel=1.0, static=10.0, moving=25.0, settle=1.0)
    seg = timing.segments(200.0)
    assert seg["static"] == (0, 2000) and seg["spinup"] == (2000, 2315)
    assert seg["spindown"][1] == timing.samples(200.0) == 7000
    rate = timing.profile().rate(np.arange(7000) / 200.0)
    assert np.all(rate[seg["settle"][0] : seg["rotating"][1]] == np.pi / 2)
    with pytest.raises(ValueError, match="no steady rotation"):
        RotaryTiming(rate=10.0, max_accel=1.0, moving=20.0)


def test_live_walk_steps_with_the_actual_sample_times():
    unit = SensorUnit(np.eye(1), bias_walk=0.1, counts_per_unit=1e6, rng=4)
    ends = []
    for i in range(400):  # other instants each time: the same instants repeat their draws
        unit._walk[:] = 0.0
        unit._last_time = None
        ends.append(unit.sample(np.zeros((3, 1)), times=[10.0 * i, 10.0 * i + 2.0,
                                                        10.0 * i + 4.0])[-1, 0] * 1e-6)
    expected = 0.1**2 * (4.0 + 1.0 / unit.fs)  # the first sample steps by 1 / fs
    assert abs(np.var(ends) / expected - 1) < 5 * np.sqrt(2 / 400)


def test_mounted_unit_streams_the_table_rate_along_its_axis():
    from station.sim.live import MountedUnit
    from station.sim.table import TablePhysics

    class Stopped:
        t = 100.0

        def now(self):
            return self.t

    clock = Stopped()
    table = TablePhysics(clock, max_accel=10.0)
    table.set_rate(2.0)
    table.start()
    clock.t = 200.0
    a = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.5]])
    source = MountedUnit(SensorUnit(a, counts_per_unit=1000.0, rng=0), table)
    assert source(200.0 + np.arange(4) * 0.005).tolist() == [[0, 0, 1000]] * 4
    assert source([99.0]).tolist() == [[0, 0, 0]]  # a sample from before the start: at rest
    source.orientation = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    assert source([200.0]).tolist() == [[2000, 0, 0]]
    # named effects go through to the unit's output chain: clipped at the saturation range
    from station.model.effects import Saturation

    clipped = MountedUnit(SensorUnit(a, counts_per_unit=1000.0, rng=0), table, source.orientation,
                          effects={"saturation": Saturation(range=1.5)})
    assert clipped([200.0]).tolist() == [[1500, 0, 0]]


def test_live_sample_runs_the_named_sensor_effects_of_the_output_chain():
    from station.model.effects import BiasDrift, Latency, Saturation, ScaleNonlinearity

    unit = SensorUnit(np.eye(2), bias=[0.1, 0.0], counts_per_unit=1000.0, rng=0)
    effects = {"scale_nonlinearity": ScaleNonlinearity(k2=(0.1, 0.0)),
               "bias_drift": BiasDrift(warmup=(0.0, 0.5), warmup_tau=10.0),
               "saturation": Saturation(range=1.5)}
    counts = unit.sample(np.array([[1.0, 2.0], [2.0, 1.0]]), [0.0, 10.0], effects)
    # by hand: s + k2 s^2 + b + warmup exp(-t / tau), clipped at +-1.5, in counts
    assert counts.tolist() == [[1200, 1500], [1500, round(1000 * (1 + 0.5 * np.exp(-1)))]]
    with pytest.raises(ValueError, match="latency"):
        unit.sample(np.zeros((2, 2)), [0.0, 1.0], {"latency": Latency(0.01)})
    with pytest.raises(ValueError, match="bias_drift heating"):
        unit.sample(np.zeros((2, 2)), [0.0, 1.0], {"bias_drift": BiasDrift(heating=0.1)})


def test_virtual_benches_take_named_effects_into_the_output_chain_and_the_session():
    from station.model.effects import Saturation, from_json, to_json
    from station.twin.hand_bench import HandBench
    from station.twin.rotary_bench import VirtualBench

    live = {"saturation": Saturation(range=(0.5,) * 12)}
    assert from_json({"saturation": {"range": [0.5] * 12}}) == live  # JSON lists back to tuples
    bench = VirtualBench(effects=to_json(live))
    try:
        assert bench.mounted.effects == live
        again = VirtualBench.from_metadata(bench.metadata())  # as a resumed session rebuilds it
        try:
            assert again.mounted.effects == live
        finally:
            again.close()
    finally:
        bench.close()
    plain = VirtualBench(seed=2)
    assert "effects" not in plain.metadata()
    plain.close()
    hand = HandBench(effects={"saturation": {"range": 30.0}})
    assert hand.rig.effects == {"saturation": Saturation(range=30.0)}
    with pytest.raises(ValueError, match="latency"):
        VirtualBench(effects={"latency": {"delay": 0.001}})
