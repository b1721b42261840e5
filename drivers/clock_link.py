"""Lockstep time across processes: `station twin` and `station record` on one stepped clock.

The process that runs the twins owns the `drivers.clock.SteppedClock` and serves it on a Unix socket
(`ClockServer`; its path goes in the bench profile as `[bench] lockstep`). A station connects with
`connect(path)`: in the twin's own process that is the served clock itself (the in-process twins of
the tests), elsewhere a `RemoteClock`, a stepped clock whose threads take part in the served one as
one member. The remote side reports, one line each, when all its threads wait (`WAIT <instant or
none> <1 if one of them idles>`), when one works again (`WORK`), whether it takes part at all
(`JOIN`, `LEAVE`: a station with no thread on the clock does not hold time), the bytes its reader
took from a link (`TAKEN <link> <n>`), a link it (re)opened (`FORGET <link>`) and a resumed
session's start (`START <instant>`). The server answers `TIME <instant> <in flight>` whenever it
wakes the remote side: time moved to its instant, or the remote side has something to look at (a
nudge, bytes on their way); `STARTED <instant> 0` answers a `START`. Time never moves while the
remote side works, so both processes see the same instants in the same order, on any host.
"""

import contextlib
import os
import socket
import tempfile
import threading

from drivers.clock import SteppedClock
from drivers.errors import LinkError

SERVED = {}
"""{socket path: SteppedClock} served by this process (`connect` hands them out directly)."""


class ClockLinkError(LinkError):
    """The lockstep clock of the virtual bench cannot be reached, or its process ended."""


class ClockServer:
    """Serve `clock` at a new socket path (`path`) until `close()`; registered in `SERVED`."""

    def __init__(self, clock: SteppedClock):
        self.clock = clock
        self._dir = tempfile.mkdtemp(prefix="lockstep-")
        self.path = os.path.join(self._dir, "clock.sock")
        self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._socket.bind(self.path)
        self._socket.listen()
        self._remotes = []
        SERVED[self.path] = clock
        self._thread = threading.Thread(target=self._accept, name="clock server", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop serving: the remote sides see the link end."""
        SERVED.pop(self.path, None)
        with contextlib.suppress(OSError):
            self._socket.shutdown(socket.SHUT_RDWR)
        self._socket.close()
        for remote in list(self._remotes):
            remote.close()
        self._thread.join(5)
        with contextlib.suppress(OSError):
            os.unlink(self.path)
            os.rmdir(self._dir)

    def _accept(self) -> None:
        while True:
            try:
                connection, _ = self._socket.accept()
            except OSError:  # closed
                return
            remote = _Remote(self.clock, connection)
            self._remotes.append(remote)
            threading.Thread(target=remote.serve, name="clock link", daemon=True).start()


class _Remote:
    """One connected station process: a member of the served clock while it takes part."""

    idle = False  # one of its threads idles: a nudge wakes it too

    def __init__(self, clock: SteppedClock, connection: socket.socket):
        self.clock, self.connection = clock, connection
        self._open = True
        self._links = {}  # link -> the probe kept while this station reads it

    def is_alive(self) -> bool:
        """Is the station process still connected? (`drivers.clock._ended` asks.)"""
        return self._open

    def wake(self, instant: float, flight: bool) -> None:
        """Tell the remote side the time (it works from now on); called with the lock held."""
        self._send(f"TIME {instant!r} {int(flight)}")

    def close(self) -> None:
        self._open = False
        with contextlib.suppress(OSError):
            self.connection.shutdown(socket.SHUT_RDWR)

    def serve(self) -> None:
        """Hello (the time), then each line the remote side sends, until it hangs up."""
        c = self.clock
        with c._lock:
            self._send(f"TIME {c.now()!r} 0")
        try:
            for line in self.connection.makefile("r", encoding="ascii"):
                self._handle(line.split())
        except (OSError, ValueError):
            pass
        finally:
            self._open = False
            with c._lock:
                c._members.pop(self, None)
                c._waiting.pop(self, None)
                c._seen.pop(self, None)
                for probe in self._links.values():
                    c._probes.remove(probe)
                self._links.clear()
                c._move_if_quiet()
            self.connection.close()

    def _handle(self, words: list) -> None:
        c, kind = self.clock, words[0] if words else ""
        with c._lock:
            if kind == "JOIN":
                c._members[self] = False
            elif kind == "LEAVE":
                c._members.pop(self, None)
                c._waiting.pop(self, None)
            elif kind == "WAIT":
                self.idle = words[2] == "1"
                if self.idle and c._seen.get(self) != c._nudges:
                    c._seen[self] = c._nudges  # nudged while it worked: look again first
                    self._send(f"TIME {c._t!r} 0")
                    return
                c._waiting[self] = None if words[1] == "none" else float(words[1])
            elif kind == "WORK":
                c._waiting.pop(self, None)
            elif kind == "TAKEN":
                c._ledger[words[1]] = c._ledger.get(words[1], 0) - int(words[2])
            elif kind == "FORGET":
                link = words[1]
                c._ledger[link] = 0
                if link not in self._links:
                    self._links[link] = lambda: c.in_flight(link)
                    c._probes.append(self._links[link])
            elif kind == "START":
                instant = float(words[1])
                if instant > c._t:
                    c._t = instant
                    c._wake(lambda until: until is not None and until <= c._t)
                self._send(f"STARTED {c._t!r} 0")
                return
            else:
                raise ValueError(f"unknown lockstep message {words!r}")
            c._move_if_quiet()

    def _send(self, line: str) -> None:
        try:
            self.connection.sendall(line.encode("ascii") + b"\n")
        except OSError:
            self._open = False


class RemoteClock(SteppedClock):
    """A stepped clock whose time is the served one's at `path` (module docstring): its threads
    wait and nudge locally; the process as a whole takes part in the served clock."""

    def __init__(self, path: str):
        super().__init__()
        self.path = path
        self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self._socket.connect(path)
        except OSError as exc:
            raise ClockLinkError(
                f"cannot reach the virtual bench's lockstep clock at {path} ({exc}); start "
                "`station twin` and use the bench profile it writes") from exc
        self._lines = self._socket.makefile("r", encoding="ascii")
        self._joined, self._reported, self._flight = False, None, False
        self._starts = 0  # `STARTED` answers so far
        self._t = self._read_time()
        threading.Thread(target=self._receive, name="clock link", daemon=True).start()

    def close(self) -> None:
        """Hang up (the served clock forgets this process)."""
        with contextlib.suppress(OSError):
            self._socket.shutdown(socket.SHUT_RDWR)

    # -- what the served clock decides --------------------------------------------------------

    def advance_to(self, instant: float) -> None:
        """Ask the served clock to move forward to `instant` (a resumed session's start); returns
        once it has answered (so it has also booked every line sent before). Waits on the lock's
        condition, not an Event: see `SteppedClock._wait` on a Ctrl-C inside `with`."""
        with self._lock:
            answered = self._starts + 1
            self._send(f"START {instant!r}")
            while self._starts < answered:
                if self.lost is not None:
                    raise self.lost
                self._cond.wait(self.backstop)

    def in_flight(self, link: str) -> bool:
        """Did the served clock say bytes are on their way to this process's readers, and has
        no reader taken any since? (It says so again, if need be, once told.)"""
        return self._flight

    def taken(self, link: str, n: int) -> None:
        if n:
            with self._lock:
                self._flight = False
                self._send(f"TAKEN {link} {n}")

    def forget(self, link: str) -> None:
        with self._lock:
            self._send(f"FORGET {link}")

    def _read_time(self) -> float:
        """The instant of the next `TIME` line (a `STARTED` one on the way is counted)."""
        while True:
            words = self._lines.readline().split()
            if len(words) != 3 or words[0] not in ("TIME", "STARTED"):
                raise ClockLinkError(f"{self.path} is not a lockstep clock (got {words!r})")
            if words[0] == "TIME":
                self._flight = words[2] == "1"
                return float(words[1])
            with self._lock:
                self._t = max(self._t, float(words[1]))
                self._starts += 1
                self._cond.notify_all()

    def _receive(self) -> None:
        """The served clock's wake-ups, until the link ends."""
        try:
            while True:
                instant = self._read_time()
                with self._lock:
                    self._t, self._reported = max(self._t, instant), None
                    super()._wake(lambda until: until is None or until <= self._t)
                    self._report()
        except (OSError, ValueError, ClockLinkError) as exc:
            with self._lock:
                why = str(exc) or "the twin process ended"
                self.lost = ClockLinkError(
                    f"the virtual bench's lockstep clock at {self.path} is gone ({why}); check "
                    "`station twin`, then resume the session")
                self._cond.notify_all()

    # -- this process's threads ---------------------------------------------------------------

    def _wake(self, which, flight: bool = False) -> list:
        """A local wake-up (a nudge): the served clock must not move while they work."""
        woken = super()._wake(which, flight)
        if woken and self._reported is not None:
            self._send("WORK")
            self._reported = None
        return woken

    def _move_if_quiet(self) -> None:
        """Report to the served clock instead of moving time (module docstring)."""
        if self.lost is not None:
            self._cond.notify_all()
            return
        self._report()

    def _report(self) -> None:
        self._forget_ended()
        consumers = not all(self._members.values())
        if consumers != self._joined:
            self._send("JOIN" if consumers else "LEAVE")
            self._joined, self._reported = consumers, None
        if not consumers:
            return
        if any(t not in self._waiting for t in self._members):
            if self._reported is not None:
                self._send("WORK")
                self._reported = None
            return
        if any(_probe(p) for p in self._probes):
            self._wake(lambda until: until is None)
            return
        instants = [until for until in self._waiting.values() if until is not None]
        idle = any(until is None for until in self._waiting.values())
        report = f"{min(instants)!r} {int(idle)}" if instants else f"none {int(idle)}"
        if report != self._reported:
            self._flight = False
            self._send(f"WAIT {report}")
            self._reported = report

    def _send(self, line: str) -> None:
        try:
            self._socket.sendall(line.encode("ascii") + b"\n")
        except OSError as exc:
            self.lost = self.lost or ClockLinkError(
                f"the virtual bench's lockstep clock at {self.path} is gone ({exc})")


def _probe(probe) -> bool:
    try:
        return bool(probe())
    except Exception:  # noqa: BLE001 - a closing device must not stop the clock
        return False


def connect(path: str, start: float | None = None) -> SteppedClock:
    """The lockstep clock served at `path`: this process's own (`SERVED`) or a `RemoteClock`;
    moved forward to `start` when given (a resumed session)."""
    clock = SERVED.get(path) or RemoteClock(path)
    if start is not None:
        clock.advance_to(start)
    return clock
