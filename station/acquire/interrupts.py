"""Ctrl-C and `kill` that are never lost.

Python runs a signal handler between two bytecodes of the main thread, also inside a weakref
callback or a `__del__`; an exception raised there is printed ("Exception ignored in ...") and
dropped, so a KeyboardInterrupt from Ctrl-C could vanish and the recording go on with the rotary
table turning. `install()` makes SIGINT and SIGTERM (`kill`) raise KeyboardInterrupt and also
remember it; `raise_dropped()`, called wherever a protocol polls its devices
(`station.acquire.recorder.Recorder.check`), raises it again if nobody has handled it; whoever
handles it (stops the table, records the abort) does so inside `with handling(exc) as cause:`.
From the moment the handler raises until the interrupt is handled (the `handling` block ends,
or `handled()`), a second Ctrl-C (a technician pressing twice) is remembered, not raised in the
middle of the abort.

A device watched from another thread (the thermal chamber while a session records) stops the
recording the same way: `deliver(error)` makes the main thread's next `raise_dropped()` raise it.

The KeyboardInterrupt lands wherever the main thread is, so a lock that another thread may wait
for is taken there with `with` on a C lock: never `with condition:` (`Condition.__enter__` is
Python code) nor `acquire()` then `try`, where an interrupt in between leaves it taken and the
other thread (the recorder's reader, a heartbeat) waits for ever while the station joins it: the
lockstep clock (`drivers.clock.SteppedClock._wait`) and the log handler
(`station.cli.log_handler`). `tests/signal_places.py` raises the interrupt at every place it can
land in a call; tests/test_lockstep.py, test_table_modbus.py and test_cli_logging.py sweep it.
A main thread that only waits to be told to end (`station twin`) waits on a `Wake`, which takes
no lock at all.
"""

import contextlib
import os
import select
import signal
import sys
import threading

_pending: str | None = None
_delivered: BaseException | None = None
_shielded = False  # an interrupt was raised: a further one is only remembered
_handling = False  # ... and is being handled (`handling`)
_next_hook = sys.unraisablehook


def install() -> dict:
    """Handle SIGINT and SIGTERM as above (main thread only); returns the previous handlers for
    `restore`."""
    global _next_hook
    if threading.current_thread() is not threading.main_thread():
        return {}
    if sys.unraisablehook is not _unraisable:  # installed twice: chained once, not to itself
        _next_hook, sys.unraisablehook = sys.unraisablehook, _unraisable
    return {number: signal.signal(number, _interrupted) for number in (signal.SIGINT,
                                                                       signal.SIGTERM)}


def restore(previous: dict) -> None:
    """Put back the handlers `install` replaced; forget any interrupt."""
    for number, handler in previous.items():
        signal.signal(number, handler)
    if previous and sys.unraisablehook is _unraisable:
        sys.unraisablehook = _next_hook
    handled()


def raise_dropped() -> None:
    """Raise KeyboardInterrupt again for a signal whose first one was dropped, or the error
    another thread delivered; nothing while an interrupt is being handled."""
    if _handling:
        return
    if _pending is not None:
        raise KeyboardInterrupt(f"{_pending} (raised again: the first was dropped)")
    if _delivered is not None:
        raise _delivered


def deliver(error: BaseException) -> None:
    """Have the main thread's next `raise_dropped()` raise `error` (found by another thread)."""
    global _delivered
    _delivered = error


def withdraw(error: BaseException) -> None:
    """Forget `error` if it was delivered and not raised yet (its watcher has ended)."""
    global _delivered
    if _delivered is error:
        _delivered = None


def handled() -> None:
    """The interrupt (or delivered error) is handled: `raise_dropped` no longer raises it, and
    the next signal raises again."""
    global _pending, _delivered, _shielded, _handling
    _pending = _delivered = None
    _shielded = _handling = False


def _stands_for(exc: BaseException) -> BaseException:
    """What `exc` stands for: the pending interrupt itself (KeyboardInterrupt, `exc` its cause)
    when one was pending and `exc` is another error. The handler's KeyboardInterrupt can land
    inside a library's lock handling, which then raises its own error instead (seen:
    "RuntimeError: cannot release un-acquired lock" from a Ctrl-C at a position's start, the
    station exiting 1 with a traceback instead of 130)."""
    if _pending is None or isinstance(exc, KeyboardInterrupt):
        return exc
    interrupt = KeyboardInterrupt(_pending)
    interrupt.__cause__ = exc
    return interrupt


@contextlib.contextmanager
def handling(exc: BaseException):
    """What `exc` stands for (`exc`, or the interrupt it came from) for the block that handles
    it (stops the table, records the abort), the interrupt handled when the block ends. Until
    then a further SIGINT or SIGTERM is remembered, not raised in the middle of it: the shield
    goes up when the handler raises the first, so no bytecode between the two is open.
    Measured before it: a second Ctrl-C in the abort event's write left the session without its
    `abort` (tests/test_abort_shield.py)."""
    global _shielded, _handling
    _shielded = _handling = True  # for a delivered error too
    try:
        yield _stands_for(exc)
    finally:
        handled()


def _unraisable(unraisable) -> None:
    """Python dropped an exception it could not raise (in a finaliser, a weakref callback): a
    dropped interrupt is not on its way to a handler, so the shield falls with it (the next
    Ctrl-C raises; `raise_dropped` raises this one again)."""
    global _shielded
    if isinstance(unraisable.exc_value, KeyboardInterrupt) and not _handling:
        _shielded = False
    _next_hook(unraisable)


def _interrupted(number, frame):
    global _pending, _shielded
    _pending = "interrupted (Ctrl-C)" if number == signal.SIGINT else "terminated (SIGTERM)"
    if not _shielded:
        _shielded = True
        raise KeyboardInterrupt(_pending)


class Wake:
    """A wait that a signal handler or another thread ends, with no lock anywhere: `set()` writes
    a byte to a pipe (`os.write`: safe in a handler), `wait(timeout)` selects on it (a Ctrl-C
    raises out of the select, holding nothing). `threading.Event` is not that: its `wait` holds
    a Python lock inside a `with`, where a Ctrl-C can leave it taken; the next `set()`, a twin
    thread's failure or a SIGTERM handler's in the main thread (the lock is not reentrant),
    then blocks for ever. `close()` it once nothing can call `set()` any more."""

    def __init__(self):
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)

    def set(self, *_) -> None:
        """Wake the wait (now or the next one); usable as a signal handler."""
        with contextlib.suppress(BlockingIOError):  # a full pipe is awake already
            os.write(self._write, b"\0")

    def wait(self, timeout: float | None = None) -> bool:
        """True when woken (`set` called) within `timeout` seconds (None: for ever)."""
        return bool(select.select([self._read], [], [], timeout)[0])

    def close(self) -> None:
        """Close the pipe (a `set()` after it would write to whatever file takes its number)."""
        os.close(self._read)
        os.close(self._write)
