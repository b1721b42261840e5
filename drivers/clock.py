"""Clocks shared by the recorder and the virtual devices.

`WallClock` is the real monotonic time. `ScaledClock` runs `speed` times faster than the wall, so a
10-minute protocol can be driven through the real drivers in seconds, at the mercy of the host:
a busy host delivers samples late. `SteppedClock` is lockstep time (as PX4's SITL lockstep and
AirSim's SteppableClock keep a flight stack correct however slowly the simulator runs): it stands
still while any thread that takes part has work, so a session on the virtual bench gives the same
samples and the same calibration on any host, and runs as fast as the CPU allows.

Every clock has the same verbs, so devices, recorder and protocols are written once:

- `now()`; `sleep(seconds, stop)`: wait that much clock time (or until the Event `stop` is set);
- `idle(seconds, stop)`: nothing to do until something changes (real time: wait `seconds` of wall
  time and look again);
- `pace(stop)`: a streaming twin's wait before its next delivery;
- `nudge()`: something others may wait for changed (bytes written, samples stored);
- `enlist(thread, producer)`, `leave(thread)`, `watch(probe)`, `unwatch(probe)`: lockstep
  bookkeeping; `sent(link, n)`, `taken(link, n)`, `forget(link)`, `in_flight(link)`: a ledger of
  the bytes a twin wrote to a link (e.g. a pty, whose kernel hands written bytes to the reader's
  side asynchronously: a port can look empty while bytes are on their way) and the reader took;
  no-ops on real-time clocks.

`realtime` says whether wall-time guards (a reply timeout, a lag in wall seconds) mean anything.
"""

import math
import threading
import time

PACE = 0.002
"""Wall seconds a streaming twin waits between two looks at what is due, on a real-time clock."""
REPLY = 0.5
"""Wall seconds a device driver waits for a reply (a Modbus request) on a real-time clock."""
LOCKSTEP_REPLY = 30.0
"""... and on a stepped clock: a reply late because the host is busy is no fault there (time waits
for it), and a request sent again would ask a twin's physics twice."""


def reply_timeout(clock) -> float:
    """Wall seconds a device driver on `clock` waits for a reply."""
    return REPLY if clock.realtime else LOCKSTEP_REPLY


class WallClock:
    """Host monotonic time in seconds."""

    speed = 1.0
    realtime = True

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float, stop: threading.Event | None = None) -> None:
        """Wait `seconds` of this clock (less when `stop` is set meanwhile)."""
        if seconds <= 0:
            return
        if stop is None:
            time.sleep(seconds / self.speed)
        else:
            stop.wait(seconds / self.speed)

    def idle(self, seconds: float, stop: threading.Event | None = None) -> None:
        """Nothing to do now: wait `seconds` of wall time, then look again."""
        if stop is None:
            time.sleep(seconds)
        else:
            stop.wait(seconds)

    def pace(self, stop: threading.Event | None = None) -> None:
        """A streaming twin's wait before it looks at what is due again (`PACE` wall seconds)."""
        self.idle(PACE, stop)

    def nudge(self) -> None:
        """Nothing to do on a real-time clock."""

    def enlist(self, thread=None, producer: bool = False) -> None:
        """Nothing to do on a real-time clock."""

    def leave(self, thread=None) -> None:
        """Nothing to do on a real-time clock."""

    def watch(self, probe) -> None:
        """Nothing to do on a real-time clock."""

    def unwatch(self, probe) -> None:
        """Nothing to do on a real-time clock."""

    def sent(self, link: str, n: int) -> None:
        """Nothing to do on a real-time clock."""

    def taken(self, link: str, n: int) -> None:
        """Nothing to do on a real-time clock."""

    def forget(self, link: str) -> None:
        """Nothing to do on a real-time clock."""

    def in_flight(self, link: str) -> bool:
        """Nothing is kept in flight on a real-time clock."""
        return False


class ScaledClock(WallClock):
    """Simulated time that advances `speed` times faster than the wall clock, starting at
    `start`."""

    def __init__(self, speed: float = 1.0, start: float = 0.0):
        if not (speed > 0 and math.isfinite(speed)):
            raise ValueError(f"clock speed must be positive and finite, got {speed!r}")
        self.speed = float(speed)
        self._start = float(start)
        self._wall0 = time.monotonic()
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._start + (time.monotonic() - self._wall0) * self.speed


class SteppedClock:
    """Lockstep time, starting at `start` (clock seconds).

    The threads that take part (`enlist`: the station's protocol and readers, the twins' streamers;
    a thread that waits on the clock takes part from then on) each either work or wait: `sleep`
    until an instant, or `idle` until something changes. Time moves only when every one of them
    waits and no probe (`watch`: e.g. a serial port's unread bytes) reports data in flight; it
    then jumps to the earliest instant a sleeper waits for, and every idle thread looks again.
    `nudge()` (bytes written, samples stored) wakes the idle threads at once, so a waiter always
    sees, before time moves on, what the others did at this instant: the order in which the host
    runs the threads cannot change what happens at any clock time.

    Time stands still while no station thread (a member that is not a `producer`) takes part:
    a twin alone does not run ahead of the session it serves.

    step     : clock seconds between two deliveries of a streaming twin (`pace`): the host latency
               of the virtual bench, one step at most
    backstop : wall seconds after which a waiting thread looks again whether time can move (a
               probe cleared by a thread that does not take part, e.g. python-can's notifier)
    """

    realtime = False
    speed = math.inf
    lost = None  # the error every wait raises once the time's source is gone (a remote clock)

    def __init__(self, start: float = 0.0, step: float = 0.25, backstop: float = 0.05):
        if not (step > 0 and math.isfinite(step) and math.isfinite(start)):
            raise ValueError(f"a stepped clock needs a finite start and a positive step, got "
                             f"start {start!r}, step {step!r}")
        self.step, self.backstop = float(step), float(backstop)
        self._t = float(start)
        self._lock = threading.RLock()  # `with self._lock`, never `with self._cond` (_wait)
        self._cond = threading.Condition(self._lock)
        self._members = {}  # thread -> producer?
        self._waiting = {}  # thread -> the instant it sleeps until (None: idle)
        self._probes = []
        self._ledger = {}  # link -> bytes sent minus bytes taken
        self._nudges = 0  # nudges so far
        self._seen = {}  # thread -> `_nudges` when it last stopped waiting
        self._flight = (None, -math.inf)  # what the last wake for data in flight saw, and when

    def now(self) -> float:
        return self._t

    # -- who takes part ----------------------------------------------------------------------

    def enlist(self, thread=None, producer: bool = False) -> None:
        """`thread` (default: the calling one) takes part; a `producer` (a twin's streamer)
        alone does not make time move."""
        with self._lock:
            self._members[thread or threading.current_thread()] = producer

    def leave(self, thread=None) -> None:
        """`thread` (default: the calling one) no longer takes part."""
        with self._lock:
            thread = thread or threading.current_thread()
            self._members.pop(thread, None)
            self._waiting.pop(thread, None)
            self._move_if_quiet()

    def watch(self, probe) -> None:
        """Keep time still while `probe()` is true (data in flight that a member will take)."""
        with self._lock:
            self._probes.append(probe)

    def unwatch(self, probe) -> None:
        """Forget `probe` (the reader that takes its data stopped)."""
        with self._lock:
            if probe in self._probes:
                self._probes.remove(probe)
            self._move_if_quiet()

    # -- the ledger of links --------------------------------------------------------------------

    def sent(self, link: str, n: int) -> None:
        """A twin wrote `n` bytes to `link` (the name both ends know, e.g. the port's path)."""
        with self._lock:
            self._ledger[link] = self._ledger.get(link, 0) + n

    def taken(self, link: str, n: int) -> None:
        """The reader of `link` took `n` bytes (perhaps before the twin's `sent` is booked)."""
        with self._lock:
            self._ledger[link] = self._ledger.get(link, 0) - n

    def forget(self, link: str) -> None:
        """The reader (re)opened `link`, dropping what was sent before (pyserial flushes the
        input on open)."""
        with self._lock:
            self._ledger[link] = 0

    def in_flight(self, link: str) -> bool:
        """Has `link` bytes sent and not taken yet?"""
        return self._ledger.get(link, 0) > 0

    # -- waiting -----------------------------------------------------------------------------

    def sleep(self, seconds: float, stop: threading.Event | None = None) -> None:
        """Wait until `seconds` from now (or until `stop` is set)."""
        if seconds > 0:
            self._wait(self._t + seconds, stop)

    def idle(self, seconds: float = 0.0, stop: threading.Event | None = None) -> None:
        """Wait until something changes: a nudge or a move of time (`seconds` is for real-time
        clocks)."""
        self._wait(None, stop)

    def pace(self, stop: threading.Event | None = None) -> None:
        """Wait until the next multiple of `step` (a streaming twin's next delivery)."""
        self._wait((math.floor(self._t / self.step + 1e-9) + 1) * self.step, stop)

    def nudge(self) -> None:
        """Something changed: every idle member looks again before time moves (one that was
        working meanwhile looks again at once when it next idles)."""
        with self._lock:
            self._nudges += 1
            self._wake(lambda until: until is None)

    def _wait(self, until, stop) -> None:
        """Wait as a member (`sleep`, `idle`, `pace`).

        A Ctrl-C or `kill` raises KeyboardInterrupt in the main thread between any two bytecodes
        (`station.acquire.interrupts`), also in the middle of this: the thread then works again
        (not left among the waiters, where time would move while it handles the interrupt), and
        the lock is never left held. That is why every `with` here takes `_lock` (a C lock, taken
        with no Python frame in between) and never `_cond`: `Condition.__enter__` is Python, and a
        KeyboardInterrupt raised once it had taken the lock left it taken for good (measured: 1
        `station record` in about 300 interrupted at a position's start hung, its reader thread
        waiting for the lock that the main thread, joining it, held)."""
        me = threading.current_thread()
        with self._lock:
            self._members.setdefault(me, False)
            if until is None and self._seen.get(me) != self._nudges:
                self._seen[me] = self._nudges  # nudged while it worked: look again first
                return
            self._waiting[me] = None if until is None else float(until)  # not a numpy scalar
            try:
                self._move_if_quiet()
                while me in self._waiting:
                    if self.lost is not None:
                        raise self.lost
                    if stop is not None and stop.is_set():
                        return
                    self._cond.wait(self.backstop)
                    self._move_if_quiet()
                self._seen[me] = self._nudges
            finally:
                if me in self._waiting:  # stopped, lost or interrupted: it works from now on
                    del self._waiting[me]
                    self._move_if_quiet()

    def advance_to(self, instant: float) -> None:
        """Move time forward to `instant` at once, if it is later (a resumed session goes on after
        its last recorded instant); the sleepers it passes wake."""
        with self._lock:
            if instant > self._t:
                self._t = float(instant)
                self._wake(lambda until: until is None or until <= self._t)

    def _wake(self, which, flight: bool = False) -> list:
        """Wake the waiting members for which `which(until)` is true (they work from now on); a
        member in another process (`drivers.clock_link`) is told the time, and whether data is in
        flight. Returns those woken."""
        woken = [m for m, until in self._waiting.items()
                 if which(until) or (getattr(m, "idle", False) and which(None))]
        for member in woken:
            del self._waiting[member]
            if hasattr(member, "wake"):
                self._seen[member] = self._nudges
                member.wake(self._t, flight)
        if woken:
            self._cond.notify_all()
        return woken

    def _move_if_quiet(self) -> None:
        """With the lock held: move time to the earliest instant a sleeper waits for, once every
        member waits and nothing is in flight (see the class docstring)."""
        self._forget_ended()
        if any(t not in self._waiting for t in self._members) or all(self._members.values()):
            return
        if any(_busy(probe) for probe in self._probes):
            self._wake_for_flight()
            return
        instants = [until for until in self._waiting.values() if until is not None]
        if not instants:
            return
        self._t = max(self._t, min(instants))
        self._wake(lambda until: until is None or until <= self._t)

    def _forget_ended(self) -> None:
        """With the lock held: forget the members that ended without leaving (`_ended`)."""
        for member in _ended(self._members):
            del self._members[member]
            self._waiting.pop(member, None)
            self._seen.pop(member, None)

    def _wake_for_flight(self) -> None:
        """With the lock held, data in flight: wake the idle members, a reader has data to take.
        Once per change (a nudge, a move of time, bytes sent or taken), or after `backstop` wall
        seconds: a member with nothing to do with the data (a fixture waiting for a command)
        would otherwise spin, taking the CPU from the reader (perhaps in another process, on a
        busy host) while it takes the bytes."""
        seen, now = (self._nudges, self._t, tuple(self._ledger.items())), time.monotonic()
        if seen == self._flight[0] and now - self._flight[1] < self.backstop:
            return
        self._flight = (seen, now)
        self._wake(lambda until: until is None, flight=True)


def _ended(members) -> list:
    """The members that ran and ended: a thread that started and no longer runs (one enlisted
    before its start has not), another process's member (`drivers.clock_link`) that says so.

    Not `Thread.is_alive()`: in Python 3.11 a KeyboardInterrupt landing inside it (right after
    its try to take the thread's own lock) releases that lock (bpo-45274's repair) and marks the
    live thread stopped, so the clock forgot a live member and `join` no longer waited for it."""
    running = set(threading.enumerate())
    return [m for m in members if (m.ident is not None and m not in running
                                   if isinstance(m, threading.Thread) else not m.is_alive())]


def _busy(probe) -> bool:
    """A probe's answer; one that fails (its port closed meanwhile) has nothing in flight."""
    try:
        return bool(probe())
    except Exception:  # noqa: BLE001 - a closing device must not stop the clock
        return False
