"""The crash-safe HDF5 session file: one unit, one protocol run (format: docs/session-format.md).

    format.py   names, version, columns, units and the data classes (StreamSpec, StreamData, ...)
    writer.py   SessionWriter (create, append, events, resume) and write_results
    reader.py   Session: reads a file, also while a writer is live (SWMR read)
    _repair.py  the HDF5 superblock's open-for-write flags a killed writer leaves, cleared on resume

This namespace is the public interface; the modules' other names are the package's own.
"""

from station.errors import SessionFormatError, SessionLockedError
from station.files.session.format import (
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
from station.files.session.reader import Session
from station.files.session.writer import SessionWriter, write_results

__all__ = [
    "EVENT_KINDS", "FORMAT_VERSION", "TABLE_STATUS_BITS", "Event", "Session", "SessionFormatError",
    "SessionLockedError", "SessionResults", "SessionWriter", "StreamData", "StreamSpec",
    "TableData", "last_completed_position", "nominal_layout", "write_results",
]
