"""What one calibration record holds: the unit, the verdict, every parameter with its 1-sigma,
where the calibration came from (files and their sha256, bench, devices, software, operator,
host, time) and the bench's health figures of that session.

Values are SI (rad/s, m/s^2, T, s; scale factors and rate errors are ratios, 1); each parameter
row names its unit. `Record.from_calibration` builds a record from a calibration file
(`station.calfiles.calfile.Calibration`) and what its session says (`station.records.sources`).
"""

import getpass
import json
import os
import socket
from dataclasses import dataclass, field, fields

KINDS = ("session", "campaign", "combined")
"""What a record's calibration was made from: one session's solve, a thermal campaign's solve,
or `station combine` over several calibration files."""


@dataclass(frozen=True)
class Parameter:
    """One estimated figure of one sensor: name (bias, scale_factor, noise_white, ...), the
    sensor's name, its value and 1-sigma (None: not known) in `unit`."""

    name: str
    sensor: str
    value: float
    sigma: float | None
    unit: str


@dataclass(frozen=True)
class Record:
    """One calibration of one unit, as the store keeps it (docs/records.md, "Schema").

    created is the calibration's time (ISO 8601 UTC); tolerances the verdict's limits (JSON
    text) or None; table_rate_error the table's relative rate error over the session's rotating
    windows (measured / commanded - 1); chamber_settling_s the longest soak's settling time of a
    thermal campaign. `id` and `recorded` (when it was stored) are set by the store."""

    unit_serial: str
    kind: str
    created: str
    calibration_sha256: str
    parameters: tuple = ()
    model: str | None = None
    lot: str | None = None
    verdict: str | None = None
    tolerances: str | None = None
    status: str | None = None
    chi2: float | None = None
    dof: int | None = None
    positions: int | None = None
    method: str | None = None
    calibration_path: str | None = None
    session_path: str | None = None
    session_sha256: str | None = None
    profile_sha256: str | None = None
    bench: str | None = None
    table_id: str | None = None
    chamber_id: str | None = None
    imu_link: str | None = None
    station_version: str | None = None
    operator: str | None = field(default_factory=lambda: operator())
    host: str | None = field(default_factory=socket.gethostname)
    table_rate_error: float | None = None
    chamber_settling_s: float | None = None
    id: int | None = None
    recorded: str | None = None

    @classmethod
    def from_calibration(cls, cal, path, kind: str = "session") -> "Record":
        """The record of the calibration `cal` written to the file `path`; the session it names
        (`cal.session["path"]`) is read for its hash, devices and health where it still exists."""
        from station.records.sources import file_sha256, session_facts

        if kind not in KINDS:
            raise ValueError(f"kind {kind!r}: one of {KINDS}")
        source = (cal.session or {}).get("path")
        verdict = cal.verdict or {}
        return cls(unit_serial=cal.unit_serial, kind=kind, created=cal.created,
                   calibration_sha256=file_sha256(path), parameters=parameters(cal),
                   verdict=verdict.get("overall"),
                   tolerances=tolerances(verdict),
                   status=cal.fit.get("status"), chi2=_number(cal.fit.get("chi2")),
                   dof=cal.fit.get("dof"), positions=cal.fit.get("positions"),
                   method=cal.fit.get("method"), calibration_path=str(os.path.abspath(path)),
                   station_version=cal.software_version,
                   **(session_facts(source) if source else {}))

    def row(self) -> dict:
        """The calibrations table's columns of this record (COLUMNS), by name."""
        return {name: getattr(self, name) for name in COLUMNS}


COLUMNS = tuple(f.name for f in fields(Record) if f.name not in ("parameters", "id", "recorded"))
"""The columns a record writes into the calibrations table, in order."""


def parameters(cal) -> tuple:
    """Every parameter of a calibration with its 1-sigma: each sensor's bias and scale factor,
    and its noise figures (white-noise density, bias instability, random walk) where measured."""
    unit = cal.units[0]
    rows = [Parameter("bias", s, float(v), float(e), unit)
            for s, v, e in zip(cal.sensors, cal.bias, cal.bias_sigma, strict=True)]
    rows += [Parameter("scale_factor", s, float(v), float(e), "1")
             for s, v, e in zip(cal.sensors, cal.scale_factors, cal.scale_factors_sigma,
                                strict=True)]
    if cal.noise is not None:
        doc = cal.noise.to_document(unit)
        for term in ("white", "bias_instability", "random_walk"):
            if doc[term] is not None:
                rows += [Parameter(f"noise_{term}", s, float(v), float(e), doc["units"][term])
                         for s, v, e in zip(cal.sensors, doc[term], doc[f"{term}_sigma"],
                                            strict=True)]
    return tuple(rows)


def tolerances(verdict: dict) -> str | None:
    """The limits a verdict judged against, as JSON text {"scale_factor": T, "bias": T,
    "axis_angle_deg": T} (the kinds it tested), None without a verdict."""
    kinds = {"scale factor": "scale_factor", "bias": "bias", "(deg)": "axis_angle_deg"}
    limits = {kind: p["limit"] for p in verdict.get("parameters", ())
              for words, kind in kinds.items() if p["name"].endswith(words)}
    return json.dumps(limits, sort_keys=True) if verdict else None


def operator() -> str | None:
    """Who runs the station: STATION_OPERATOR, else the login name (None if neither is known)."""
    try:
        return os.environ.get("STATION_OPERATOR") or getpass.getuser()
    except (KeyError, OSError):
        return None


def _number(x) -> float | None:
    """x as a float, None kept."""
    return None if x is None else float(x)
