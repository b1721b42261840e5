"""Where a calibration came from, as its record says: the session file's sha256, the unit's
model and lot, the bench and its devices, the bench profile's hash, and the bench's health in
that session (the table's rate error, a thermal chamber's settling).

Everything here is read from what the session recorded (its metadata: the bench profile's tables
and the device profiles, `station.acquire.bench.record`; its table stream); a figure the session
does not have is left out (None in the record). A session that cannot be read leaves only its
path: a record is never refused for its session's sake.
"""

import hashlib
import json
from pathlib import Path

import numpy as np

from station.errors import StationError

CHUNK = 1 << 20


def file_sha256(path) -> str:
    """The sha256 (hex) of a file's bytes, read a MiB at a time."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(CHUNK):
            digest.update(block)
    return digest.hexdigest()


def session_facts(path) -> dict:
    """The record's fields a session (a session file, or a thermal campaign's directory) gives:
    session_path and, where they can be read, session_sha256, model, lot, bench, table_id,
    chamber_id, imu_link, profile_sha256, table_rate_error, chamber_settling_s."""
    path = Path(path)
    facts = {"session_path": str(path)}
    try:
        if path.is_dir():
            return {**facts, **_campaign_facts(path)}
        if path.is_file():
            return {**facts, "session_sha256": file_sha256(path), **_file_facts(path)}
    except (StationError, OSError, ValueError, KeyError, TypeError):
        pass  # what could be read stays; the record names the session's path
    return facts


def _file_facts(path) -> dict:
    """session_facts of one session file."""
    from station.session import Session

    with Session.open(path) as session:
        return {**bench_facts(session.metadata), "table_rate_error": table_rate_error(session)}


def _campaign_facts(directory: Path) -> dict:
    """session_facts of a thermal campaign: its manifest's sha256, the devices of its first soak's
    session, the median table rate error over the soaks and the longest soak's settling time."""
    from station.session.campaign import Campaign, manifest_path

    manifest = manifest_path(directory)
    campaign = Campaign.load(directory)
    files = [directory / s["file"] for s in campaign.soaks if (directory / s["file"]).is_file()]
    soaks = [_file_facts(f) for f in files]
    rates = [s["table_rate_error"] for s in soaks if s["table_rate_error"] is not None]
    settling = [float(s["soak_seconds"]) for s in campaign.soaks if "soak_seconds" in s]
    return {**(soaks[0] if soaks else {}), "session_sha256": file_sha256(manifest),
            "table_rate_error": float(np.median(rates)) if rates else None,
            "chamber_settling_s": max(settling) if settling else None}


def bench_facts(metadata: dict) -> dict:
    """model, lot, bench, table_id, chamber_id, imu_link and profile_sha256 from a session's
    metadata (the recorded bench profile and device profiles); None where not recorded."""
    bench = metadata.get("bench") or {}
    tables = bench.get("tables") or {}
    profiles = metadata.get("profiles") or {}
    models = [p["imu"]["name"] for p in profiles.values()
              if isinstance(p, dict) and isinstance(p.get("imu"), dict) and "name" in p["imu"]]
    recorded = {"bench": tables, "profiles": profiles}
    return {"model": models[0] if models else None,
            "lot": metadata.get("lot") or (tables.get("bench") or {}).get("lot"),
            "bench": (tables.get("bench") or {}).get("name")
            or (Path(bench["profile"]).stem if bench.get("profile") else None),
            "table_id": device_id(tables.get("table"), (profiles.get("table") or {}).get("table")),
            "chamber_id": device_id(tables.get("chamber"), None),
            "imu_link": link_id(tables.get("imu")),
            "profile_sha256": hashlib.sha256(json.dumps(recorded, sort_keys=True).encode())
            .hexdigest() if tables else None}


def device_id(section: dict | None, profile: dict | None) -> str | None:
    """A device's identity: its register map's name (or profile) and its address (host:port, or
    serial port and device id); None when the bench had no such device."""
    if not isinstance(section, dict):
        return None
    name = (profile or {}).get("name") or section.get("profile") or "?"
    if "host" in section:
        return f"{name} at {section['host']}:{section.get('port', 502)}"
    where = section.get("serial_port") or section.get("port")
    return f"{name} at {where}" if where else str(name)


def link_id(section: dict | None) -> str | None:
    """The IMU link: its kind and where it is (port, CAN channel, URL)."""
    if not isinstance(section, dict):
        return None
    where = next((section[k] for k in ("port", "channel", "url", "device") if k in section), "")
    return f"{section.get('link', '?')} {where}".strip()


def table_rate_error(session) -> float | None:
    """The table's relative rate error over the session: the median over its at-rate states of
    measured / commanded - 1 (a table whose registers echo the command shows 0 here: only an
    encoder on the shaft sees the error). None without a table or an at-rate state."""
    try:
        table = session.table()
    except (StationError, KeyError):
        return None
    steady = table.flag("at_rate") & (np.abs(table.rate_setpoint) > 0)
    if not steady.any():
        return None
    return float(np.median(table.rate[steady] / table.rate_setpoint[steady] - 1.0))
