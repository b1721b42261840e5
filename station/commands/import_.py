"""`station import`: a foreign recording into a new session file (station/files/importers.py)."""

import argparse
from pathlib import Path

EXAMPLES = """examples:
  station import text xsens.h5 --stream accel=xsens_acc.mat --unit accel=counts:m/s^2 \\
      --stream gyro=xsens_gyro.mat --unit gyro=counts:rad/s
  station import csv ferraris.h5 example_ferraris_session.csv --fs 102.4 --index n_samples \\
      --stream acc=acc_x,acc_y,acc_z --unit acc=m/s^2 --stream gyr=gyr_x,gyr_y,gyr_z --unit gyr=deg/s
  station import npz rotary.h5 recording.npz"""


def register(sub) -> None:
    p = sub.add_parser(
        "import", help="convert a foreign recording (text, CSV, .npz) into a session file",
        description=__doc__ + " Units: m/s^2, g, rad/s, deg/s, T, uT, gauss, or raw counts "
        "counts:<SI unit>[@<counts per SI unit>].", epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("format", choices=("text", "csv", "npz"), help="format of the recording")
    p.add_argument("out", type=Path, help="session file to create (.h5, must not exist)")
    p.add_argument("source", nargs="?", type=Path, help="the CSV or .npz file")
    p.add_argument("--stream", action="append", default=[], metavar="NAME=WHAT",
                   help="text: NAME=FILE (columns t x y z ...); csv: NAME=COL,COL,...")
    p.add_argument("--unit", action="append", default=[], metavar="NAME=UNIT",
                   help="unit of a stream's numbers")
    p.add_argument("--time", metavar="COLUMN", help="csv: column of time stamps in seconds")
    p.add_argument("--index", metavar="COLUMN", help="csv: column of sample numbers (with --fs)")
    p.add_argument("--fs", type=float, help="sample rate, Hz")
    p.add_argument("--unit-serial", default="IMPORTED", help="serial number of the unit")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.errors import CalibrationInputError
    from station.files.importers import import_csv, import_npz, import_text

    if args.out.exists():
        raise SystemExit(f"station import: {args.out} exists; choose another name")
    try:
        streams, units = _pairs(args.stream, "--stream"), _pairs(args.unit, "--unit")
        if args.format == "text":
            out = import_text(args.out, streams, units, unit_serial=args.unit_serial, fs=args.fs)
        elif args.source is None:
            raise SystemExit(f"station import {args.format}: give the source file")
        elif args.format == "csv":
            columns = {name: [c.strip() for c in what.split(",")] for name, what in streams.items()}
            out = import_csv(args.out, args.source, columns, units, time_column=args.time,
                             index_column=args.index, fs=args.fs, unit_serial=args.unit_serial)
        else:
            out = import_npz(args.out, args.source, unit_serial=args.unit_serial)
    except (CalibrationInputError, OSError) as exc:
        print(f"station import: {exc}")
        return 2
    print(f"wrote {out}")
    return 0


def _pairs(items, option: str) -> dict:
    from station.errors import CalibrationInputError

    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name or not value or name in out:
            raise CalibrationInputError(f"{option} {item!r} is not NAME=VALUE (once per name).",
                                        f"Write e.g. {option} accel=...")
        out[name] = value
    return out
