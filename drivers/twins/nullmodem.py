"""Two virtual serial ports joined by a null-modem cable: what one end writes, the other reads.

Each end is a pseudo-terminal pair in raw mode behind a stable path (`a`, `b`: symlinks to the pty
slaves, as udev's /dev/serial/by-id/...); a thread copies bytes between the two masters. It is how
a serial device server that opens a port by name (pymodbus' `ModbusSerialServer`) and a driver that
does the same meet on one machine, as `socat pty,link=A pty,link=B` does.
"""

import contextlib
import os
import select
import shutil
import tempfile
import threading
import tty


class NullModem:
    """Ports `a` and `b` joined by a copying thread; `close()` ends it and removes the ports."""

    def __init__(self, names: tuple = ("ttyA", "ttyB")):
        self._dir = tempfile.mkdtemp(prefix="nullmodem-")
        self._masters, self._slaves, paths = [], [], []
        for name in names:
            master, slave = os.openpty()
            tty.setraw(master)
            tty.setraw(slave)
            path = os.path.join(self._dir, name)
            os.symlink(os.ttyname(slave), path)
            self._masters.append(master)
            self._slaves.append(slave)  # kept open: the pty lives while a port closes and reopens
            paths.append(path)
        self.a, self.b = paths
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._copy, name="NullModem", daemon=True)
        self._thread.start()

    def _copy(self) -> None:
        """Copy every byte that arrives at one master to the other, until `close()`."""
        a, b = self._masters
        other = {a: b, b: a}
        while not self._stop.is_set():
            readable, _, _ = select.select([a, b], [], [], 0.05)
            for fd in readable:
                with contextlib.suppress(OSError):  # nobody has the other end open: bytes lost
                    os.write(other[fd], os.read(fd, 4096))

    def close(self) -> None:
        """Stop copying, close the ptys and remove the ports (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(2)
        for fd in self._masters + self._slaves:
            os.close(fd)
        shutil.rmtree(self._dir, ignore_errors=True)
