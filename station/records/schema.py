"""The record store's schema and its numbered migrations.

The store holds a `schema_version` table: one row per migration applied (its number, when, what).
`migrate` applies the missing ones in order, all in one transaction (a station killed meanwhile
leaves the store as it was), under a lock so that two stations opening one new PostgreSQL
database at once do not both create it. A store whose version is above `LATEST` was made by a
newer station: it is refused (`NewerStoreError`), never written.

A migration is a list of statements written once for both SQL dialects; `{id}`, `{real}` and
`{without_rowid}` stand for the spellings that differ (`Dialect.types`). Add a migration at the
end of `MIGRATIONS`, never edit one that was released (docs/records.md, "Migrations").
"""

from station.errors import NewerStoreError
from station.files.provenance import utc_now

MIGRATIONS = (
    ("calibrations and their parameters", (
        """CREATE TABLE calibrations (
            id {id},
            unit_serial TEXT NOT NULL,
            kind TEXT NOT NULL,
            created TEXT NOT NULL,
            calibration_sha256 TEXT NOT NULL UNIQUE,
            model TEXT, lot TEXT, verdict TEXT, tolerances TEXT, status TEXT,
            chi2 {real}, dof INTEGER, positions INTEGER, method TEXT,
            calibration_path TEXT, session_path TEXT, session_sha256 TEXT, profile_sha256 TEXT,
            bench TEXT, table_id TEXT, chamber_id TEXT, imu_link TEXT,
            station_version TEXT, operator TEXT, host TEXT,
            table_rate_error {real}, chamber_settling_s {real},
            recorded TEXT NOT NULL,
            parameter_count INTEGER NOT NULL)""",
        """CREATE TABLE parameters (
            calibration_id BIGINT NOT NULL REFERENCES calibrations (id) ON DELETE CASCADE,
            name TEXT NOT NULL,
            sensor TEXT NOT NULL,
            value {real} NOT NULL,
            sigma {real},
            unit TEXT NOT NULL,
            PRIMARY KEY (calibration_id, name, sensor)){without_rowid}""",
        "CREATE INDEX calibrations_unit ON calibrations (unit_serial, created)",
        "CREATE INDEX calibrations_model ON calibrations (model, created)",
        "CREATE INDEX calibrations_bench ON calibrations (bench, created)",
        "CREATE INDEX calibrations_created ON calibrations (created)",
        # the control charts read one parameter of one sensor over every record
        "CREATE INDEX parameters_series ON parameters (name, sensor, unit, calibration_id, "
        "value)",
    )),
)
"""(description, statements) of migration 1, 2, ... in order."""

LATEST = len(MIGRATIONS)

VERSION_TABLE = ("CREATE TABLE IF NOT EXISTS schema_version (version INTEGER PRIMARY KEY, "
                 "applied TEXT NOT NULL, description TEXT NOT NULL)")


def version(cur, store) -> int:
    """The store's schema version (0: none yet), read in the transaction of cursor `cur`."""
    cur.execute(store.dialect.has_versions)
    if not cur.fetchone()[0]:
        return 0
    cur.execute("SELECT MAX(version) FROM schema_version")
    return cur.fetchone()[0] or 0


def migrate(store) -> int:
    """Bring `store` (a `station.records.store.Store`) to the LATEST schema in one locked
    transaction; its version. A store already at LATEST is only read (a reader without write
    access can query it). NewerStoreError when the store is newer than this station."""
    with store.transaction() as cur:
        current = _known(version(cur, store), store)
    if current == LATEST:
        return current
    with store.transaction(exclusive=True) as cur:
        store.dialect.lock_schema(cur)  # first: PostgreSQL's CREATE TABLE IF NOT EXISTS races
        cur.execute(VERSION_TABLE)
        current = _known(version(cur, store), store)  # another station may have migrated it
        for number in range(current + 1, LATEST + 1):
            description, statements = MIGRATIONS[number - 1]
            for statement in statements:
                cur.execute(statement.format(**store.dialect.types))
            cur.execute(store.sql("INSERT INTO schema_version (version, applied, description) "
                                  "VALUES (?, ?, ?)"), (number, utc_now(), description))
    return LATEST


def _known(current: int, store) -> int:
    """`current`, unless it is newer than this station knows (NewerStoreError)."""
    if current > LATEST:
        raise NewerStoreError(
            f"the record store {store.where} has schema version {current}, made by a newer "
            f"station (this one knows versions up to {LATEST}): upgrade this station, or give "
            "another store (--db)")
    return current
