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
