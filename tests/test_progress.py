"""Long commands show a progress bar on a terminal's stderr and nothing when stderr is a pipe
(station.commands.progress), so that JSON and piped output stay clean."""

import contextlib
import os
import pty
import subprocess
import sys
import threading

import numpy as np

from station.commands import progress


def _csv(path, rows: int = 120_000):
    t = np.arange(rows) / 100.0
    np.savetxt(path, np.column_stack([t, np.sin(t), np.cos(t), t * 0 + 9.8]), delimiter=",",
               header="t,ax,ay,az", comments="", fmt="%.6f")
    return path


IMPORT = ["import", "csv", "{out}", "{csv}", "--stream", "acc=ax,ay,az", "--unit", "acc=m/s^2",
          "--time", "t"]


def _station(args, tmp_path, stderr):
    out, csv = tmp_path / "x.h5", _csv(tmp_path / "x.csv")
    argv = [a.format(out=out, csv=csv) for a in args]
    env = {**os.environ, "COLUMNS": "300"}
    return subprocess.run([sys.executable, "-m", "station", *argv], stdout=subprocess.PIPE,
                          stderr=stderr, env=env, timeout=300, check=False)


def test_import_on_a_terminal_shows_the_bytes_read(tmp_path):
    """The terminal is read while the command runs, as a terminal is: unread, a slow import's
    progress bar (more redraws on a busy host) fills the pty and the command waits for ever."""
    controller, terminal = pty.openpty()
    seen = bytearray()

    def read() -> None:
        with contextlib.suppress(OSError):  # the terminal side is closed and drained
            while chunk := os.read(controller, 65536):
                seen.extend(chunk)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        done = _station(IMPORT, tmp_path, terminal)
    finally:
        os.close(terminal)
        reader.join(60)
        os.close(controller)
    seen = bytes(seen)
    assert done.returncode == 0, seen
    size = (tmp_path / "x.csv").stat().st_size
    assert b"importing into" in seen and f"{size}/{size}".encode() in seen, seen[-400:]


def test_import_through_a_pipe_prints_nothing_on_stderr(tmp_path):
    done = _station([*IMPORT, "--json"], tmp_path, subprocess.PIPE)
    assert done.returncode == 0 and done.stderr == b""
    assert done.stdout.startswith(b"{")


def test_the_helper_is_silent_off_a_terminal(capsys):
    with progress("counting", "things") as advance:
        for k in range(5):
            advance(k + 1, 5)
    assert capsys.readouterr() == ("", "")
