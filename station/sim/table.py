"""Live physics of the rotary table, driven by a shared clock (the Modbus twin's truth).

The table's controller ramps its rate towards the setpoint with bounded acceleration, integrates the
angle exactly (piecewise linear rate), and raises `at_rate` once the rate has stayed within
`tolerance` of the setpoint for `settle_time`. `TableState.rate` and `.angle` are what the table
reports; with the `rate_error` effect the physical motion the IMU feels is `true_rate = factor *
rate`, where the factor is drawn anew at every `start()`, and the reported motion is the
command's (default) or, with `RateError(encoder=True)`, the true one (an encoder on the shaft).
"""

import collections
import math
import threading
from dataclasses import dataclass

import numpy as np

from station.model.effects.rate_error import RateError

HISTORY = 10_000  # commands remembered for `true_rates` (a session issues a few per position)


@dataclass(frozen=True)
class TableState:
    """Snapshot of the table at `time` (seconds of the shared clock); rates rad/s, angles rad.

    `angle` is unwrapped (cumulative). `true_rate`/`true_angle` are the physical motion, which
    differs from the reported one only under the `rate_error` effect.
    """

    time: float
    rate: float
    angle: float
    rate_setpoint: float
    running: bool
    moving: bool
    at_rate: bool
    fault: bool
    true_rate: float
    true_angle: float


class TablePhysics:
    """Rotary table physics advanced to `clock.now()` on every call; thread-safe.

    Parameters
    ----------
    clock : object with `now()` (e.g. `drivers.clock.ScaledClock`), shared with the other twins.
    max_accel : bound on |d rate / dt|, rad/s^2.
    rate_noise : standard deviation of the reported rate while moving, rad/s (encoder jitter).
    max_rate : largest accepted |setpoint|, rad/s.
    tolerance : |rate - setpoint| below which the table counts as at rate, rad/s.
    settle_time : how long the rate must stay within tolerance before `at_rate`, s.
    rate_error : optional `RateError` effect (true rate differs from the command).
    seed : seed of the numpy Generator for the rate noise and the rate-error draws.
    """

    def __init__(
        self,
        clock,
        max_accel=2.0,
        rate_noise=0.0,
        max_rate=20.0,
        tolerance=1e-3,
        settle_time=0.5,
        rate_error: RateError | None = None,
        seed=None,
    ):
        if not max_accel > 0:
            raise ValueError(f"max_accel must be positive (rad/s^2), got {max_accel!r}")
        if not (tolerance > 0 and settle_time >= 0 and rate_noise >= 0 and max_rate > 0):
            raise ValueError(
                "tolerance and max_rate must be positive, settle_time and rate_noise non-negative"
            )
        self._clock = clock
        self.max_accel = float(max_accel)
        self.rate_noise = float(rate_noise)
        self.max_rate = float(max_rate)
        self.tolerance = float(tolerance)
        self.settle_time = float(settle_time)
        self._rate_error = rate_error or RateError()
        # the reported rate's noise is drawn at every poll, the rate errors at every start: two
        # streams, so that how often a host polled does not change the errors of a seeded table
        noise, errors = np.random.SeedSequence(seed).spawn(2)
        self._rng, self._errors = np.random.default_rng(noise), np.random.default_rng(errors)
        self._lock = threading.Lock()
        self._t = clock.now()
        self._rate = 0.0
        self._angle = 0.0
        self._true_angle = 0.0
        self._factor = 1.0
        self._setpoint = 0.0
        self._running = False
        self._fault = False
        self._in_band_since = None
        # command history (time, rate then, target, true-rate factor): the motion at any past time
        self._history = collections.deque([(self._t, 0.0, 0.0, 1.0)], maxlen=HISTORY)

    @property
    def clock(self):
        """The shared clock the physics follow."""
        return self._clock

    def _target(self) -> float:
        return self._setpoint if self._running and not self._fault else 0.0

    def _advance(self) -> None:
        """Integrate rate and angle from the last update to clock.now() (ramp, then constant)."""
        t1 = self._clock.now()
        dt = t1 - self._t
        if dt <= 0:
            return
        r0, target = self._rate, self._target()
        t_ramp = abs(target - r0) / self.max_accel
        if dt < t_ramp:
            r1 = r0 + math.copysign(self.max_accel * dt, target - r0)
            dangle = 0.5 * (r0 + r1) * dt
        else:
            r1 = target
            dangle = 0.5 * (r0 + target) * t_ramp + target * (dt - t_ramp)
        self._track_band(r0, r1, t_ramp)
        self._rate, self._angle, self._t = r1, self._angle + dangle, t1
        self._true_angle += self._factor * dangle

    def _track_band(self, r0: float, r1: float, t_ramp: float) -> None:
        """Remember when the rate entered the tolerance band around the setpoint."""
        if not (self._running and not self._fault) or abs(r1 - self._setpoint) >= self.tolerance:
            self._in_band_since = None
        elif self._in_band_since is None:
            gap = abs(r0 - self._setpoint)
            entered = max(0.0, (gap - self.tolerance) / self.max_accel)
            self._in_band_since = self._t + min(entered, t_ramp)

    def _command(self) -> None:
        """A command changed the target: restart the settle timer from the present state and
        remember the command, so that the motion at past times stays known (`true_rates`)."""
        self._in_band_since = None
        self._track_band(self._rate, self._rate, 0.0)
        self._history.append((self._t, self._rate, self._target(), self._factor))

    def true_rates(self, times) -> np.ndarray:
        """Physical rate (rad/s) at each of `times` (clock seconds), past or present.

        A twin that computes its samples late (a loaded host) must not give a sample the motion of
        the moment it is computed: the rate at the sample's own time follows from the commands
        (ramp with bounded acceleration from the rate at the command, then constant).
        """
        times = np.asarray(times, dtype=float)
        with self._lock:
            hist = np.array(self._history)
        t_cmd, r0, target, factor = hist.T
        i = np.clip(np.searchsorted(t_cmd, times, side="right") - 1, 0, len(hist) - 1)
        dt = np.maximum(times - t_cmd[i], 0.0)
        ramp = r0[i] + np.sign(target[i] - r0[i]) * self.max_accel * dt
        done = dt >= np.abs(target[i] - r0[i]) / self.max_accel
        return factor[i] * np.where(done, target[i], ramp)

    def set_rate(self, rate_rad_s: float) -> None:
        """Set the rate setpoint (rad/s, signed), reached with bounded acceleration."""
        rate = float(rate_rad_s)
        if not math.isfinite(rate) or abs(rate) > self.max_rate:
            raise ValueError(
                f"rate setpoint {rate_rad_s!r} rad/s is outside the table's range "
                f"+-{self.max_rate} rad/s; command a smaller rate"
            )
        with self._lock:
            self._advance()
            self._setpoint = rate
            self._command()

    def start(self) -> bool:
        """Run towards the setpoint; refused (returns False) while a fault is active."""
        with self._lock:
            self._advance()
            if self._fault:
                return False
            self._running = True
            self._factor = float(self._rate_error.factors(1, self._errors)[0])
            self._command()
            return True

    def stop(self) -> None:
        """Decelerate to rest with the bounded acceleration."""
        with self._lock:
            self._advance()
            self._running = False
            self._command()

    def fault(self, flag: bool) -> None:
        """Raise (True) or clear (False) a fault; a fault stops the run, the table decelerates."""
        with self._lock:
            self._advance()
            self._fault = bool(flag)
            if self._fault:
                self._running = False
            self._command()

    def state(self) -> TableState:
        """Advance to clock.now() and return the reported and true motion."""
        with self._lock:
            self._advance()
            moving = self._rate != 0.0
            noise = (
                self.rate_noise * self._rng.standard_normal() if moving and self.rate_noise else 0.0
            )
            at_rate = (
                self._in_band_since is not None
                and self._t - self._in_band_since >= self.settle_time
            )
            encoder = self._rate_error.encoder  # the registers read the shaft, not the command
            return TableState(
                time=self._t,
                rate=(self._factor if encoder else 1.0) * self._rate + noise,
                angle=self._true_angle if encoder else self._angle,
                rate_setpoint=self._setpoint,
                running=self._running,
                moving=moving,
                at_rate=at_rate,
                fault=self._fault,
                true_rate=self._factor * self._rate,
                true_angle=self._true_angle,
            )


@dataclass(frozen=True)
class PositionState:
    """The position axis at `time` (clock seconds): angle (cumulative) and setpoint in rad,
    `in_position` once the axis has reached its setpoint (docs/devices.md); the rate mode's
    `spinning` (in rate mode), `rate` and `rate_setpoint` (rad/s), `at_rate` and `moving` (either
    mode)."""

    time: float
    angle: float
    setpoint: float
    in_position: bool
    spinning: bool = False
    rate: float = 0.0
    rate_setpoint: float = 0.0
    at_rate: bool = False
    moving: bool = False


class PositionAxis:
    """The inner (position) axis of a two-axis table; thread-safe, advanced to `clock.now()` on
    each call.

    Position mode: the axis moves to its setpoint at a bounded rate `max_rate` (rad/s), then holds
    it exactly. `on_move(setpoint, arrival)`, when given, is called at every command with the clock
    time the axis will reach the setpoint (what turns the simulated unit). The slew itself is not
    felt by a simulated unit (the unit takes its new orientation on arrival): the protocol moves
    the axis in position mode only with the table at rest and waits before it measures.

    Rate mode (`spin`): the axis runs at its rate setpoint (`set_rate`), reached and left with the
    bounded acceleration `max_accel` (rad/s^2): the motion of a `TablePhysics` (its ramps, its
    `at_rate` after `settle_time` within `tolerance`, its `true_rates` at past times: the rate the
    simulated unit feels about the axis). `hold` ends it: the axis decelerates and holds where it
    comes to rest (`on_move` is told that angle and when); in position mode `hold` halts a slew
    where it is. The angle is the position-mode angle plus what the rate mode swept."""

    def __init__(self, clock, max_rate: float = 0.5, angle: float = 0.0, on_move=None,
                 max_accel: float = 2.0, tolerance: float = 1e-3, settle_time: float = 0.5,
                 spin_limit: float = 20.0):
        if not max_rate > 0:
            raise ValueError(f"max_rate must be positive (rad/s), got {max_rate!r}")
        self._clock, self.max_rate, self.on_move = clock, float(max_rate), on_move
        self._lock = threading.Lock()
        self._t, self._angle, self._setpoint = clock.now(), float(angle), float(angle)
        self._spinner = TablePhysics(clock, max_accel=max_accel, max_rate=spin_limit,
                                     tolerance=tolerance, settle_time=settle_time)

    @property
    def clock(self):
        """The shared clock the axis follows."""
        return self._clock

    def _advance(self) -> None:
        t1 = self._clock.now()
        step = self.max_rate * max(t1 - self._t, 0.0)
        gap = self._setpoint - self._angle
        self._angle = self._setpoint if abs(gap) <= step else self._angle + math.copysign(step, gap)
        self._t = max(t1, self._t)

    def set_position(self, angle: float) -> None:
        """Command the axis to `angle` (rad, finite; the cumulative angle); refused (ValueError)
        in rate mode: `hold` first."""
        if not math.isfinite(angle):
            raise ValueError(f"position setpoint {angle!r} must be a finite angle in rad")
        if self._spinner.state().running:
            raise ValueError("the position axis is in rate mode: hold it before positioning it")
        swept = self._spinner.state().angle  # the rate mode's part of the angle, at rest
        with self._lock:
            self._advance()
            self._setpoint = float(angle) - swept
            arrival = self._t + abs(self._setpoint - self._angle) / self.max_rate
        if self.on_move is not None:
            self.on_move(float(angle), arrival)

    def set_rate(self, rate: float) -> None:
        """The rate-mode setpoint (rad/s, signed); ValueError beyond `spin_limit`."""
        self._spinner.set_rate(rate)

    def spin(self) -> None:
        """Rate mode: run at the rate setpoint (a slew in progress halts where it is)."""
        with self._lock:
            self._advance()
            self._setpoint = self._angle
        self._spinner.start()

    def hold(self) -> None:
        """Position mode, held where the axis comes to rest (see the class doc)."""
        with self._lock:
            self._advance()
            self._setpoint = self._angle
        self._spinner.stop()
        s = self._spinner.state()
        stopping = abs(s.rate) / self._spinner.max_accel
        rest = self._setpoint + s.angle + 0.5 * s.rate * stopping
        if self.on_move is not None:
            self.on_move(rest, s.time + stopping)

    def true_rates(self, times) -> np.ndarray:
        """The axis' rate (rad/s) in rate mode at each of `times` (`TablePhysics.true_rates`)."""
        return self._spinner.true_rates(times)

    def state(self) -> PositionState:
        """Advance to clock.now() and return the axis' state."""
        s = self._spinner.state()
        with self._lock:
            self._advance()
            slewing = self._angle != self._setpoint
            return PositionState(self._t, self._angle + s.angle, self._setpoint + s.angle,
                                 not (slewing or s.moving), s.running, s.rate, s.rate_setpoint,
                                 s.at_rate, slewing or s.moving)


class MountingFixture:
    """A motorised fixture that re-mounts the unit in the positions of a plan, commanded through
    the table's controller (the `mount` register of `drivers.rotary_table`). `request(n)` asks
    for position n (1-based; 0: none); whoever moves the unit (the virtual bench's fixture
    thread) takes `pending()` and reports `done(n)`, or `on_request(n)`, when set, moves it at
    once, before the request returns (lockstep time: the station's next read sees the move
    whatever the host's timing). Asking again for the position held needs no move. Thread-safe."""

    def __init__(self):
        self._lock = threading.Lock()
        self._requested = self._held = 0
        self.on_request = None

    def request(self, position: int) -> None:
        with self._lock:
            self._requested = int(position)
        if self.on_request is not None and self.pending() is not None:
            self.on_request(int(position))

    def pending(self) -> int | None:
        """The position asked for and not yet held, or None."""
        with self._lock:
            return self._requested if self._requested not in (0, self._held) else None

    def done(self, position: int) -> None:
        """The unit is now held in `position`."""
        with self._lock:
            self._held = int(position)

    def state(self) -> tuple[int, bool]:
        """(position asked for, is it held)."""
        with self._lock:
            return self._requested, self._requested != 0 and self._requested == self._held
