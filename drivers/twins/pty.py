"""The device end of a virtual serial port: a pseudo-terminal pair behind a stable path.

The driver opens `link.port` exactly as it would open /dev/ttyUSB0. `port` is a stable symlink (like
udev's /dev/serial/by-id/...) to the pty slave, so the same path works again after `unplug()` and
`plug()`. Both pty ends are put in raw mode at once (no echo, no line buffering) and the link keeps
one slave fd open so the pty survives the driver closing and reopening the port.

Writes never block: `write` returns when the pty is full for good (the caller's stop event, an
unplug, or no reader). With `unread_after`, a pty that takes no bytes has no reader when no program
but the link holds its slave open (the station closed the port, or was killed; read from /proc), or
when it has accepted nothing for `unread_after` wall seconds: `unread()` tells the twin, whose data
due meanwhile is then lost, as a real device's bytes are when nobody reads its port. (A fast clock
makes the wait costly: at 40x, two wall seconds are 80 s of samples that a resumed session would
otherwise receive late, in a backlog that a loaded host may not catch up with before it ends.)
"""

import contextlib
import glob
import math
import os
import select
import shutil
import tempfile
import threading
import time
import tty

HELD_CHECK = 0.05
"""Wall seconds between two looks in /proc for a program holding the pty open."""


def _target(fd_link: str) -> str | None:
    """Where a /proc/PID/fd/N link points; None if it has gone or cannot be read."""
    try:
        return os.readlink(fd_link)
    except OSError:
        return None


class PtyLink:
    """A pty pair whose slave is reached at `port` (see the module docstring).

    unread_after : wall seconds after which a pty that takes no bytes counts as unread (None:
                   never); at once when no other program holds it open
    """

    def __init__(self, unread_after=None, name: str = "ttyIMU"):
        self.unread_after = unread_after
        self._blocked_since = None  # wall time the pty stopped taking bytes
        self._checked = (-math.inf, True)  # (wall time, a reader held the slave then)
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
        """Has the pty taken no bytes for `unread_after` wall seconds, or since nobody holds it
        open, and still none now?"""
        if self.unread_after is None or self._blocked_since is None or (
                time.monotonic() - self._blocked_since < self.unread_after and self._held()):
            return False
        with self._lock, contextlib.suppress(OSError, ValueError):
            if self._master is not None and select.select([], [self._master], [], 0)[1]:
                self._blocked_since = None  # a reader is back
        return self._blocked_since is not None

    def _held(self) -> bool:
        """Does a program other than this link hold the pty's slave open (a reader)? Read from
        /proc at most every `HELD_CHECK` wall seconds; True where /proc cannot tell."""
        now = time.monotonic()
        if now - self._checked[0] >= HELD_CHECK:
            self._checked = (now, self._reader_in_proc())
        return self._checked[1]

    def _reader_in_proc(self) -> bool:
        try:
            slave = os.ttyname(self._keeper)
        except (OSError, TypeError):  # unplugged meanwhile
            return True
        mine = f"/proc/{os.getpid()}/fd/{self._keeper}"
        if _target(mine) != slave:  # no /proc, or another layout: it cannot tell
            return True
        return any(_target(fd) == slave for fd in glob.glob("/proc/[0-9]*/fd/*") if fd != mine)

    def write(self, data: bytes, stop: threading.Event, full=None) -> int:
        """Write while the pty accepts bytes; stop early on unplug, `stop` or no reader. Bytes
        written. `full()`, when given, is called each time the pty is full (e.g. the clock's
        `nudge`, so that the reader takes what is there)."""
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
            if full is not None:
                full()
            with contextlib.suppress(OSError, ValueError):  # unplugged meanwhile
                select.select([], [master], [], 0.02)
        return done
