"""A controller's communication watchdog and the host's heartbeat that feeds it.

Industrial controllers stop on a loss of communication: the host writes a changing counter to a
holding register (the heartbeat) and, when that register has not changed for `period` seconds,
the controller acts by itself (a Modbus "communication timeout"). The rotary table then stops
(`stop`); the thermal chamber goes to a safe setpoint and keeps conditioning (`safe`) or stops
(`off`). A killed, hung or disconnected station so never leaves the table turning or the chamber
at a campaign's setpoint.

`Watchdog` is the `[table.watchdog]` / `[chamber.watchdog]` section of a device profile (parsed
with `Watchdog.parse`; docs/devices.md "Watchdog"); `Heartbeat` is the thread that writes the
counter while a session or campaign holds the device (`RotaryTable.heartbeat`,
`ThermalChamber.heartbeat`).

Time: on a real-time clock (a real bench, or a twin at `--speed X`) the watchdog's period is wall
seconds, as a controller's timer is (a scaled clock runs the physics faster, not the timer, so a
busy host does not trip it); on a stepped (lockstep) clock it is clock seconds and the heartbeat
is a member of the clock (a producer), so time cannot move past a beat the station has not
written (`device_now`, `device_wait`).
"""

import logging
import math
import threading
import time
from dataclasses import dataclass

from drivers.errors import DeviceError, ProfileError

log = logging.getLogger(__name__)

ACTIONS = {"table": ("stop",), "chamber": ("safe", "off")}
"""What each device's controller can do when its watchdog expires."""
BEATS_PER_PERIOD = 3
"""Heartbeats written per watchdog period: two may be lost or late before the controller acts."""
COUNTER = 1 << 16  # the counter wraps in its uint16 register


@dataclass(frozen=True)
class Watchdog:
    """The watchdog of a controller (addresses 0-based, as on the wire).

    register      : the holding register the host writes the heartbeat counter to (uint16)
    period        : s without a change of that register after which the controller acts
    action        : "stop" (table); "safe" (chamber: go to `safe_setpoint` and hold it) or "off"
                    (chamber: stop conditioning)
    tripped_bit   : bit of the status register the controller sets when its watchdog acted
                    (cleared by the next run command)
    safe_setpoint : K, the chamber's setpoint for the action "safe" (None otherwise)
    """

    register: int
    period: float
    action: str
    tripped_bit: int
    safe_setpoint: float | None = None

    def __post_init__(self):
        if not 0 <= self.register <= 0xFFFF:
            raise ProfileError(f"register: must be an address 0..65535, got {self.register!r}")
        if not (math.isfinite(self.period) and 0 < self.period <= 3600):
            raise ProfileError(f"period: must be a finite number of seconds in (0, 3600], got "
                               f"{self.period!r}")
        if not 0 <= self.tripped_bit < 16:
            raise ProfileError(f"tripped_bit: must be a status bit 0..15, got "
                               f"{self.tripped_bit!r}")
        if (self.action == "safe") != (self.safe_setpoint is not None):
            raise ProfileError("safe_setpoint: give it (K) with action = \"safe\", and only then")
        if self.safe_setpoint is not None and not (math.isfinite(self.safe_setpoint)
                                                   and self.safe_setpoint > 0):
            raise ProfileError(f"safe_setpoint: must be a positive number of kelvin, got "
                               f"{self.safe_setpoint!r}")

    @classmethod
    def parse(cls, s, device: str) -> "Watchdog":
        """Build from the `[<device>.watchdog]` Section `s` (`drivers.profile.Section`) of a
        "table" or "chamber"; a ProfileError names the file, the section and the key."""
        fields = {"register": s.get("register", int), "period": s.get("period", float),
                  "action": s.get("action", str, choices=ACTIONS[device]),
                  "tripped_bit": s.get("tripped_bit", int),
                  "safe_setpoint": s.get("safe_setpoint", float, default=None)}
        s.finish()
        try:
            return cls(**fields)
        except ProfileError as exc:
            raise ProfileError(f"{s.source}: [{s.name}] {exc}") from None

    @property
    def beat(self) -> float:
        """Seconds between two heartbeats."""
        return self.period / BEATS_PER_PERIOD

    def words(self) -> str:
        """The watchdog in words, for the live view and messages."""
        if self.action == "safe":
            action = f"sends the chamber to {self.safe_setpoint:.2f} K"
        else:
            action = "stops the table" if self.action == "stop" else "stops the chamber"
        return f"period {self.period:g} s, {action}"


def device_now(clock) -> float:
    """Seconds on the watchdog's time base (module docstring): wall on a real-time clock."""
    return time.monotonic() if clock.realtime else clock.now()


def device_wait(clock, seconds: float, stop: threading.Event) -> None:
    """Wait `seconds` on the watchdog's time base, or until `stop` is set; on a stepped clock as
    a member of it (time moves to the end of the wait once every member waits)."""
    if clock.realtime:
        stop.wait(max(seconds, 0.0))
    else:
        clock.sleep(seconds, stop)


class Heartbeat:
    """Write a changing counter with `write(count)` every `watchdog.beat` seconds while entered,
    the first before `__enter__` returns (the controller is armed before the device is used; a
    failure then is raised). The count goes on from the register's value (`read()`), so the
    first beat changes it too: a station restarted after a kill does not write the value the
    killed one left, which the controller would not count as a beat. A later write that fails
    (a `DeviceError` after the driver's retries) is told to `on_error(error)`, once per run of
    failures, and the beats go on (a link that comes back is fed again). On a stepped clock the
    thread takes part in it (enlisted before it starts) as a producer: time does not move past
    its next beat while it works, but it alone does not move time either (a station whose
    protocol has not started yet holds the clock still, as before)."""

    def __init__(self, read, write, watchdog: Watchdog, clock, on_error, name: str):
        self.read, self.write, self.watchdog, self.clock = read, write, watchdog, clock
        self.on_error, self.name = on_error, name
        self.beats = 0  # counters written
        self._count = 0  # the last counter written (or read)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"{name} heartbeat", daemon=True)

    def __enter__(self) -> "Heartbeat":
        try:
            self._count = self.read()
            self._beat()
        except DeviceError as error:
            self._said(error)
            raise
        self.clock.enlist(self._thread, producer=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self.clock.nudge()
        self._thread.join()

    def _beat(self) -> None:
        """Write the next counter."""
        count = (self._count + 1) % COUNTER
        self.write(count)
        self._count, self.beats = count, self.beats + 1

    def _said(self, error: DeviceError) -> DeviceError:
        """`error` with a note on what a missing heartbeat means."""
        error.add_note(f"the {self.name}'s watchdog heartbeat could not be written: without it "
                       f"the controller acts within {self.watchdog.period:g} s "
                       f"({self.watchdog.words()})")
        return error

    def _run(self) -> None:
        failing = False
        try:
            while True:
                device_wait(self.clock, self.watchdog.beat, self._stop)
                if self._stop.is_set():
                    return
                try:
                    self._beat()
                    failing = False
                except DeviceError as error:
                    if not failing:
                        log.warning("%s", self._said(error))
                        self.on_error(error)
                    failing = True
        except DeviceError as lost:  # the lockstep clock is gone (ClockLinkError): no more beats
            if not self._stop.is_set():
                self.on_error(lost)
