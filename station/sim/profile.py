"""Commanded rate profile of the rotary table: piecewise-linear rate, exact angle.

A position of the rotary protocol is: rest (static window), spin-up with bounded acceleration,
settle, steady rate (rotating window), spin-down. The angle is the exact integral of the
piecewise-linear rate, so whole revolutions can be cut without integration error.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Profile:
    """Rate through the knots (times, rates), linear in between, zero angle at times[0]."""

    times: tuple
    rates: tuple

    def rate(self, t: np.ndarray) -> np.ndarray:
        """Rate at times t (rad/s); held at the end values outside the knots."""
        return np.interp(t, self.times, self.rates)

    def angle(self, t: np.ndarray) -> np.ndarray:
        """Integral of the rate from times[0] to t (rad), exact for the piecewise-linear rate."""
        tk, rk = np.asarray(self.times, float), np.asarray(self.rates, float)
        area = np.concatenate([[0.0], np.cumsum(0.5 * (rk[1:] + rk[:-1]) * np.diff(tk))])
        t = np.asarray(t, float)
        i = np.clip(np.searchsorted(tk, t, side="right") - 1, 0, len(tk) - 1)
        dt = t - tk[i]
        return area[i] + dt * 0.5 * (rk[i] + self.rate(t))


@dataclass(frozen=True)
class RotaryTiming:
    """Durations of one position of the rotary protocol (s) and the commanded motion.

    rate : commanded steady rate c_cmd, rad/s.
    max_accel : bound on the table's acceleration, rad/s^2 (spin-up/down last rate/max_accel).
    static : duration of the rest window before spinning, s.
    moving : spin-up + settle + steady + spin-down, s.
    settle : wait after reaching the rate before the rotating window, s.
    """

    rate: float = np.pi / 2
    max_accel: float = 1.0
    static: float = 10.0
    moving: float = 25.0
    settle: float = 1.0

    def __post_init__(self):
        if not (self.rate != 0 and self.max_accel > 0 and self.static > 0 and self.settle >= 0):
            raise ValueError(
                "rotary timing needs a non-zero rate, positive max_accel and static "
                "time, non-negative settle time"
            )
        if self.steady <= 0:
            raise ValueError(
                f"moving time {self.moving} s leaves no steady rotation after spin-up, "
                f"settle and spin-down ({self.moving - self.steady:.3f} s); "
                "lengthen it or raise max_accel"
            )

    @property
    def ramp(self) -> float:
        """Duration of the spin-up (and of the spin-down), s."""
        return abs(self.rate) / self.max_accel

    @property
    def steady(self) -> float:
        """Duration of the rotating window before it is cut to whole revolutions, s."""
        return self.moving - 2 * self.ramp - self.settle

    def profile(self) -> Profile:
        """The commanded trapezoid: rest, ramp up, constant rate, ramp down to rest."""
        t_up = self.static + self.ramp
        t_down = self.static + self.moving - self.ramp
        return Profile(
            (0.0, self.static, t_up, t_down, self.static + self.moving),
            (0.0, 0.0, self.rate, self.rate, 0.0),
        )

    def segments(self, fs: float) -> dict:
        """[start, stop) sample indices of each phase for samples at i / fs."""
        edges = np.cumsum([0.0, self.static, self.ramp, self.settle, self.steady, self.ramp])
        idx = np.ceil(np.round(edges * fs, 9)).astype(int)
        names = ("static", "spinup", "settle", "rotating", "spindown")
        return {name: (int(idx[i]), int(idx[i + 1])) for i, name in enumerate(names)}

    def samples(self, fs: float) -> int:
        """Number of samples of one position."""
        return round((self.static + self.moving) * fs)
