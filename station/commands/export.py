"""`station export`: calibration files -> the formats other tools read.

--to c-header   a C header for firmware (station.exports.c): the fusion matrix, biases and
                counts per SI unit, so that v = FUSION (counts / COUNTS_PER_UNIT - BIAS); any m;
                a temperature model's reference, range and coefficients when the file has one
--to kalibr     Kalibr's imu.yaml: noise densities, random walks, update rate, and the
                scale-misalignment intrinsics (station.exports.kalibr); accelerometer + gyro
--to ardupilot  ArduPilot INS_ACCOFFS/INS_ACCSCAL/INS_GYROFFS, a Mission Planner / MAVProxy
                parameter file (station.exports.autopilot)
--to px4        PX4 CAL_ACCn_*/CAL_GYROn_*, a QGroundControl parameter file (same module)
--to ros        sensor_msgs/Imu covariances, a ROS 2 parameters YAML (station.exports.ros)
--to imucal     imucal's FerrarisCalibrationInfo JSON (station.exports.imucal);
                accelerometer + gyro

The first file is an accelerometer (m/s^2) or a gyro (rad/s) calibration; `--gyro` adds the
gyro one to an accelerometer's. Formats that cannot hold the calibration refuse it and say why
(docs/cli.md, `station export`); the autopilots' per-axis models state what they drop.
"""

import json
from pathlib import Path

FORMATS = ("c-header", "kalibr", "ardupilot", "px4", "ros", "imucal")
SUFFIXES = {"c-header": ".h", "kalibr": ".kalibr.yaml", "ardupilot": ".ardupilot.param",
            "px4": ".px4.params", "ros": ".ros.yaml", "imucal": ".imucal.json"}
OPTIONS = {"type": ("c-header",), "prefix": ("c-header",), "instance": ("ardupilot", "px4"),
           "acc_id": ("px4",), "gyro_id": ("px4",), "rostopic": ("kalibr",),
           "rate": ("kalibr", "ros")}
"""The formats each format option applies to (given to another format, it is refused)."""


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.description = __doc__
    p.epilog = (
        "examples:\n  station export SN42.cal.json --c-header imu_cal.h\n"
        "  station export SN42.cal.json --to c-header --out imu_cal.h --type double "
        "--prefix GYRO_CAL --json\n"
        "  station export ACC.cal.json --gyro GYRO.cal.json --to kalibr --out imu.yaml\n"
        "  station export ACC.cal.json --gyro GYRO.cal.json --to ardupilot --instance 1\n"
        "  station export ACC.cal.json --to px4 --acc-id 2818058\n"
        "  station export ACC.cal.json --gyro GYRO.cal.json --to ros --rate 200\n"
        "  station export ACC.cal.json --gyro GYRO.cal.json --to imucal --out cal.json"
    )
    p.add_argument("calibration", type=Path,
                   help="calibration file (from `station solve`): accelerometer or gyro")
    p.add_argument("--gyro", type=Path, metavar="GYRO.cal.json",
                   help="the gyro calibration, when the first file is the accelerometer's")
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument("--to", choices=FORMATS, help="the format to write")
    target.add_argument("--c-header", type=Path, metavar="OUT.h",
                        help="write a C header (same as --to c-header --out OUT.h)")
    p.add_argument("--out", type=Path,
                   help="file to write (default: beside the calibration, named for the format)")
    p.add_argument("--type", choices=("float", "double"),
                   help="c-header: C type of the arrays (default float)")
    p.add_argument("--prefix",
                   help="c-header: prefix of the macro and array names (default IMU_CAL)")
    p.add_argument("--instance", type=int,
                   help="ardupilot: IMU 1-3 (default 1); px4: calibration slot 0-3 (default 0)")
    p.add_argument("--acc-id", type=int, help="px4: the accelerometer's device id (CAL_ACCn_ID)")
    p.add_argument("--gyro-id", type=int, help="px4: the gyro's device id (CAL_GYROn_ID)")
    p.add_argument("--rostopic", help="kalibr: the IMU topic (default /imu0)")
    p.add_argument("--rate", type=float, metavar="HZ",
                   help="kalibr, ros: the IMU's sample rate (default: that of the noise "
                        "figures)")
    p.add_argument("--unit-serial", help="refuse the calibration unless it is for this unit")
    p.add_argument("--force", action="store_true",
                   help="overwrite an existing file; autopilots: write a per-axis model even "
                        "when it drops more than 1 %% of the reading")
    p.add_argument("--json", action="store_true", help="machine-readable summary")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.calfiles.calfile import load
    from station.commands import existing_file, new_file
    from station.errors import InputError

    fmt = "c-header" if args.c_header is not None else args.to
    if args.c_header is not None and args.out is not None:
        raise InputError("give the header's name once: --c-header OUT.h, or --to c-header "
                         "--out OUT.h")
    for option, formats in OPTIONS.items():
        if getattr(args, option) is not None and fmt not in formats:
            raise InputError(f"--{option.replace('_', '-')} applies to --to "
                             f"{' and '.join(formats)}, not to {fmt}; leave it out")
    out = args.c_header or args.out or _default_name(args.calibration, fmt)
    out = new_file(out, "--out name", args.force)
    cals = [load(existing_file(path, "a calibration file (.cal.json)"),
                 unit_serial=args.unit_serial)
            for path in (args.calibration, args.gyro) if path is not None]
    written = _write(fmt, cals, args)
    out.write_text(written.text)
    suspect = [f"{cal.units[0]} calibration marked suspect: "
               f"{'; '.join(map(str, cal.fit.get('status_reasons') or ['(no reason given)']))}"
               for cal in cals if cal.fit.get("status") == "suspect"]
    summary = {"out": str(out), "format": fmt, "unit_serial": cals[0].unit_serial,
               "calibrations": [str(p) for p in (args.calibration, args.gyro) if p],
               "notes": suspect + list(written.notes)}
    print(json.dumps(summary, indent=2) if args.json else
          "\n".join([f"wrote {out} ({fmt}) for unit {cals[0].unit_serial}",
                     *(f"  {note}" for note in summary["notes"])]))
    return 0


def export(calibration: Path, fmt: str) -> Path:
    """Export the calibration file `calibration` to `fmt` with the format's default options,
    beside it under its default name (replaced if there); the file written."""
    from types import SimpleNamespace

    from station.calfiles.calfile import load

    out = _default_name(calibration, fmt)
    defaults = SimpleNamespace(**dict.fromkeys(OPTIONS), force=False)
    out.write_text(_write(fmt, [load(calibration)], defaults).text)
    return out


def _default_name(calibration: Path, fmt: str) -> Path:
    """SN42.cal.json -> SN42.kalibr.yaml (beside it)."""
    name = calibration.name
    for ending in (".cal.json", ".json"):
        if name.endswith(ending):
            name = name[: -len(ending)]
            break
    return calibration.with_name(name + SUFFIXES[fmt])


def _write(fmt: str, cals: list, args):
    """The chosen format's text and notes (station.exports)."""
    from station.errors import InputError
    from station.exports.imu import Imu, Written

    if fmt == "c-header":
        from station.exports.c import c_header

        if len(cals) > 1:
            raise InputError("a C header holds one calibration file; export the gyro one "
                             "with its own header")
        cal, prefix, ctype = cals[0], args.prefix or "IMU_CAL", args.type or "float"
        notes = (f"{prefix}_FUSION[{cal.d}][{cal.m}] and {prefix}_BIAS "
                 f"({ctype}, {cal.units[0]})",)
        if cal.temperature is not None:
            t = cal.temperature
            notes += (f"the temperature model: {prefix}_T_REF, _T_MIN, _T_MAX "
                      f"({t.t_min:.2f} .. {t.t_max:.2f} K), bias order {t.orders['bias']}, "
                      f"scale order {t.orders['scale']} (the formula in the header's comment)",)
        return Written(c_header(cal, prefix, ctype), notes)
    imu = Imu.of(*cals)
    if fmt == "kalibr":
        from station.exports.kalibr import kalibr

        return kalibr(imu, args.rostopic or "/imu0", args.rate)
    if fmt == "ardupilot":
        from station.exports.autopilot import ardupilot

        return ardupilot(imu, 1 if args.instance is None else args.instance, args.force)
    if fmt == "px4":
        from station.exports.autopilot import px4

        return px4(imu, 0 if args.instance is None else args.instance, args.acc_id,
                   args.gyro_id, args.force)
    if fmt == "ros":
        from station.exports.ros import ros

        return ros(imu, args.rate)
    from station.exports.imucal import imucal

    return imucal(imu)
