"""`station import`: a foreign recording into a new session file (station/imports/recordings.py)."""

import json
from pathlib import Path

EXAMPLES = (
    "examples:\n"
    "  station import text xsens.h5 --stream accel=xsens_acc.mat --unit accel=counts:m/s^2 \\\n"
    "      --stream gyro=xsens_gyro.mat --unit gyro=counts:rad/s\n"
    "  station import text mpu.h5 --no-time --fs 100 --stream acc=imu0.log --columns acc=1-3 \\\n"
    "      --unit acc=m/s^2 --stream gyro=imu0.log --columns gyro=4-6 --unit gyro=rad/s\n"
    "  station import csv ferraris.h5 example_ferraris_session.csv "
    "--fs 102.4 --index n_samples \\\n"
    "      --stream acc=acc_x,acc_y,acc_z --unit acc=m/s^2 "
    "--stream gyr=gyr_x,gyr_y,gyr_z --unit gyr=deg/s\n"
    "  station import csv logger.h5 logger.csv --time t_us --time-unit us --delimiter ';' \\\n"
    "      --skip-rows 3 --stream acc=ax,ay,az --unit acc=g\n"
    "  station import npz rotary.h5 recording.npz\n"
    "  station import binary exp_1.h5 exp_1.bin --profile mimu4444\n"
    "  station import ulog px4.h5 log_12_2026-11-25.ulg --instance 1\n"
    "  station import ulog px4.h5 log_12_2026-11-25.ulg --topic sensor_combined\n"
    "  station import dataflash ardupilot.h5 00000042.BIN\n"
    "  station import dataflash raw.h5 00000042.BIN --batch   # the batch sampler's samples\n"
    "  station import csv euroc.h5 mav0/imu0/data.csv       # a Kalibr/EuRoC IMU CSV, recognised"
)

DELIMITER_NAMES = {"tab": "\t", "\\t": "\t", "space": " "}
"""Spellings of delimiters awkward to type."""


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.description = (
        __doc__ + " Units: m/s^2, g, rad/s, deg/s, T, uT, gauss, or raw counts "
        "counts:<SI unit>[@<counts per SI unit>]. text/csv: the delimiter is sniffed and lines "
        "before the header are skipped unless given; .mat files v5/v7 and v7.3 (HDF5) are read, "
        "arrays in either orientation (the time axis is the long one). binary: a raw dump of "
        "a serial IMU's frames, decoded by the drivers' parser with a device profile. "
        "ulog (PX4, pyulog) and dataflash (ArduPilot .bin, pymavlink): the IMU's accelerometer "
        "and gyro as streams acc and gyro in m/s^2 and rad/s, at their logged time stamps, the "
        "numbers exact; ulog: the fastest IMU topic logged (the notes list the candidates' rates; "
        "--topic chooses). text/csv time stamps that are a host's clock (bunched lines) are "
        "replaced by the device's counter (--index) or rate (--fs) when given, said in the "
        "notes. csv without --stream: a Kalibr/EuRoC IMU CSV is recognised by its header."
    )
    p.epilog = EXAMPLES
    p.add_argument("format", choices=("text", "csv", "npz", "binary", "ulog", "dataflash"),
                   help="format of the recording")
    p.add_argument("out", type=Path, help="session file to create (.h5, must not exist)")
    p.add_argument("source", nargs="?", type=Path,
                   help="the CSV, .npz, binary dump, .ulg or .bin log")
    p.add_argument("--stream", action="append", default=[], metavar="NAME=WHAT",
                   help="text: NAME=FILE (columns t x y z ...); csv: NAME=COL,COL,...")
    p.add_argument("--unit", action="append", default=[], metavar="NAME=UNIT",
                   help="unit of a stream's numbers")
    p.add_argument("--time", metavar="COLUMN", help="csv: column of time stamps")
    p.add_argument("--time-unit", choices=("s", "ms", "us", "ns"),
                   help="text/csv: unit of the time stamps (default s, checked for a plausible "
                        "rate)")
    p.add_argument("--columns", action="append", default=[], metavar="NAME=COLS",
                   help="text: a stream's value columns in its file, counted from 1 (e.g. "
                        "acc=1-3 or acc=2,3,4; default: every column after the time)")
    p.add_argument("--no-time", action="store_true",
                   help="text: the files have no time column; the rows are samples at --fs")
    p.add_argument("--index", metavar="COLUMN",
                   help="csv: column of the device's sample numbers (with --fs; with --time: "
                        "they place samples whose time stamps are a host's clock)")
    p.add_argument("--fs", type=float, help="sample rate, Hz")
    p.add_argument("--delimiter", metavar="CHAR",
                   help="text/csv: column delimiter (',', ';', tab, space; csv default: sniffed)")
    p.add_argument("--skip-rows", type=int, metavar="N",
                   help="text/csv: lines before the header (csv) or the numbers (text); csv "
                        "default: the header line is found")
    p.add_argument("--profile", metavar="PROFILE",
                   help="binary: device profile (bundled name or TOML path)")
    p.add_argument("--instance", type=int, metavar="N",
                   help="ulog/dataflash: the IMU instance (ULog multi_id, DataFlash IMU I or "
                        "IMU2/IMU3; default the first)")
    p.add_argument("--topic", metavar="NAME",
                   help="ulog: the IMU topic family (sensor_accel or sensor_gyro, "
                        "sensor_combined, vehicle_imu; default the fastest logged)")
    p.add_argument("--batch", action="store_true",
                   help="dataflash: the batch sampler's raw-rate samples (ISBH/ISBD) instead of "
                        "the IMU messages")
    p.add_argument("--unit-serial", default="IMPORTED", help="serial number of the unit")
    p.add_argument("--json", action="store_true", help="print the session written as JSON")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.commands import existing_file, new_file, progress

    new_file(args.out, option="name")
    with progress(f"importing into {args.out}", "bytes") as advance:
        out = _import(args, existing_file, advance)
    from station.session import Session

    with Session.open(out) as session:
        notes = session.metadata.get("import", {}).get("notes", [])
        streams = {name: {"channels": list(s.channels), "units": list(s.units),
                          "rate_hz": s.rate_hz, "samples": len(session.stream(name).seq)}
                   for name, s in session.specs.items()}
    if args.json:
        print(json.dumps({"session": str(out), "unit_serial": args.unit_serial,
                          "streams": streams, "notes": notes}))
    else:
        print(f"wrote {out}")
        for note in notes:
            print(f"  {note}")
    return 0


def _import(args, existing_file, advance) -> Path:
    """The importer of `args.format` called with the options given; `advance(done, total)` hears
    of the bytes read where the importer counts them (csv)."""
    from station.errors import InputError
    from station.imports import recordings

    if args.instance is not None and args.format not in ("ulog", "dataflash"):
        raise InputError(f"--instance is for flight-controller logs (ulog, dataflash), not "
                         f"`import {args.format}`; leave it out")
    if args.topic is not None and args.format != "ulog":
        raise InputError(f"--topic is for PX4 ULog files, not `import {args.format}`; leave it "
                         "out")
    if args.batch and args.format != "dataflash":
        raise InputError(f"--batch is for DataFlash logs, not `import {args.format}`; leave it "
                         "out")
    streams, units = _pairs(args.stream, "--stream"), _pairs(args.unit, "--unit")
    delimiter = DELIMITER_NAMES.get(args.delimiter, args.delimiter)
    if delimiter is not None and len(delimiter) != 1:
        raise InputError(f"--delimiter {args.delimiter!r} is not one character; give e.g. "
                         "--delimiter ';' or --delimiter tab")
    if args.skip_rows is not None and args.skip_rows < 0:
        raise InputError(f"--skip-rows {args.skip_rows} is negative; give the number of lines "
                         "to skip")
    if args.format == "text":
        for path in streams.values():
            existing_file(path, "a text recording (--stream NAME=FILE)")
        columns = {name: _numbers(cols, f"--columns {name}={cols}")
                   for name, cols in _pairs(args.columns, "--columns").items()}
        return recordings.import_text(args.out, streams, units, unit_serial=args.unit_serial,
                                     fs=args.fs, time_unit=args.time_unit, delimiter=delimiter,
                                     skip_rows=args.skip_rows or 0, columns=columns,
                                     untimed=args.no_time)
    if args.source is None:
        raise InputError(f"`import {args.format}` needs the source file")
    if args.format == "csv":
        source = existing_file(args.source, "a CSV recording")
        columns = {name: [c.strip() for c in what.split(",")] for name, what in streams.items()}
        return recordings.import_csv(args.out, source, columns, units, time_column=args.time,
                                    index_column=args.index, fs=args.fs,
                                    unit_serial=args.unit_serial, time_unit=args.time_unit,
                                    delimiter=delimiter, skip_rows=args.skip_rows,
                                    progress=advance)
    if args.format in ("ulog", "dataflash"):
        return _flight_log(args, existing_file)
    if args.format == "npz":
        return recordings.import_npz(args.out, existing_file(args.source, "an .npz recording"),
                                    unit_serial=args.unit_serial)
    if args.profile is None:
        raise InputError("`import binary` needs the device profile of the frames; give "
                         "--profile NAME_OR_PATH (e.g. --profile mimu4444)")
    return recordings.import_binary(args.out, existing_file(args.source, "a binary dump"),
                                   args.profile, unit_serial=args.unit_serial)


def _flight_log(args, existing_file) -> Path:
    """A PX4 ULog or ArduPilot DataFlash log's IMU (station/imports/ulog.py,
    dataflash.py)."""
    from station.errors import InputError

    given = [option for option, value in (
        ("--stream", args.stream), ("--unit", args.unit), ("--columns", args.columns),
        ("--time", args.time), ("--time-unit", args.time_unit), ("--index", args.index),
        ("--fs", args.fs), ("--profile", args.profile)) if value]
    if given:
        raise InputError(f"`import {args.format}` takes the IMU's streams, units and time stamps "
                         f"from the log; leave out {', '.join(given)} (--instance N chooses the "
                         "IMU, --topic the ULog topic)")
    if args.instance is not None and args.instance < 0:
        raise InputError(f"--instance {args.instance} is negative; give the instance number "
                         "(0 is the first)")
    if args.format == "ulog":
        from station.imports.ulog import import_ulog

        return import_ulog(args.out, existing_file(args.source, "a ULog file (.ulg)"),
                           instance=args.instance, topic=args.topic,
                           unit_serial=args.unit_serial)
    from station.imports.dataflash import import_dataflash

    return import_dataflash(args.out, existing_file(args.source, "a DataFlash log (.bin)"),
                            instance=args.instance, batch=args.batch,
                            unit_serial=args.unit_serial)


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


def _numbers(text: str, what: str) -> list:
    """0-based indices from 1-based numbers and ranges, e.g. "1-3" or "2,3,4"."""
    from station.errors import CalibrationInputError

    indices = []
    try:
        for part in text.split(","):
            first, _, last = part.partition("-")
            indices += range(int(first) - 1, int(last or first))
    except ValueError:
        indices = []
    if not indices or min(indices) < 0:
        raise CalibrationInputError(f"{what}: not column numbers.",
                                    "Count the columns from 1, e.g. acc=1-3 or acc=2,3,4.")
    return indices
