"""What the streaming twins share (drivers.twins.serial, drivers.twins.mavlink): one background
thread serving over a link that can be unplugged (`drivers.twins.pty.PtyLink`, or a UDP sender)."""

import threading

from drivers.twins.failure import fail


class Streamer:
    """Base of a twin that streams from one background thread over `self.link` (set by the
    subclass: anything with plug, unplug, plugged and close) on `self.clock` (`drivers.clock`; the
    thread takes part in a stepped clock as a producer). The subclass defines `_run` (which
    hands its exception to `_failed`) and starts it with `_launch(name)` from its `start()`. A
    context manager: `start()` on entry, `stop()` on exit.

    A streaming error (e.g. from the source) ends the stream at once (`drivers.twins.failure`):
    kept in `error`, the link unplugged for good, told to `on_error(exc)` if the owner set one,
    else re-raised by `stop()`."""

    def __init__(self):
        self.error = None
        self.on_error = None
        self._stop = threading.Event()
        self._thread = None

    def plug(self) -> None:
        """Plug the device back in (the same port or address); a twin that failed stays
        unplugged, as a device that crashed stays silent."""
        if self.error is None:
            self.link.plug()

    @property
    def plugged(self) -> bool:
        """True between `plug()` and `unplug()`."""
        return self.link.plugged

    def unplug(self) -> None:
        """Pull the cable: a pty closes (its reader gets an error, as with a real unplug), UDP
        goes silent. The bytes it held are gone: on a stepped clock they are no longer in flight
        (else time would wait for ever for a reader to take them, and the station would never
        see its IMU fall silent)."""
        self.link.unplug()
        self.clock.forget(self.port)
        self.clock.nudge()

    def _launch(self, name: str):
        """Start `_run` in the background thread `name`; returns self."""
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.clock.enlist(self._thread, producer=True)
        self._thread.start()
        return self

    def _failed(self, exc: Exception) -> None:
        """The stream cannot go on: unplug and tell (see the class docstring)."""
        fail(self, exc, self.unplug)

    def stop(self) -> None:
        """Stop streaming, close the link (a pty and its port link are removed); re-raise a
        streaming error (e.g. from the source) that no `on_error` was told."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        self.link.close()
        if self.error is not None and self.on_error is None:
            raise self.error

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
