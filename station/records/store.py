"""The calibration record store behind one small interface: `open_store(url)` -> `Store`.

    with open_store("sqlite:///sessions/station.db") as store:   # or postgresql://...
        store.add(record)                       # one record = one transaction
        store.history("SN1234")                 # every record of a unit, oldest first
        store.records(Selection.parse("model=imu12-serial since=2026-11-01"))

Backends: SQLite (`station.records.sqlite`, the embedded default, a file beside the sessions)
and PostgreSQL (`station.records.postgres`, psycopg 3: several stations sharing one database).
They differ only in how they connect and in `Dialect`; every query is written once, with `?`
placeholders (turned into psycopg's `%s`), and takes its values as parameters: no SQL is ever
built from data. Errors of either driver become `RecordStoreError` naming the store and what to
do. URL forms, the default store and STATION_DB: `store_url`, docs/records.md.
"""

import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from station.errors import InputError, RecordStoreError
from station.files.provenance import utc_now
from station.records.record import COLUMNS, Parameter, Record

DEFAULT_NAME = "station.db"
"""The default store's file name, in the directory of the calibration file written (a solve) or
the working directory (the queries)."""
ENV = "STATION_DB"
URL_FORMS = ("sqlite:///PATH (sqlite:////absolute/path), a plain file path, or "
             "postgresql://user@host/dbname (also postgresql:///dbname?host=/socket/dir)")


@dataclass(frozen=True)
class Dialect:
    """What differs between the backends: name, placeholder, the type spellings of the schema
    (`station.records.schema`), the driver's error classes, advice on failure, the lock taken
    while migrating, and the query that says whether the version table exists (1 or 0)."""

    name: str
    placeholder: str
    types: dict
    errors: tuple
    advice: str
    lock_schema: object
    has_versions: str


class Store:
    """A connection to a record store (`open_store`). Use it as a context manager or close it."""

    def __init__(self, connection, dialect: Dialect, where: str):
        self.connection = connection
        self.dialect = dialect
        self.where = where
        self._begin = None  # set by a backend that begins its own transactions (sqlite)

    def __enter__(self) -> "Store":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the connection (a record not yet committed is rolled back)."""
        self.connection.close()

    def sql(self, text: str) -> str:
        """A statement written with `?` placeholders, in this backend's placeholder."""
        return text.replace("?", self.dialect.placeholder)

    @contextmanager
    def transaction(self, exclusive: bool = False):
        """A cursor inside one transaction: committed when the block ends, rolled back if it
        raises. exclusive: take the write lock at once (sqlite BEGIN IMMEDIATE). Driver errors
        become RecordStoreError."""
        try:
            with self.dialect_transaction(exclusive) as cur:
                yield cur
        except self.dialect.errors as exc:
            raise RecordStoreError(f"the record store {self.where} failed: "
                                   f"{' '.join(str(exc).split())}; {self.dialect.advice}") from None

    def dialect_transaction(self, exclusive: bool):
        """The backend's transaction (a context manager yielding a cursor)."""
        raise NotImplementedError

    def add(self, record: Record) -> int | None:
        """Store one record and its parameters in one transaction; its id, or None when a record
        of the same calibration file (sha256) is already there."""
        row = record.row()
        names = (*COLUMNS, "recorded", "parameter_count")
        values = (*row.values(), utc_now(), len(record.parameters))
        with self.transaction(exclusive=True) as cur:
            cur.execute(self.sql(f"INSERT INTO calibrations ({', '.join(names)}) VALUES "
                                 f"({', '.join('?' * len(names))}) ON CONFLICT "
                                 "(calibration_sha256) DO NOTHING RETURNING id"), values)
            found = cur.fetchone()
            if found is None:
                return None
            cur.executemany(self.sql("INSERT INTO parameters (calibration_id, name, sensor, "
                                     "value, sigma, unit) VALUES (?, ?, ?, ?, ?, ?)"),
                            [(found[0], p.name, p.sensor, p.value, p.sigma, p.unit)
                             for p in record.parameters])
        return int(found[0])

    def history(self, serial: str) -> list:
        """Every record of the unit `serial`, oldest first."""
        from station.records.query import Selection

        return self.records(Selection({"serial": serial}))

    def records(self, selection) -> list:
        """The records a `station.records.query.Selection` picks, with their parameters,
        oldest first (by calibration time, then id)."""
        where, values = selection.where()
        columns = ("id", "recorded", *COLUMNS)
        with self.transaction() as cur:
            cur.execute(self.sql(f"SELECT {', '.join(columns)} FROM calibrations {where} "
                                 "ORDER BY created, id"), values)
            rows = cur.fetchall()
            cur.execute(self.sql("SELECT calibration_id, name, sensor, value, sigma, unit FROM "
                                 f"parameters WHERE calibration_id IN (SELECT id FROM "
                                 f"calibrations {where}) ORDER BY calibration_id, name, sensor"),
                        values)
            params = {}
            for cid, *p in cur.fetchall():
                params.setdefault(cid, []).append(Parameter(*p))
        return [Record(**dict(zip(columns, row, strict=True)),
                       parameters=tuple(params.get(row[0], ()))) for row in rows]

    def series(self, selection) -> list:
        """[(name, sensor, unit, record ids, values)] of every parameter, sensor and unit over the
        records `selection` picks (ids int64 and values float arrays, in no particular order):
        the control charts' input, read one at a time through the index parameters_series, two
        numbers a row."""
        import numpy as np

        where, values = selection.where()
        picked = f" AND calibration_id IN (SELECT id FROM calibrations {where})" if where else ""
        out = []
        with self.transaction() as cur:
            cur.execute("SELECT DISTINCT name, sensor, unit FROM parameters "
                        "ORDER BY name, sensor, unit")
            for key in cur.fetchall():
                cur.execute(self.sql("SELECT calibration_id, value FROM parameters WHERE "
                                     f"name = ? AND sensor = ? AND unit = ?{picked}"),
                            (*key, *values))
                rows = np.array(cur.fetchall(), dtype=float).reshape(-1, 2)
                out.append((*key, rows[:, 0].astype(np.int64), rows[:, 1]))
        return out

    def summaries(self, selection) -> list:
        """(id, unit_serial, model, bench, session_sha256, created, verdict, table_rate_error,
        chamber_settling_s) of the records `selection` picks, oldest first."""
        where, values = selection.where()
        with self.transaction() as cur:
            cur.execute(self.sql("SELECT id, unit_serial, model, bench, session_sha256, created, "
                                 "verdict, table_rate_error, chamber_settling_s FROM calibrations "
                                 f"{where} ORDER BY created, id"), values)
            return cur.fetchall()

    def incomplete(self) -> list:
        """Ids of records whose parameter rows are not all there (none, in a sound store: a
        record and its parameters are one transaction)."""
        with self.transaction() as cur:
            cur.execute("SELECT c.id FROM calibrations c LEFT JOIN parameters p ON "
                        "p.calibration_id = c.id GROUP BY c.id, c.parameter_count "
                        "HAVING COUNT(p.calibration_id) <> c.parameter_count")
            return [row[0] for row in cur.fetchall()]

    def integrity(self) -> str | None:
        """The backend's own check of its storage: "ok" or what is damaged; None where the
        station cannot ask (a PostgreSQL server checks its own pages)."""
        return None

    def count(self) -> int:
        """How many records the store holds."""
        with self.transaction() as cur:
            cur.execute("SELECT COUNT(*) FROM calibrations")
            return int(cur.fetchone()[0])


def store_url(db: str | None = None, near=None) -> tuple:
    """(url, explicit): `db` (--db) if given, else the environment's STATION_DB, else the default
    store `station.db` in the directory `near` (the calibration file's; default: the working
    directory). explicit: the command line named the store (--db: then a failed write makes the
    command fail; a line's STATION_DB keeps solving while its server is down)."""
    if db:
        return db, True
    if os.environ.get(ENV):
        return os.environ[ENV], False
    return f"sqlite:///{Path(near or '.') / DEFAULT_NAME}", False


def open_store(url: str, create: bool = True) -> Store:
    """The store at `url` (URL_FORMS), its schema migrated to this station's. create False: a
    SQLite file must exist already (a query names a store, it does not make one)."""
    if url.startswith(("postgresql://", "postgres://")):
        from station.records.postgres import connect
    elif url.startswith("sqlite:///") or "://" not in url:
        from station.records.sqlite import connect
    else:
        raise InputError(f"record store URL {redact(url)!r}: give {URL_FORMS}")
    from station.records.schema import migrate

    store = connect(url, create)
    try:
        migrate(store)
    except BaseException:
        store.close()
        raise
    return store


def redact(url: str) -> str:
    """The URL without its password (user:secret@host -> user:***@host)."""
    scheme, sep, rest = url.partition("://")
    if not sep or "@" not in rest.split("/", 1)[0]:
        return url
    auth, host = rest.split("@", 1)
    user = auth.split(":", 1)[0]
    return f"{scheme}://{user}{':***' if ':' in auth else ''}@{host}"
