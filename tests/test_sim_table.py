"""Live rotary-table physics: bounded acceleration, exact angle, at_rate settling, faults."""

import math
import threading

import pytest

from drivers.clock import ScaledClock
from station.model.effects.rate_error import RateError
from station.sim.table import TablePhysics


class SteppedClock:
    """A clock the test moves by hand, so the physics can be checked against closed forms."""

    def __init__(self):
        self.t = 0.0

    def now(self):
        return self.t


def test_spin_up_is_a_bounded_ramp_and_angle_is_its_integral():
    clock = SteppedClock()
    table = TablePhysics(clock, max_accel=2.0, settle_time=0.5, tolerance=1e-3)
    table.set_rate(1.0)
    assert table.start()
    clock.t = 0.25
    s = table.state()
    assert s.rate == pytest.approx(0.5) and s.angle == pytest.approx(0.5 * 2.0 * 0.25**2)
    assert s.moving and s.running and not s.at_rate
    clock.t = 0.9  # reached 1 rad/s at 0.5 s; in band since 0.4995 s; settled after 0.9995 s
    assert not table.state().at_rate
    clock.t = 3.0
    s = table.state()
    assert s.rate == 1.0 and s.at_rate
    assert s.angle == pytest.approx(0.25 + 1.0 * 2.5)  # ramp area + steady part


def test_stop_decelerates_to_rest_and_total_angle_matches():
    clock = SteppedClock()
    table = TablePhysics(clock, max_accel=1.0)
    table.set_rate(-2.0)
    table.start()
    clock.t = 5.0
    table.stop()
    clock.t = 6.0
    s = table.state()
    assert s.rate == pytest.approx(-1.0) and not s.running and s.moving and not s.at_rate
    clock.t = 10.0
    s = table.state()
    assert s.rate == 0.0 and not s.moving
    # up 2 s (-2 rad), steady 3 s (-6 rad), down 2 s (-2 rad)
    assert s.angle == pytest.approx(-10.0)


def test_fault_stops_the_table_and_refuses_start_until_cleared():
    clock = SteppedClock()
    table = TablePhysics(clock, max_accel=4.0)
    table.set_rate(1.0)
    table.start()
    clock.t = 2.0
    table.fault(True)
    assert not table.start()
    clock.t = 3.0
    s = table.state()
    assert s.fault and not s.running and s.rate == 0.0
    table.fault(False)
    assert table.start()


def test_setpoint_outside_range_is_refused_with_advice():
    table = TablePhysics(SteppedClock(), max_rate=5.0)
    with pytest.raises(ValueError, match="outside the table's range"):
        table.set_rate(6.0)
    with pytest.raises(ValueError):
        table.set_rate(math.nan)


def test_rate_error_changes_true_motion_not_the_report():
    clock = SteppedClock()
    table = TablePhysics(clock, max_accel=10.0, rate_error=RateError(scale=0.01), seed=1)
    table.set_rate(1.0)
    table.start()
    clock.t = 10.0
    s = table.state()
    assert s.rate == 1.0 and s.true_rate == pytest.approx(1.01)
    assert s.true_angle == pytest.approx(1.01 * s.angle)


def test_an_encoder_reports_the_true_motion_under_rate_error():
    clock = SteppedClock()
    table = TablePhysics(clock, max_accel=10.0, rate_error=RateError(scale=0.01, encoder=True),
                        seed=1)
    table.set_rate(1.0)
    table.start()
    clock.t = 10.0
    s = table.state()
    assert s.true_rate == pytest.approx(1.01) and s.rate == s.true_rate
    assert s.angle == s.true_angle and s.rate_setpoint == 1.0


def test_rate_noise_has_its_standard_deviation_while_moving_only():
    clock = SteppedClock()
    table = TablePhysics(clock, max_accel=10.0, rate_noise=0.01, seed=3)
    assert table.state().rate == 0.0
    table.set_rate(1.0)
    table.start()
    clock.t = 1.0
    rates = [table.state().rate - 1.0 for _ in range(2000)]
    sd = math.sqrt(sum(r * r for r in rates) / len(rates))
    assert abs(sd - 0.01) < 0.01 * 5 / math.sqrt(2 * 2000)  # 5 sigma of the sd estimate


def test_concurrent_callers_on_a_fast_clock_see_monotonic_time_and_angle():
    table = TablePhysics(ScaledClock(speed=100.0), max_accel=5.0)
    table.set_rate(3.0)
    table.start()
    seen = []

    def poll():
        for _ in range(300):
            seen.append(table.state())

    threads = [threading.Thread(target=poll) for _ in range(3)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    final = table.state()
    assert all(s.time <= final.time and s.angle <= final.angle for s in seen)
    assert all(0.0 <= s.rate <= 3.0 for s in seen)


def test_true_rates_at_past_times_follow_the_command_history():
    """A late twin asks for the motion at its samples' own (past) times: the answer must be the
    state the table had then, not the present one (closed form: ramps of 2 rad/s^2)."""
    clock = SteppedClock()
    table = TablePhysics(clock, max_accel=2.0, rate_error=RateError(scale=0.01), seed=3)
    table.set_rate(1.0)
    clock.t = 1.0
    table.start()  # ramp 1.0 .. 1.5 s, then 1 rad/s
    clock.t = 4.0
    factor = table.state().true_rate  # the rate_error factor drawn at start (rate is 1 rad/s)
    assert factor != 1.0
    table.stop()  # ramp down 4.0 .. 4.5 s
    clock.t = 10.0  # everything below is asked afterwards, as a lagging twin would
    times = [0.5, 1.25, 2.0, 4.25, 6.0]
    expected = [0.0, 0.5 * factor, factor, 0.5 * factor, 0.0]
    assert table.true_rates(times) == pytest.approx(expected)
