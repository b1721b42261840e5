"""The physics of a virtual thermal chamber: its air and a unit inside, on a shared clock.

Air (first order with a rate limit): while the chamber runs, the air temperature A approaches the
ramped setpoint G with time constant `tau_air`, its rate limited to `heat_rate` when heating and
`cool_rate` when cooling (K/min, a chamber's heater and compressor differ):

    dA/dt = clip((G - A) / tau_air, -cool_rate, +heat_rate)

G follows the setpoint at the ramp rate (K/min), starting from the air temperature when the
setpoint is written (as controllers ramp from the process value); ramp 0 puts G at the setpoint at
once. Stopped, or in alarm (a controller stops conditioning then, and stays stopped until told to
run again), the air relaxes to the room with `tau_room`, unlimited. The door bit is only a bit:
opening is not modelled.

Unit (first order): the unit's own temperature U lags the air with time constant `tau_unit`,
dU/dt = (A - U) / tau_unit. With the air on a ramp of slope r from U = A = T0 at t = 0,
U(t) = T0 + r (t - tau_unit (1 - exp(-t / tau_unit))).

Both are integrated on a fixed grid of steps of `step` clock seconds from the physics' start
(default a hundredth of the shorter time constant), each exact for a constant input (exponential
update, the air's step then clipped to the rate limit), lazily up to the grid point at or after the
instant asked. A command (setpoint, ramp, run, stop) acts from that grid point on, as a controller
acts at its next scan. So the temperatures depend only on the commands' scans, never on when, or
how often, anyone asked: the same instant always gets the same value to the last bit (as long as
nobody asks for an instant still to come: the grid is then integrated ahead, and a command given
meanwhile acts only after it).

`unit_temperature(t)` answers for any instant (one or an array of them), interpolated linearly
between the grid points (before the start: the room temperature, where the unit sat), so an IMU
twin may ask for its own sample times however late a busy host makes it ask. The whole history is
kept: 8 bytes a step, 290 kB an hour of clock time at a 0.1 s step.
"""

import math
import threading
from dataclasses import dataclass

import numpy as np

ON_GRID = 1e-6
"""Steps: an instant this close to a grid point is on it (the rounding of (t - start) / step)."""


@dataclass(frozen=True)
class ChamberState:
    """The chamber at clock time `time`: air, unit and setpoint in K, ramp in K/min."""

    time: float
    air: float
    unit: float
    setpoint: float
    ramp: float
    running: bool
    alarm: bool
    door_open: bool
    at_setpoint: bool


class ChamberPhysics:
    """Air and unit temperatures of a virtual chamber (see the module docstring).

    clock      : the shared clock (drivers.clock); times are its seconds
    room       : room temperature, K (the start temperature of air and unit)
    heat_rate, cool_rate : the air's largest heating and cooling rates, K/min
    band       : |air - setpoint| within which the chamber reports at setpoint, K
    alarm, door_open : fault knobs (attributes), served as status bits
    """

    def __init__(self, clock, room: float = 296.15, tau_air: float = 60.0,
                 heat_rate: float = 5.0, cool_rate: float = 3.0, tau_unit: float = 300.0,
                 tau_room: float = 1800.0, band: float = 0.5, step: float | None = None):
        for name, value in (("room", room), ("tau_air", tau_air), ("heat_rate", heat_rate),
                            ("cool_rate", cool_rate), ("tau_unit", tau_unit),
                            ("tau_room", tau_room), ("band", band)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"chamber physics: {name} must be positive, got {value!r}")
        self.clock, self.room, self.band = clock, room, band
        self.tau_air, self.tau_unit, self.tau_room = tau_air, tau_unit, tau_room
        self.heat, self.cool = heat_rate / 60.0, cool_rate / 60.0  # K/s
        self.step = step or min(tau_air, tau_unit) / 100.0
        self.alarm = self.door_open = False
        self.running = False
        self.started = None  # clock time conditioning last started
        self.setpoint, self.ramp = room, 0.0
        self._start = clock.now()
        self._k = 0  # the grid point integrated up to
        self._air = self._unit = self._goal = room
        self._units = np.full(1024, room)  # the unit at grid points 0.._k (capacity doubles)
        self._lock = threading.Lock()

    @property
    def _t(self) -> float:
        """Clock time of the grid point integrated up to."""
        return self._start + self._k * self.step

    def set_setpoint(self, kelvin: float) -> None:
        """A new setpoint, approached from the present air temperature at the ramp rate."""
        with self._lock:
            self._advance(self.clock.now())
            self.setpoint = kelvin
            self._goal = kelvin if self.ramp == 0 else self._air

    def set_ramp(self, k_per_min: float) -> None:
        """A new ramp rate (K/min, 0 = as fast as possible), from now on."""
        if not (math.isfinite(k_per_min) and k_per_min >= 0):
            raise ValueError(f"ramp must be >= 0 K/min, got {k_per_min!r}")
        with self._lock:
            self._advance(self.clock.now())
            self.ramp = k_per_min

    def run(self) -> None:
        """Start conditioning (ignored in alarm, as a controller refuses to start then)."""
        with self._lock:
            self._advance(self.clock.now())
            if not self.running and not self.alarm:
                self.running, self.started = True, self._t
                self._goal = self.setpoint if self.ramp == 0 else self._air

    def stop(self) -> None:
        """Stop conditioning: the air drifts to the room."""
        with self._lock:
            self._advance(self.clock.now())
            self.running = False

    def state(self) -> ChamberState:
        """Everything at the present clock time."""
        with self._lock:
            self._advance(self.clock.now())
            return ChamberState(self._t, self._air, self._unit, self.setpoint, self.ramp,
                                self.running, self.alarm, self.door_open,
                                self.running and abs(self._air - self.setpoint) <= self.band)

    def unit_temperature(self, t=None):
        """The unit's temperature at clock time `t` (default now; a float, or an array of times
        for an array of temperatures), K, interpolated between grid points; the room's before
        the start."""
        with self._lock:
            x = np.maximum(self._grid(self.clock.now() if t is None else t), 0.0)
            self._advance_to(math.ceil(np.max(x)))
            k = np.floor(x).astype(np.int64)
            before, after = self._units[k], self._units[np.minimum(k + 1, self._k)]
            value = before + (after - before) * (x - k)
            return float(value) if np.ndim(value) == 0 else value

    def _grid(self, t):
        """Clock time(s) `t` in steps from the start, snapped to a grid point within ON_GRID."""
        x = (np.asarray(t, float) - self._start) / self.step
        near = np.rint(x)
        return np.where(np.abs(x - near) <= ON_GRID, near, x)

    def _advance(self, t: float) -> None:
        """Integrate air and unit up to the grid point at or after clock time `t` (called with
        the lock held)."""
        self._advance_to(math.ceil(self._grid(t)))

    def _advance_to(self, k: int) -> None:
        """Integrate air and unit, step by step, up to grid point `k` (with the lock held)."""
        if self.alarm:  # a controller in alarm stops conditioning
            self.running = False
        dt = self.step
        while self._k < k:
            air = self._air
            if self.running:
                move = self.ramp / 60.0 * dt if self.ramp else math.inf  # the ramped setpoint
                self._goal += max(-move, min(move, self.setpoint - self._goal))
                change = (self._goal - air) * -math.expm1(-dt / self.tau_air)
                self._air = air + max(-self.cool * dt, min(self.heat * dt, change))
            else:
                self._air = air + (self.room - air) * -math.expm1(-dt / self.tau_room)
            middle = 0.5 * (air + self._air)
            self._unit += (middle - self._unit) * -math.expm1(-dt / self.tau_unit)
            self._k += 1
            if self._k == len(self._units):
                self._units = np.concatenate([self._units, np.empty_like(self._units)])
            self._units[self._k] = self._unit
