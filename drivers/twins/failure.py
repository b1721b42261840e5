"""What a twin does when its background thread cannot go on: one rule for every twin (the serial
and MAVLink streamers, the CAN IMU, the table and chamber Modbus servers, the served benches'
fixtures), told at once rather than kept for `stop()`.

The twin side, `fail(twin, exc, silence)` in the thread's `except Exception` block:
- the exception is kept in the twin's `error` (the first: what follows is its consequence);
- `silence()` makes the twin's devices go quiet at once, as a device that crashed: a pty is
  unplugged (the station's serial driver gets an I/O error), a Modbus server closes (its
  connections are refused), a CAN twin sends nothing more;
- the twin's `on_error(exc)` is called, if its owner set one.

The owner side, `Failures`: the failures of one bench's twins. `watch(twin, name)` sets the twin's
`on_error`; each failure is kept with the twin's name and told at once to `on_failure(words)`: a
warning in the log, unless the owner says otherwise (`station twin` ends then, its error line
naming the twin and the cause). Leaving the bench's `with` (`after`), an error the station raised
meanwhile (e.g. "no IMU sample for 10 s") gets a note saying which twin stopped and why; without
one, the failure is raised as a `TwinError`.
"""

import logging
import threading

from drivers.errors import TwinError

log = logging.getLogger(__name__)


def fail(twin, exc: Exception, silence=None) -> None:
    """End `twin`'s thread on `exc`, from its `except Exception` block: keep it in `twin.error`,
    call `silence()`, tell `twin.on_error(exc)`; a twin that has failed already is left as it is."""
    if twin.error is not None:
        return
    twin.error = exc
    if silence is not None:
        try:
            silence()
        except Exception as also:  # noqa: BLE001 - the first failure is the one to tell
            exc.add_note(f"silencing the twin failed too: {type(also).__name__}: {also}")
    if twin.on_error is not None:
        twin.on_error(exc)


class Failures:
    """The failures of one bench's twins, each told at once (see the module docstring).

    failed     : [(name, exception)] in the order they came
    on_failure : callable(words), called in the failing twin's thread (default: a warning)
    """

    def __init__(self):
        self.failed = []
        self.on_failure = log.warning
        self._lock = threading.Lock()

    def watch(self, twin, name: str):
        """Have `twin`'s failure told here as that of `name` (e.g. "serial IMU"); returns the
        twin."""
        twin.on_error = lambda exc: self._report(name, exc)
        return twin

    def words(self) -> str:
        """Every failure in one line: "the serial IMU twin stopped: ValueError: ..." ("" if
        none)."""
        with self._lock:
            return "; ".join(f"the {name} twin stopped: {type(exc).__name__}: {exc}"
                             for name, exc in self.failed)

    def after(self, exc: BaseException | None) -> None:
        """On leaving the bench's `with`: note the failures on `exc`, the error that ends it, or
        raise them as a TwinError when nothing else went wrong."""
        words = self.words()
        if not words:
            return
        if exc is not None:
            exc.add_note(f"the virtual bench failed: {words}")
            return
        raise TwinError(words) from self.failed[0][1]

    def _report(self, name: str, exc: Exception) -> None:
        with self._lock:
            self.failed.append((name, exc))
        self.on_failure(self.words())
