"""A child process forked from this one to run a Python function, with the part of
`subprocess.Popen` that the structure check uses (`communicate`, `kill`, `returncode`, `pid`, a
context manager), so `station.session.check` treats it as the interpreter it starts otherwise.

Why: a fresh interpreter imports numpy and h5py again, as much CPU time as the whole of a small
solve (issue 35: `station solve` within 3x `import numpy, h5py`); a fork inherits them. Only
safe in a process with one thread: a fork copies the locks other threads hold (h5py's global lock
among them) without the threads that would release them. `forkable()` says when.

The child writes to two pipes that replace its file descriptors 1 and 2 (what the HDF5 library
prints on a crash is kept, as from a started interpreter), never runs the parent's exit handlers
(os._exit) and exits 0 after `work` returns, 1 on an exception (its traceback on the pipe), or by
the signal that ended it (returncode -signal, as Popen reports it).
"""

import faulthandler
import os
import selectors
import signal
import subprocess
import sys
import threading
import time
import traceback


def forkable() -> bool:
    """Whether this process may fork a child that uses h5py: a POSIX fork and one thread."""
    return hasattr(os, "fork") and threading.active_count() == 1


class Forked:
    """`work(out)` run in a forked child; `out` a text file on its standard output pipe."""

    def __init__(self, work):
        sys.stdout.flush()
        sys.stderr.flush()
        out_r, out_w = os.pipe()
        err_r, err_w = os.pipe()
        self.pid = os.fork()
        if self.pid == 0:  # the child: never returns
            os.close(out_r)
            os.close(err_r)
            _run(work, out_w, err_w)
        os.close(out_w)
        os.close(err_w)
        self.returncode = None
        self._pipes = {out_r: [], err_r: []}  # standard output, then error: what each has sent

    def communicate(self, timeout: float | None = None) -> tuple:
        """(stdout, stderr) as text once the child has closed them and exited;
        subprocess.TimeoutExpired when that takes longer than `timeout` s (call again after
        `kill`)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with selectors.DefaultSelector() as sel:
            for fd in self._pipes:
                sel.register(fd, selectors.EVENT_READ)
            while sel.get_map():
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    raise subprocess.TimeoutExpired(f"forked child {self.pid}", timeout)
                for key, _ in sel.select(left):
                    chunk = os.read(key.fd, 65536)
                    if chunk:
                        self._pipes[key.fd].append(chunk)
                    else:
                        sel.unregister(key.fd)
        self._reap()
        return tuple(b"".join(sent).decode(errors="replace") for sent in self._pipes.values())

    def kill(self) -> None:
        """SIGKILL the child (nothing when it has been reaped already)."""
        if self.returncode is None:
            os.kill(self.pid, signal.SIGKILL)

    def _reap(self) -> None:
        if self.returncode is None:
            self.returncode = os.waitstatus_to_exitcode(os.waitpid(self.pid, 0)[1])

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        """Close the pipes; a child still running is killed and reaped (no zombie)."""
        if self.returncode is None:
            self.kill()
            self._reap()
        for fd in self._pipes:
            os.close(fd)


def _run(work, out_w: int, err_w: int) -> None:
    """The child's life: file descriptors 1 and 2 onto the pipes, `work`, os._exit."""
    code = 1
    try:
        faulthandler.disable()  # the parent's (pytest's, -X faulthandler) would print our crash
        os.dup2(out_w, 1)
        os.dup2(err_w, 2)
        os.close(out_w)
        os.close(err_w)
        with os.fdopen(1, "w", closefd=False) as out:
            try:
                work(out)
                code = 0
            except BaseException:  # noqa: BLE001 - the child reports everything, then exits
                with os.fdopen(2, "w", closefd=False) as err:
                    traceback.print_exc(file=err)
    finally:
        os._exit(code)
