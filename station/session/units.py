"""The units of a session recorded with several units on one table (docs/session-format.md,
"Several units"): each unit's stream, serial number and mounting on the plate, read from the
session's (untrusted) metadata `units`.

A one-unit session has no `units` entry: its one unit is the session's `unit_serial` on stream
`imu`, as always.
"""

import re
from dataclasses import dataclass

import numpy as np

from station.errors import SessionFormatError

SERIAL = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}\Z")
"""A unit serial: it names files (SESSION.<serial>.cal.json), so no path separators."""


@dataclass(frozen=True)
class SessionUnit:
    """One unit of a session.

    stream      : its sample stream ("imu", "imu2", ...)
    unit_serial : its serial number (names its calibration file)
    mounting    : (3, 3) rotation plate frame -> unit frame, None when the profile gave none
    """

    stream: str
    unit_serial: str
    mounting: np.ndarray | None = None

    def to_json(self) -> dict:
        """The metadata entry of the unit (`recorded_units` reads it back)."""
        mounting = None if self.mounting is None else np.asarray(self.mounting).tolist()
        return {"stream": self.stream, "unit_serial": self.unit_serial, "mounting": mounting}


def unit_stream(k: int) -> str:
    """The stream name of unit k (0-based) on a plate: "imu", "imu2", "imu3", ..."""
    return "imu" if k == 0 else f"imu{k + 1}"


def recorded_units(metadata: dict, streams, path) -> list:
    """The `SessionUnit`s of a session with several units, [] for a one-unit session (no `units`
    in its metadata); SessionFormatError names an entry that is not a unit of the file: an
    unknown stream, a serial that cannot name a file, a repeated one, a mounting that is not a
    3 x 3 rotation."""
    entries = metadata.get("units")
    if entries is None:
        return []
    if not isinstance(entries, list) or not entries:
        raise SessionFormatError(f"{path}: metadata 'units' must be a non-empty list of units")
    units = [_unit(e, streams, path) for e in entries]
    for key in ("stream", "unit_serial"):
        values = [getattr(u, key) for u in units]
        if len(set(values)) != len(values):
            raise SessionFormatError(f"{path}: metadata 'units' repeats a {key} ({values})")
    return units


def _unit(entry, streams, path) -> SessionUnit:
    """One metadata entry of `units`, checked."""
    if not isinstance(entry, dict):
        raise SessionFormatError(f"{path}: metadata 'units' holds {entry!r}, not a unit")
    stream, serial = entry.get("stream"), entry.get("unit_serial")
    if stream not in streams:
        raise SessionFormatError(f"{path}: metadata 'units' names stream {stream!r}; the file's "
                                 f"streams are {sorted(streams)}")
    if not isinstance(serial, str) or not SERIAL.match(serial):
        raise SessionFormatError(f"{path}: unit serial {serial!r} of stream {stream!r} must be "
                                 "1-64 letters, digits, '.', '_' or '-'")
    return SessionUnit(stream, serial, _mounting(entry.get("mounting"), stream, path))


def _mounting(value, stream: str, path) -> np.ndarray | None:
    """A unit's mounting (None, or a 3 x 3 rotation within 1e-6)."""
    if value is None:
        return None
    try:
        r = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        r = np.zeros(0)
    if r.shape != (3, 3) or not np.all(np.isfinite(r)) or \
            not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise SessionFormatError(f"{path}: the mounting of stream {stream!r} is not a 3 x 3 "
                                 "rotation (rows orthonormal, determinant +1)")
    return r


def unit_serial(metadata: dict, streams, stream: str, path) -> str | None:
    """The serial of the unit recorded on `stream`, None when the session records one unit (its
    `unit_serial` then) or `stream` is none of its units'."""
    found = [u.unit_serial for u in recorded_units(metadata, streams, path) if u.stream == stream]
    return found[0] if found else None
