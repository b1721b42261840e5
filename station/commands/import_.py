"""`station import`: a foreign recording into a new session file (station/files/importers.py)."""

import json
from pathlib import Path

EXAMPLES = (
    "examples:\n"
    "  station import text xsens.h5 --stream accel=xsens_acc.mat --unit accel=counts:m/s^2 \\\n"
    "      --stream gyro=xsens_gyro.mat --unit gyro=counts:rad/s\n"
    "  station import csv ferraris.h5 example_ferraris_session.csv "
    "--fs 102.4 --index n_samples \\\n"
    "      --stream acc=acc_x,acc_y,acc_z --unit acc=m/s^2 "
    "--stream gyr=gyr_x,gyr_y,gyr_z --unit gyr=deg/s\n"
    "  station import npz rotary.h5 recording.npz"
)


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.description = (
        __doc__ + " Units: m/s^2, g, rad/s, deg/s, T, uT, gauss, or raw counts "
        "counts:<SI unit>[@<counts per SI unit>]."
    )
    p.epilog = EXAMPLES
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
    p.add_argument("--json", action="store_true", help="print the session written as JSON")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.commands import existing_file, new_file, progress
    from station.errors import InputError
    from station.files.importers import import_csv, import_npz, import_text

    new_file(args.out, option="name")
    streams, units = _pairs(args.stream, "--stream"), _pairs(args.unit, "--unit")
    with progress(f"importing into {args.out}", "bytes") as advance:
        if args.format == "text":
            for path in streams.values():
                existing_file(path, "a text recording (--stream NAME=FILE)")
            out = import_text(args.out, streams, units, unit_serial=args.unit_serial, fs=args.fs)
        elif args.source is None:
            raise InputError(f"`import {args.format}` needs the source file")
        elif args.format == "csv":
            source = existing_file(args.source, "a CSV recording")
            columns = {name: [c.strip() for c in what.split(",")] for name, what in streams.items()}
            out = import_csv(args.out, source, columns, units, time_column=args.time,
                             index_column=args.index, fs=args.fs, unit_serial=args.unit_serial,
                             progress=advance)
        else:
            out = import_npz(args.out, existing_file(args.source, "an .npz recording"),
                             unit_serial=args.unit_serial)
    if args.json:
        from station.files.session import Session

        with Session.open(out) as session:
            streams = {name: {"channels": list(s.channels), "units": list(s.units),
                              "rate_hz": s.rate_hz, "samples": len(session.stream(name).seq)}
                       for name, s in session.specs.items()}
        print(json.dumps({"session": str(out), "unit_serial": args.unit_serial,
                          "streams": streams}))
    else:
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
