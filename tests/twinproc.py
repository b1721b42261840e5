"""`station` commands in their own processes, as a technician runs them: `station_run` one
command with nobody at the keyboard, `TwinProcess` a `station twin` beside `station record`."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

STATION = [sys.executable, "-m", "station"]
ENV = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
"""The commands' environment: this checkout's station, whatever the working directory."""


def station_run(*args, timeout: float = 300) -> subprocess.CompletedProcess:
    """`station ARGS` with stdin closed (nobody answers): its exit code and output, as text."""
    return subprocess.run([*STATION, *map(str, args)], stdin=subprocess.DEVNULL, env=ENV,
                          capture_output=True, text=True, timeout=timeout, check=False)


class TwinProcess:
    """`station twin ARGS --json` (a context manager). `started` is the first line it prints (its
    devices, once it serves them). On exit it is stopped by SIGINT, as Ctrl-C would; when the block
    ended normally it must then exit 0, and `truth` is the truth its last line prints.

    args : the twin's options (without --json)
    """

    def __init__(self, *args: str):
        self.process = subprocess.Popen([*STATION, "twin", *args, "--json"], env=ENV, text=True,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.started: dict = {}
        self.truth: dict = {}

    def __enter__(self) -> "TwinProcess":
        try:
            self.started = json.loads(self.process.stdout.readline())
        except BaseException:
            self._stop()
            raise
        return self

    def __exit__(self, kind, *_) -> None:
        out, err = self._stop()
        if kind is None:
            assert self.process.returncode == 0, err
            self.truth = json.loads(out.splitlines()[-1])["truth"]

    def _stop(self) -> tuple:
        """SIGINT, then the rest of its output; killed if it has not stopped after 600 s."""
        self.process.send_signal(signal.SIGINT)
        try:
            return self.process.communicate(timeout=600)
        except subprocess.TimeoutExpired:
            self.process.kill()
            return self.process.communicate()
