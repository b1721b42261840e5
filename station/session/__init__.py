"""The crash-safe HDF5 session file: one unit, one protocol run (format: docs/session-format.md),
and the thermal campaign: a directory of session files, one per chamber setpoint, and its manifest.

    format.py   names, version, columns, units and the data classes (StreamSpec, StreamData, ...)
    writer.py   SessionWriter (create, append, events, resume) and write_results
    reader.py   Session: reads a file, also while a writer is live (SWMR read)
    check.py    checked: the whole file read back once in a child process, its CPU time bounded
    units.py    the units of a session of several units on one table (metadata `units`)
    torn.py     the last chunk a killed writer left half-written, told from damage and cut off
    _repair.py  the HDF5 superblock's open-for-write flags a killed writer leaves, cleared on resume
    campaign.py the thermal campaign's manifest (campaign.json)

This namespace is the public interface; the modules' other names are the package's own.
"""

from station.errors import SessionFormatError, SessionLockedError
from station.session.format import (
    COUNTS,
    EVENT_KINDS,
    FORMAT_VERSION,
    TABLE_STATUS_BITS,
    Event,
    SessionResults,
    StreamData,
    StreamSpec,
    TableData,
    last_completed_position,
    nominal_layout,
)

_LAZY = {"Session": "station.session.reader",
         "SessionWriter": "station.session.writer",
         "write_results": "station.session.writer"}
"""Imported on first use (PEP 562, as `station` itself does): reading and writing results load the
solver (scipy), which `python -m station.session.check` does not need."""


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = [
    "COUNTS", "EVENT_KINDS", "FORMAT_VERSION", "TABLE_STATUS_BITS", "Event", "Session",
    "SessionFormatError", "SessionLockedError", "SessionResults", "SessionWriter", "StreamData",
    "StreamSpec", "TableData", "last_completed_position", "nominal_layout", "write_results",
]
