"""A pymodbus server running in a background thread with its own asyncio loop, for the twins.

`ServerThread.start(make_server)` runs `make_server()` (a coroutine function returning a started
pymodbus server) in the thread and returns once it listens; the server stops on `close()` or by
itself after `lifetime` seconds, so a forgotten twin never outlives its test.

The twin's Modbus action hook goes through `guarded`: an exception there (e.g. from the physics)
is no Modbus exception reply but the twin failing (`drivers.twins.failure.fail`, on the `owner`
twin: its `error` and `on_error`): the server closes at once, the request unanswered. So does an
error that ends the server's loop once it serves.
"""

import asyncio
import contextlib
import threading

from drivers.twins.failure import fail


class ServerThread:
    """The thread, loop and life of the Modbus server of `owner` (a twin with `error` and
    `on_error`)."""

    def __init__(self, name: str, lifetime: float, owner):
        self.name, self.lifetime, self.owner = name, lifetime, owner
        self.server = None
        self._loop = asyncio.new_event_loop()
        self._stopping = None
        self._ready = threading.Event()
        self._thread = None
        self._error = None

    def start(self, make_server) -> None:
        """Start the thread serving `await make_server()`; raises if it does not listen in 10 s."""
        self._thread = threading.Thread(target=self._serve, args=(make_server,), name=self.name,
                                        daemon=True)
        self._thread.start()
        self._ready.wait(10)
        if self.server is None or self._error is not None:
            raise RuntimeError(f"the {self.name} Modbus server did not start: {self._error!r}")

    def close(self, first=None) -> None:
        """Stop the server and its thread (idempotent); `first`: a function the loop runs just
        before (e.g. resetting the connections of a controller that dies)."""
        if self._thread is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop, first)
            self._thread.join(10)

    def guarded(self, action):
        """The pymodbus action hook `action`, whose exception fails the owner twin: the server
        closes and the request gets no reply."""
        async def hook(*args):
            try:
                return await action(*args)
            except Exception as exc:  # noqa: BLE001 - told at once (drivers.twins.failure)
                fail(self.owner, exc, self._stopping.set)
                raise asyncio.CancelledError from exc  # no reply
        return hook

    def _stop(self, first) -> None:
        if first is not None:
            first()
        self._stopping.set()

    def _serve(self, make_server) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._main(make_server))
        except Exception as exc:  # noqa: BLE001 - reported by start(), or told once serving
            if self._ready.is_set():
                fail(self.owner, exc)
            self._error = exc
            self._ready.set()
        finally:
            pending = asyncio.all_tasks(self._loop)
            for task in pending:
                task.cancel()
            self._loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
            self._loop.close()

    async def _main(self, make_server) -> None:
        self._stopping = asyncio.Event()
        server = await make_server()
        self.server = server
        try:
            self._ready.set()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stopping.wait(), self.lifetime)
        finally:
            await server.shutdown()
