"""The SQLite backend of the record store: one file (stdlib sqlite3), the embedded default.

Write-ahead log (journal_mode=WAL) with synchronous=FULL: a record is one transaction, so a
station killed mid-write leaves the store with the record whole or not at all, and a committed
record survives a power cut. Several processes may write one file: a writer waits up to
BUSY_SECONDS for another's transaction (busy_timeout). Foreign keys are enforced.
"""

import sqlite3
from contextlib import contextmanager
from pathlib import Path

from station.errors import RecordStoreError
from station.records.store import Dialect, Store

BUSY_SECONDS = 30.0
DIALECT = Dialect(
    name="sqlite", placeholder="?",
    types={"id": "INTEGER PRIMARY KEY", "real": "REAL", "without_rowid": " WITHOUT ROWID"},
    errors=(sqlite3.Error,),
    advice="check the file is a record store on a writable, not full disk (`station db check`), "
           "or give another store with --db or STATION_DB",
    lock_schema=lambda cur: None,  # BEGIN IMMEDIATE already holds the write lock
    has_versions="SELECT COUNT(*) FROM sqlite_master WHERE type = 'table' AND "
                 "name = 'schema_version'")


class SqliteStore(Store):
    """A record store in a SQLite file."""

    @contextmanager
    def dialect_transaction(self, exclusive: bool):
        cur = self.connection.cursor()
        cur.execute("BEGIN IMMEDIATE" if exclusive else "BEGIN")
        try:
            yield cur
        except BaseException:
            self.connection.rollback()
            raise
        else:
            cur.execute("COMMIT")
        finally:
            cur.close()

    def integrity(self) -> str:
        """SQLite's own check of the file: "ok", or what is damaged."""
        with self.transaction() as cur:
            cur.execute("PRAGMA integrity_check")
            return "; ".join(row[0] for row in cur.fetchall())


def path_of(url: str) -> Path:
    """The file of a `sqlite:///PATH` URL (or a plain path)."""
    return Path(url.removeprefix("sqlite:///"))


def connect(url: str, create: bool = True) -> SqliteStore:
    """Open (create: or make) the SQLite store of `url`."""
    path = path_of(url)
    if not create and not path.is_file():
        raise RecordStoreError(f"no record store at {path}: give --db URL or set STATION_DB "
                               "(docs/records.md), or run a solve or `station db import` first")
    try:
        connection = sqlite3.connect(path, timeout=BUSY_SECONDS, isolation_level=None)
    except sqlite3.Error as exc:
        raise RecordStoreError(f"cannot open the record store {path} ({exc}): check the "
                               "directory exists and is writable, or give --db") from None
    try:
        _wal(connection)
        for pragma in ("synchronous=FULL", "foreign_keys=ON"):
            connection.execute(f"PRAGMA {pragma}")
    except sqlite3.Error as exc:
        connection.close()
        raise RecordStoreError(f"{path} is not a record store this station can use ({exc}); "
                               "give another file with --db") from None
    return SqliteStore(connection, DIALECT, f"sqlite:///{path}")


def _wal(connection) -> None:
    """journal_mode=WAL, waiting up to BUSY_SECONDS while another connection holds the lock:
    SQLite answers "database is locked" at once, without its busy handler, when two processes
    switch a new store's journal mode together (CI saw two writers' first opens collide)."""
    import time

    deadline = time.monotonic() + BUSY_SECONDS
    while True:
        try:
            connection.execute("PRAGMA journal_mode=WAL")
            return
        except sqlite3.OperationalError as exc:
            if "locked" not in str(exc) or time.monotonic() > deadline:
                raise
            time.sleep(0.05)
