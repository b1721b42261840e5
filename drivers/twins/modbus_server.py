"""A pymodbus server running in a background thread with its own asyncio loop, for the twins.

`ServerThread.start(make_server)` runs `make_server()` (a coroutine function returning a started
pymodbus server) in the thread and returns once it listens; the server stops on `close()` or by
itself after `lifetime` seconds, so a forgotten twin never outlives its test.
"""

import asyncio
import contextlib
import threading


class ServerThread:
    """The thread, loop and life of one twin's Modbus server."""

    def __init__(self, name: str, lifetime: float):
        self.name, self.lifetime = name, lifetime
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

    def _stop(self, first) -> None:
        if first is not None:
            first()
        self._stopping.set()

    def _serve(self, make_server) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._main(make_server))
        except Exception as exc:  # noqa: BLE001 - reported by start()
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
