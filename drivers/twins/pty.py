"""The device end of a virtual serial port: a pseudo-terminal pair behind a stable path.

The driver opens `link.port` exactly as it would open /dev/ttyUSB0. `port` is a stable symlink (like
udev's /dev/serial/by-id/...) to the pty slave, so the same path works again after `unplug()` and
`plug()`. Both pty ends are put in raw mode at once (no echo, no line buffering) and the link keeps
one slave fd open so the pty survives the driver closing and reopening the port.

Writes never block: `write` returns when the pty is full for good (the caller's stop event, an
unplug, or no reader). With `unread_after`, a pty that has accepted nothing for that many wall
seconds has no reader (the station closed the port, or was killed): `unread()` tells the twin, whose
data due meanwhile is then lost, as a real device's bytes are when nobody reads its port.
"""

import contextlib
import os
import select
import shutil
import tempfile
import threading
import time
import tty


class PtyLink:
    """A pty pair whose slave is reached at `port` (see the module docstring).

    unread_after : wall seconds after which a pty that takes no bytes counts as unread (None:
                   never)
    """

    def __init__(self, unread_after=None, name: str = "ttyIMU"):
        self.unread_after = unread_after
        self._blocked_since = None  # wall time the pty stopped taking bytes
        self._lock = threading.Lock()
        self._master = self._keeper = None
        self._dir = tempfile.mkdtemp(prefix="serial-twin-")
        self.port = os.path.join(self._dir, name)
        self.plug()

    def plug(self) -> None:
        """Connect a fresh pty pair behind `port` (raw mode on both ends before any byte flows)."""
        with self._lock:
            if self._master is not None:
                return
            master, slave = os.openpty()
            tty.setraw(master)
            tty.setraw(slave)
            os.set_blocking(master, False)
            self._master, self._keeper = master, slave
            os.symlink(os.ttyname(slave), self.port + ".new")
            os.replace(self.port + ".new", self.port)

    @property
    def plugged(self) -> bool:
        """True between `plug()` and `unplug()`."""
        return self._master is not None

    def unplug(self) -> None:
        """Pull the cable: close the pty; a reader then gets an error, as with a real unplug."""
        with self._lock:
            if self._master is None:
                return
            os.close(self._master)
            os.close(self._keeper)
            self._master = self._keeper = None
            os.unlink(self.port)

    def close(self) -> None:
        """Unplug for good and remove the port's directory."""
        self.unplug()
        shutil.rmtree(self._dir, ignore_errors=True)

    def read(self) -> bytes:
        """The bytes the station wrote to the port since the last call (b"" if none or
        unplugged)."""
        with self._lock, contextlib.suppress(BlockingIOError, OSError):
            if self._master is not None:
                return os.read(self._master, 65536)
        return b""

    def unread(self) -> bool:
        """Has the pty taken no bytes for `unread_after` wall seconds, and still none now?"""
        if self.unread_after is None or self._blocked_since is None or \
                time.monotonic() - self._blocked_since < self.unread_after:
            return False
        with self._lock, contextlib.suppress(OSError, ValueError):
            if self._master is not None and select.select([], [self._master], [], 0)[1]:
                self._blocked_since = None  # a reader is back
        return self._blocked_since is not None

    def write(self, data: bytes, stop: threading.Event) -> int:
        """Write while the pty accepts bytes; stop early on unplug, `stop` or no reader. Bytes
        written."""
        view, done = memoryview(data), 0
        while done < len(data) and not stop.is_set() and not self.unread():
            with self._lock:
                if self._master is None:
                    break
                try:
                    done += os.write(self._master, view[done:])
                    self._blocked_since = None
                    continue
                except BlockingIOError:
                    master = self._master
                    self._blocked_since = self._blocked_since or time.monotonic()
            with contextlib.suppress(OSError, ValueError):  # unplugged meanwhile
                select.select([], [master], [], 0.02)
        return done
