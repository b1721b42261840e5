"""Where a file came from: the software version and the creation time, as every file records
them."""

import importlib.metadata
from datetime import UTC, datetime


def utc_now() -> str:
    """The present time, ISO 8601 in UTC to the second (e.g. 2026-11-21T10:00:00Z)."""
    return datetime.now(UTC).isoformat(timespec="seconds").replace("+00:00", "Z")


def software_version() -> str:
    """This package's installed version, or "unknown" when it runs from an uninstalled tree."""
    try:
        return importlib.metadata.version("imu-station")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"
