"""`station export`: a calibration file -> a C header for firmware (`station.files.export_c`).

The header holds the least-squares fusion matrix (a a^T)^-1 a, the biases and the counts per SI
unit as `static const float` (or double) arrays with their units in comments, so that the firmware
computes v = FUSION (counts / COUNTS_PER_UNIT - BIAS).
"""

import json
from pathlib import Path


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.description = __doc__
    p.epilog = (
        "examples:\n  station export SN42.cal.json --c-header imu_cal.h\n"
        "  station export SN42.cal.json --c-header imu_cal.h --type double "
        "--prefix GYRO_CAL --unit-serial SN42 --json"
    )
    p.add_argument("calibration", type=Path, help="calibration file (from `station solve`)")
    p.add_argument("--c-header", type=Path, required=True, metavar="OUT.h",
                   help="C header file to write")
    p.add_argument("--type", choices=("float", "double"), default="float",
                   help="C type of the arrays (default float)")
    p.add_argument("--prefix", default="IMU_CAL",
                   help="prefix of the macro and array names (default IMU_CAL)")
    p.add_argument("--unit-serial", help="refuse the calibration unless it is for this unit")
    p.add_argument("--force", action="store_true", help="overwrite an existing header")
    p.add_argument("--json", action="store_true", help="machine-readable summary")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.commands import existing_file, new_file
    from station.files.calfile import load
    from station.files.export_c import c_header

    out = new_file(args.c_header, "--c-header name", args.force)
    cal = load(existing_file(args.calibration, "a calibration file (.cal.json)"),
               unit_serial=args.unit_serial)
    out.write_text(c_header(cal, args.prefix, args.type))
    summary = {"header": str(out), "unit_serial": cal.unit_serial, "d": cal.d, "m": cal.m,
               "type": args.type, "prefix": args.prefix, "units": cal.units[0]}
    print(json.dumps(summary, indent=2) if args.json else
          f"wrote {out}: {args.prefix}_FUSION[{cal.d}][{cal.m}] and {args.prefix}_BIAS "
          f"({args.type}, {cal.units[0]}) for unit {cal.unit_serial}")
    return 0
