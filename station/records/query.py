"""Which records a question is about: `Selection.parse("model=X since=2026-11-01")`.

Words KEY=VALUE separated by spaces, all of which a record must meet:

    serial=SN1234   model=imu12-serial   lot=L7   bench=bench2   verdict=PASS|FAIL|MARGINAL
    kind=session|campaign|combined   operator=NAME   host=NAME   session=SHA256
    table=TEXT   chamber=TEXT   imu=TEXT     (a part of the device's identity, e.g. its address)
    since=2026-11-01   until=2026-11-08     (calibration time, UTC: since <= created < until)

Each key maps to one fixed SQL condition and each value is passed as a parameter: the words
never become SQL.
"""

from dataclasses import dataclass, field
from pathlib import Path

from station.errors import InputError

CONDITIONS = {
    "serial": "unit_serial = ?", "model": "model = ?", "lot": "lot = ?", "bench": "bench = ?",
    "verdict": "verdict = ?", "kind": "kind = ?", "operator": "operator = ?", "host": "host = ?",
    "session": "session_sha256 = ?",
    "table": "table_id LIKE ?", "chamber": "chamber_id LIKE ?", "imu": "imu_link LIKE ?",
    "since": "created >= ?", "until": "created < ?",
}
"""key -> the condition on the calibrations table (its one `?` takes the value)."""
PARTIAL = ("table", "chamber", "imu")
"""Keys matched on a part of the column (LIKE %value%)."""


@dataclass(frozen=True)
class Selection:
    """The conditions of a question: {key: value} over CONDITIONS' keys (empty: every record)."""

    terms: dict = field(default_factory=dict)

    @classmethod
    def parse(cls, text: str) -> "Selection":
        """The selection written as words KEY=VALUE (the module's docstring)."""
        terms = {}
        for word in text.split():
            key, sep, value = word.partition("=")
            if not sep or not value:
                raise InputError(f"{word!r} in the record query {text!r}: write KEY=VALUE, "
                                 f"KEY one of {', '.join(CONDITIONS)}")
            if key not in CONDITIONS:
                raise InputError(f"unknown key {key!r} in the record query {text!r}: use "
                                 f"{', '.join(CONDITIONS)}")
            if key in terms:
                raise InputError(f"{key!r} given twice in the record query {text!r}")
            terms[key] = value
        return cls(terms)

    def where(self, prefix: str = "") -> tuple:
        """(WHERE clause or "", values): the conditions with `?` placeholders, columns prefixed
        by `prefix` (a table alias, e.g. "c.")."""
        if not self.terms:
            return "", ()
        clauses = [prefix + CONDITIONS[key] for key in self.terms]
        values = tuple(f"%{v}%" if key in PARTIAL else v for key, v in self.terms.items())
        return "WHERE " + " AND ".join(clauses), values


def recorded_files(store, selection: Selection, kind: str, words: str) -> list:
    """The calibration files of the records of `kind` (session, campaign, combined) that
    `selection` (written as `words`) picks, oldest first. Refused (InputError): none picked, a
    file gone, or a file whose sha256 is no longer the recorded one (edited or replaced since)."""
    from station.records.sources import file_sha256

    records = [r for r in store.records(selection) if r.kind == kind]
    if not records:
        raise InputError(f"no {kind} calibration in the record store {store.where} matches "
                         f"{words!r}")
    for r in records:
        if r.calibration_path is None or not Path(r.calibration_path).is_file():
            raise InputError(f"record {r.id} ({r.unit_serial}, {r.created}): its calibration "
                             f"file {r.calibration_path} is gone; narrow the query or restore it")
        if file_sha256(r.calibration_path) != r.calibration_sha256:
            raise InputError(f"{r.calibration_path} changed since it was recorded (record "
                             f"{r.id}): its sha256 differs; restore it or narrow the query")
    return [Path(r.calibration_path) for r in records]
