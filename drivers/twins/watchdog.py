"""A virtual controller's communication watchdog (`drivers.heartbeat`: what the real one does),
served by the table and chamber twins.

`TwinWatchdog(spec, clock, act, name)` is armed by a change of the heartbeat register (`fed`, from
the twin's Modbus write); when the register then stays unchanged for `spec.period`, it calls
`act()` (the table stops, the chamber goes to its safe setpoint or stops), logs a warning, keeps
the instant in `trips` and sets `tripped` (the status bit the twin serves) until the next run
command (`rearm`). It is disarmed then, until the heartbeat changes again.

It runs on the twin's own clock, in its own thread: on a real-time clock (`--speed X`) the period
is wall seconds (`drivers.heartbeat.device_wait`); on a stepped (lockstep) clock the armed
watchdog is a member of the clock that sleeps until its deadline, so when the station's process
dies (the clock server drops its member as its socket closes, `drivers.clock_link`) time still
moves to the deadline and the watchdog acts; once it has acted it leaves the clock (a twin alone
does not run ahead). There it joins the clock at the second change of the heartbeat, not the
first: a station in another process takes part in the served clock from its first wait on it,
and its heartbeat writes the second beat after such a wait, so the watchdog never runs time
ahead of a station that has not joined yet.
"""

import logging
import threading

from pymodbus.simulator import DataType, SimData

from drivers.heartbeat import Watchdog, device_now, device_wait

log = logging.getLogger(__name__)


def register_blocks(span: tuple, watchdog: Watchdog | None) -> list:
    """The SimData blocks a twin serves: the register map's read `span` (first, count) and the
    watchdog's heartbeat register when it lies outside it (written only, so not in the span)."""
    first, count = span
    blocks = [SimData(address=first, count=count, values=0, datatype=DataType.REGISTERS)]
    if watchdog is not None and not first <= watchdog.register < first + count:
        beat = SimData(address=watchdog.register, count=1, values=0, datatype=DataType.REGISTERS)
        blocks = sorted([*blocks, beat], key=lambda block: block.address)
    return blocks


class TwinWatchdog:
    """The watchdog `spec` of the twin named `name` on `clock`, doing `act()` on expiry."""

    def __init__(self, spec: Watchdog, clock, act, name: str):
        self.spec, self.clock, self.act, self.name = spec, clock, act, name
        self.value = None  # the heartbeat register's last value
        self.tripped = False
        self.trips = []  # clock instants at which it acted
        self._deadline = None  # armed: the instant (device time, `device_now`) it acts at
        self._changes = 0  # changes of the heartbeat since it last acted
        self._lock = threading.Lock()
        self._armed = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"{name} watchdog", daemon=True)

    def start(self) -> "TwinWatchdog":
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop watching (idempotent)."""
        self._stop.set()
        self._armed.set()
        self.clock.nudge()
        if self._thread.is_alive():
            self._thread.join(5)

    @property
    def armed(self) -> bool:
        """Does it count down (a heartbeat seen since it last acted)?"""
        return self._armed.is_set()

    def fed(self, value: int) -> None:
        """The host wrote `value` to the heartbeat register: a change (re)arms the countdown."""
        with self._lock:
            if value == self.value:
                return
            self.value = value
            self._deadline = device_now(self.clock) + self.spec.period
            self._changes += 1
            if self.clock.realtime or self._changes >= 2:  # lockstep: see the module docstring
                self._armed.set()

    def fill(self, address: int, count: int, start: int, registers: list) -> bool:
        """Serve an access to `count` registers at `address` that is the heartbeat register
        alone: its value put in `registers` (the register image from address `start`), True;
        False for any other access. The physics is not asked: a table's draws its reported
        rate's noise at every look, so a beat at the instant of a poll must not change what the
        poll reads (lockstep: the same session on any host)."""
        if address != self.spec.register or count != 1:
            return False
        registers[address - start] = self.value or 0
        return True

    def rearm(self) -> None:
        """A run command: the tripped bit clears."""
        self.tripped = False

    def _run(self) -> None:
        while not self._stop.is_set():
            self._armed.wait()
            while not self._stop.is_set():
                left = self._left()
                if left is None:
                    break
                if left <= 0 and self._trip():
                    break
                device_wait(self.clock, left, self._stop)
            self.clock.leave()  # not a member of a stepped clock while disarmed

    def _left(self) -> float | None:
        """Seconds until the deadline (None: disarmed)."""
        with self._lock:
            if self._deadline is None:
                self._armed.clear()
                return None
            return self._deadline - device_now(self.clock)

    def _trip(self) -> bool:
        """The heartbeat stopped (unless a beat came meanwhile: False): act, say so, disarm."""
        with self._lock:
            if self._deadline is None or self._deadline > device_now(self.clock):
                return False
            self._deadline, self._changes = None, 0
            self._armed.clear()
        self.tripped = True
        self.trips.append(self.clock.now())
        self.act()
        self.clock.nudge()
        log.warning("%s: no watchdog heartbeat for %g s: %s", self.name, self.spec.period,
                    self.spec.words().split(", ", 1)[1])
        return True
