"""Recognise a Kalibr/ROS-style IMU CSV by its header, so that `station import csv` reads it
without the user spelling out columns, units and the time unit.

The layout: kalibr's wiki ("Bag format", the CSV its bagcreater turns into a ROS bag):
`timestamp [ns], omega_x, omega_y, omega_z [rad/s], alpha_x, alpha_y, alpha_z [m/s^2]`, and the
EuRoC MAV dataset's `imu0/data.csv` (the same layout): `#timestamp [ns],w_RS_S_x [rad s^-1],
w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]`.
The header is the first line, comma-separated, its first field may start with `#`; a unit in
brackets, when there, must be the layout's.
"""

import re
from dataclasses import dataclass
from pathlib import Path

from station.errors import CalibrationInputError

GYRO = (("omega_x", "omega_y", "omega_z"), ("w_rs_s_x", "w_rs_s_y", "w_rs_s_z"))
ACC = (("alpha_x", "alpha_y", "alpha_z"), ("a_rs_s_x", "a_rs_s_y", "a_rs_s_z"))
"""Column names (lower case, without units) of the gyro and accelerometer, per dialect."""

UNITS = {"timestamp": ("ns",), "gyro": ("rad/s", "rad s^-1"), "acc": ("m/s^2", "m s^-2")}
"""Units a column may declare in brackets."""

HEADER_CHARS = 4096
"""Longest first line looked at."""


@dataclass(frozen=True)
class Layout:
    """A recognised IMU CSV: the time column (ns), the stream columns and units, as
    station.imports.recordings.import_csv takes them, and a note saying so."""

    time_column: str
    streams: dict
    units: dict
    note: str


def recognise(path) -> Layout:
    """The Kalibr/EuRoC layout of the CSV at `path`, or a CalibrationInputError saying what was
    found and to name the columns instead."""
    path = Path(path)
    with path.open(encoding="utf-8-sig", errors="replace") as f:
        line = f.readline(HEADER_CHARS)
    fields = [field.strip() for field in line.strip().split(",")]
    parsed = [_name_and_unit(field) for field in fields]
    names, units = tuple(n for n, _ in parsed), tuple(u for _, u in parsed)
    if len(fields) == 7 and names[0] == "timestamp":
        for gyro, acc in zip(GYRO, ACC, strict=True):
            if names[1:] == gyro + acc and _units_fit(units):
                return Layout(fields[0], {"gyro": list(fields[1:4]), "acc": list(fields[4:])},
                              {"gyro": "rad/s", "acc": "m/s^2"},
                              f"{path.name}: recognised as a Kalibr/EuRoC IMU CSV (time in ns, "
                              "gyro rad/s, accelerometer m/s^2)")
    raise CalibrationInputError(
        f"{path}: no --stream given and the first line is not a Kalibr/EuRoC IMU header "
        f"('timestamp [ns], omega_x, omega_y, omega_z, alpha_x, alpha_y, alpha_z'; found "
        f"{line.strip()[:120]!r}).",
        "Name the columns: --stream acc=COL,COL,COL --unit acc=m/s^2 --time COL (docs/cli.md).")


def _name_and_unit(field: str) -> tuple:
    """('omega_x', 'rad/s') of 'omega_x [rad/s]'; the name lower case without a leading '#'."""
    match = re.fullmatch(r"#?\s*([^\[\]]*?)\s*(?:\[([^\]]*)\])?", field)
    if match is None:
        return field.lower(), None
    return match.group(1).lower(), match.group(2)


def _units_fit(units) -> bool:
    """Whether each declared unit is the layout's (undeclared ones are taken as the layout's)."""
    kinds = ("timestamp", *["gyro"] * 3, *["acc"] * 3)
    return all(u is None or u.strip() in UNITS[k] for u, k in zip(units, kinds, strict=True))
