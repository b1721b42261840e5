"""One session per bench at a time, whatever the number of browsers: `BenchSession`.

A browser starts a session on one of the bench profiles the server was given (by its name: a
browser never names a file) for a unit serial it typed or scanned; the session runs in a thread
of its own with the very code `station record` runs (`station.acquire.bench.record`, the kind's
protocol of `station.protocols.KINDS`), the technician being a `BrowserOperator` and the view a
`BrowserView`. Every browser sees the same session and may answer its questions; a second start
while one runs is refused (`BenchBusyError`).

Pause and Abort reach the protocol as the terminal's Ctrl-C does (`station.acquire.interrupts`:
its next poll of the devices raises, and a question it waits on raises): the protocol stops the
table at once and records an `abort` event; the session file keeps the positions completed.
Paused, the session goes on with `resume` (`station.acquire.bench.resume`, as `station resume`):
the position under way when it was paused is recorded again. An aborted or failed session, or one
a killed server left, is resumed the same way by its name in the sessions folder.

A session that completed is concluded by `conclude(path) -> dict` (the command's: the calibration
file, its verdict, the report, the exports, the record store), whose result every browser gets.
"""

import dataclasses
import logging
import threading
import time
from pathlib import Path

from station.errors import InputError, OperatorAbort, SessionPaused, StationError
from station.serve.operator import BrowserOperator
from station.serve.watch import BrowserView
from station.session.units import SERIAL

log = logging.getLogger(__name__)

SESSION_FILE = r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}-\d{8}-\d{6}\.h5"
"""The names of the session files the server writes (<unit serial>-<date>-<time>.h5)."""


class BenchBusyError(StationError):
    """A session already runs on the bench: one at a time."""


class Stopped:
    """Why a browser stopped the session: the error the protocol raises, and the state after."""

    def __init__(self, error: BaseException, state: str):
        self.error, self.state = error, state


class BenchSession:
    """The bench's one session, started, watched and stopped from any browser.

    profiles : {name: bench profile path} a browser may pick from
    folder   : where session files are written (and the only files served)
    conclude : path -> dict, run once a session completed (the calibration, its verdict, ...)
    """

    def __init__(self, profiles: dict, folder, conclude):
        self.profiles = dict(profiles)
        self.folder = Path(folder)
        self.conclude = conclude
        self.state = "idle"  # running, concluding, done, paused, aborted, failed
        self.profile = self.serial = self.path = None
        self.error = self.result = None
        self.operator = BrowserOperator()
        self.view = None
        self._stop = None
        self._thread = None
        self._lock = threading.Lock()

    # -- what a browser asks for -----------------------------------------------------------------

    def start(self, profile: str, serial: str) -> None:
        """Record a new session of unit `serial` on the bench profile named `profile`."""
        bench = self.bench(profile, serial)
        path = self.folder / f"{serial}-{time.strftime('%Y%m%d-%H%M%S')}.h5"
        self._launch(profile, bench, path, fresh=True)

    def resume(self, session: str | None = None) -> None:
        """Go on with the paused session, or with the session file named `session` in the folder
        (aborted, failed or left by a killed server), on its bench profile."""
        from station.session import Session

        if session is None:
            if self.state not in ("paused", "aborted", "failed") or self.path is None:
                raise InputError("no paused session to resume; name a session of the folder")
            path, profile = self.path, self.profile
        else:
            path = self.session_file(session)
        with Session.open(path) as recorded:
            serial = recorded.metadata.get("unit_serial", "")
            source = (recorded.metadata.get("bench") or {}).get("profile")
        if session is not None:
            profile = self.profile_of(source, session)
        self._launch(profile, self.bench(profile, serial), path, fresh=False)

    def profile_of(self, source, session: str) -> str:
        """The name of the bench profile a session was recorded with (its metadata's path);
        InputError when the server was not given it."""
        for name, path in self.profiles.items():
            if source and Path(path).resolve() == Path(source).resolve():
                return name
        raise InputError(f"session {session} was recorded with the bench profile {source}; "
                         "start `station serve` with that --profile to resume it")

    def pause(self) -> None:
        """Stop the running session so that it can be resumed (the table stopped)."""
        self._halt(Stopped(SessionPaused("paused from the browser: the table is stopped; "
                                         "Resume goes on with the position under way"), "paused"))

    def abort(self) -> None:
        """End the running session now (the table stopped; the file keeps what was completed)."""
        self._halt(Stopped(OperatorAbort("aborted from the browser: the table is stopped"),
                           "aborted"))

    def answer(self, ask_id: int, value: str) -> bool:
        """A browser's answer to the question the protocol waits on."""
        return self.operator.answer(ask_id, value)

    def close(self, timeout: float = 60.0) -> None:
        """Abort a running session and wait for its thread (the server stops)."""
        if self.running():
            self.abort()
        if self._thread is not None:
            self._thread.join(timeout)

    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def snapshot(self, since: int = 0) -> dict:
        """What every browser shows, with the plot points after `since` (`BrowserView`)."""
        with self._lock:
            shown = {"state": self.state, "profile": self.profile, "serial": self.serial,
                     "session": None if self.path is None else self.path.name,
                     "error": self.error, "result": self.result,
                     "asked": self.operator.asked, "messages": list(self.operator.messages)}
            view = self.view
        shown["view"] = None if view is None else view.snapshot(since)
        return shown

    # -- checks ----------------------------------------------------------------------------------

    def bench(self, profile: str, serial: str):
        """The bench profile named `profile` (`BenchProfile`) for unit `serial`; InputError naming
        the problem for anything a browser may send."""
        from station.acquire.bench import BenchProfile

        path = self.profile_path(profile)
        if not isinstance(serial, str) or not SERIAL.match(serial):
            raise InputError(f"unit serial {serial!r}: give 1-64 letters, digits, '.', '_' or '-' "
                             "(scan the unit's barcode or type it)")
        bench = BenchProfile.load(path)
        if bench.plate:
            raise InputError(f"bench profile {profile!r} has several units, each with the serial "
                             "its profile gives; record it with `station record`")
        if bench.chamber is not None:
            raise InputError(f"bench profile {profile!r} runs a thermal campaign; record it with "
                             "`station record`")
        return dataclasses.replace(bench, unit_serial=serial)

    def profile_path(self, name: str) -> Path:
        """The bench profile a browser names; InputError naming the ones to choose from."""
        if not isinstance(name, str) or name not in self.profiles:
            raise InputError(f"no bench profile {name!r}; choose one of "
                             f"{', '.join(self.profiles)}")
        return self.profiles[name]

    def session_file(self, name: str) -> Path:
        """The session file `name` in the folder; InputError for any other name."""
        import re

        if not isinstance(name, str) or not re.fullmatch(SESSION_FILE, name) or \
                not (self.folder / name).is_file():
            raise InputError(f"no session {name!r} in {self.folder}; choose one the page lists")
        return self.folder / name

    # -- the session's thread --------------------------------------------------------------------

    def _launch(self, profile: str, bench, path: Path, fresh: bool) -> None:
        """Run the session in its thread, unless one runs."""
        with self._lock:
            if self.running() or self.state == "concluding":
                raise BenchBusyError(f"a session of unit {self.serial} runs on this bench; "
                                     "one at a time: watch it, or abort it first")
            self.operator = BrowserOperator()
            self.view = None
            self.state, self.profile, self.serial, self.path = "running", profile, \
                bench.unit_serial, path
            self.error = self.result = self._stop = None
            self._thread = threading.Thread(target=self._run, args=(bench, path, fresh),
                                            name="bench-session")
            self._thread.start()

    def _watch(self, bench, done: int = 0) -> BrowserView:
        """The session's view (on the protocol's clock once it follows it), `done` positions
        completed before; kept where the browsers read it."""
        from drivers.clock import WallClock
        from station.acquire.bench import watchdog_shown
        from station.session import StreamSpec

        spec = StreamSpec.from_profile(bench.imu.imu)
        view = BrowserView(WallClock(), spec.counts_per_unit, spec.channels,
                           watchdog=watchdog_shown(bench))
        view.done = list(range(done))
        with self._lock:
            self.view = view
        return view

    def _run(self, bench, path: Path, fresh: bool) -> None:
        """Record (or resume) the session, then conclude it; every outcome ends in `state`."""
        from station.acquire import bench as benches
        from station.acquire import interrupts

        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            if fresh:
                benches.record(bench, path, self.operator, view=self._watch(bench))
            else:
                benches.resume(bench, path, self.operator,
                               view=self._watch(bench, _completed(path)))
        except BaseException as exc:  # noqa: BLE001 - every outcome is shown, none is lost
            stop = self._stop
            if stop is not None:
                interrupts.withdraw(stop.error)
            self._table_after(bench)
            ours = stop is not None and exc is stop.error
            self._ended(stop.state if ours else "failed", _words(exc))
            if not isinstance(exc, StationError | ConnectionError | RuntimeError | ValueError):
                log.exception("the session ended on an unexpected error")
            return
        self._ended("concluding")
        try:
            result = self.conclude(path)
        except Exception as exc:  # noqa: BLE001 - shown to the technician
            self._ended("failed", f"the session was recorded, its calibration failed: "
                                  f"{_words(exc)}")
            return
        with self._lock:
            self.result = result
        self._ended("done")

    def _table_after(self, bench, patience: float = 10.0) -> None:
        """Read the table once the session ended early, for the page: the protocol commanded it
        to stop; read again while it decelerates, at most `patience` wall seconds (the page
        then shows what it last read)."""
        from drivers.errors import TableError
        from station.serve.devices import table_reading

        if bench.table_map is None or self.view is None:
            return
        deadline = time.monotonic() + patience
        try:
            reading = table_reading(bench)
            while reading.moving and time.monotonic() < deadline:
                time.sleep(0.2)
                reading = table_reading(bench)
        except TableError as exc:
            reading = None
            log.warning("the table could not be read after the session: %s", exc)
        self.view.table_after(reading)

    def _ended(self, state: str, error: str | None = None) -> None:
        with self._lock:
            self.state, self.error = state, error

    def _halt(self, stop: Stopped) -> None:
        """Deliver `stop` to the running protocol (its next device poll or question raises)."""
        from station.acquire import interrupts

        with self._lock:
            if not self.running() or self.state != "running":
                raise InputError("no session is running")
            if self._stop is not None:
                return
            self._stop = stop
        interrupts.deliver(stop.error)
        self.operator.cancel(stop.error)


def _completed(path) -> int:
    """How many positions the session file completed."""
    from station.session import Session

    with Session.open(path) as session:
        last = session.last_completed_position()
    return 0 if last is None else last + 1


def _words(exc: BaseException) -> str:
    """An error as the command line says it: its message and notes, one line."""
    words = " ".join((str(exc) or type(exc).__name__).split())
    return "; ".join([words, *getattr(exc, "__notes__", ())])
