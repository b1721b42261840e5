"""A throwaway PostgreSQL cluster for the record store's tests: initdb into a temporary
directory, pg_ctl start listening on a unix socket in that directory only (no TCP), stopped and
removed at the end.

initdb refuses to run as root, so as root the cluster is made and run as the `postgres` user
(runuser), the directory handed to it. Without PostgreSQL's binaries (/usr/lib/postgresql/*/bin)
the tests that need it skip, naming why, unless STATION_REQUIRE_PG=1 (CI): then they fail.
"""

import glob
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

REQUIRE = "STATION_REQUIRE_PG"
START_SECONDS = 120  # pg_ctl -w -t: a busy host starts a cluster slowly


def binaries() -> Path | None:
    """The newest installed PostgreSQL's bin directory with initdb and pg_ctl, or None."""
    found = [Path(d) for d in glob.glob("/usr/lib/postgresql/*/bin")
             if (Path(d) / "initdb").exists() and (Path(d) / "pg_ctl").exists()]
    return max(found, key=lambda d: int(d.parent.name), default=None)


def unavailable(reason: str):
    """Skip with `reason`, or fail with it when STATION_REQUIRE_PG=1."""
    if os.environ.get(REQUIRE) == "1":
        pytest.fail(f"{reason}, and {REQUIRE}=1 requires PostgreSQL (apt-get install postgresql)")
    pytest.skip(f"{reason}: the PostgreSQL record store tests need it (apt-get install "
                "postgresql; set STATION_REQUIRE_PG=1 to make this a failure)")


class Cluster:
    """A running throwaway cluster; `url(dbname)` connects to one of its databases. durable:
    fsync on as in production (bench/records.py); off for the tests (nothing to survive)."""

    def __init__(self, bindir: Path, durable: bool = False):
        self.bindir = bindir
        self.root = Path(tempfile.mkdtemp(prefix="station-pg-"))
        self.data = self.root / "data"
        self.as_postgres = os.geteuid() == 0
        if self.as_postgres:
            shutil.chown(self.root, "postgres", "postgres")
        self._run("initdb", "-D", str(self.data), "-A", "trust", "-U", "postgres",
                  "--no-sync", "-E", "UTF8")
        self._run("pg_ctl", "-D", str(self.data), "-l", str(self.root / "log"), "-w", "-t",
                  str(START_SECONDS), "-o",
                  f"-k {self.root} -c listen_addresses='' -c fsync={'on' if durable else 'off'}",
                  "start")
        self._made = 0

    def _run(self, tool: str, *args: str) -> None:
        command = [str(self.bindir / tool), *args]
        if self.as_postgres:
            command = ["runuser", "-u", "postgres", "--", *command]
        done = subprocess.run(command, capture_output=True, text=True, cwd=self.root)
        if done.returncode != 0:
            raise RuntimeError(f"{tool} failed ({done.returncode}): {done.stderr.strip()}"
                               f" {done.stdout.strip()[-2000:]}")

    def url(self, dbname: str = "postgres") -> str:
        return f"postgresql:///{dbname}?host={self.root}&user=postgres"

    def new_database(self) -> str:
        """A fresh empty database's URL."""
        import psycopg

        self._made += 1
        name = f"station_test_{self._made}"
        with psycopg.connect(self.url(), autocommit=True) as conn:
            conn.execute(f"CREATE DATABASE {name}")  # a name made here, not data
        return self.url(name)

    def stop(self) -> None:
        try:
            self._run("pg_ctl", "-D", str(self.data), "-m", "immediate", "-w", "stop")
        finally:
            shutil.rmtree(self.root, ignore_errors=True)


def start_cluster(durable: bool = False) -> Cluster:
    """A started cluster, or a skip (or a failure under STATION_REQUIRE_PG=1) saying why not."""
    bindir = binaries()
    if bindir is None:
        unavailable("no PostgreSQL binaries in /usr/lib/postgresql/*/bin")
    if os.geteuid() == 0 and shutil.which("runuser") is None:
        unavailable("running as root without runuser (initdb refuses root)")
    try:
        return Cluster(bindir, durable)
    except (RuntimeError, OSError, LookupError) as exc:
        unavailable(f"the throwaway PostgreSQL cluster did not start ({exc})")
