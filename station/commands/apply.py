"""`station apply`: readings -> calibrated vectors, by least-squares fusion of the m sensors.

For each instant, v = (a a^T)^-1 a (z - b) (docs/conventions.md) with a and b from the calibration
file. DATA is either
- a session file (.h5): the stream's raw counts, converted with the stream's own counts per SI unit;
  the session's unit serial, sensors and units must be the calibration's; time = sampling instants;
- a CSV file: a header row naming the columns, then numbers. One column per calibrated sensor
  (any order), named by its id, optionally with its unit: `g1` or `g1 [rad/s]` (`[counts]` with
  --counts); an optional `time` column is copied through. SI readings unless --counts, which
  divides by the calibration's counts per unit.

The output (CSV, or HDF5 when OUT ends in .h5) has columns time [s] and v_x, v_y (, v_z) in the
readings' unit (a calibration whose stimulus magnitude was unknown, e.g. a magnetometer solved
without --magnitude: in units of the local magnitude, `[local magnitude]`), in the calibration's
frame. `--sigma` adds the 1-sigma of each component that the
calibration's own uncertainty leaves (its covariance, calibration file version 2; the readings'
noise is not included): columns sigma_v_x, ... (HDF5: dataset `v_sigma`).

A calibration with a temperature model (calibration file version 6, docs/conventions.md) is
applied at the unit's temperature of each sample: from a column (`--temperature-column NAME`, in
K: a CSV column `NAME` or `NAME [K]`, or a channel of the session's stream; by default the CSV's
one column `[K]` or the stream's one channel in K, if it has one) or one fixed `--temperature
KELVIN`. A temperature outside the calibrated range is refused, naming the range, unless
`--extrapolate` (then a warning on stderr and `extrapolated` in the --json summary); HDF5 output
keeps the temperatures used (dataset `temperature`, K). The
temperature options are refused with a calibration that has no temperature model. `--sigma` with
a model includes its coefficients' uncertainty (taken independent of the reference calibration's:
the file holds no cross terms).
"""

import csv
import io
import json
import os
import re
import sys
from pathlib import Path

import numpy as np

from station.commands import existing_file, existing_session, new_file, no_check_argument
from station.errors import InputError
from station.model.temperature import check_kelvin

AXES = ("v_x", "v_y", "v_z")
HDF5_SUFFIXES = (".h5", ".hdf5")
_HEADER = re.compile(r"\s*([^\[\]]+?)\s*(?:\[\s*([^\[\]]+?)\s*\])?\s*\Z")


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.description = __doc__
    p.epilog = (
        "examples:\n  station apply SN42.cal.json sessions/SN42.h5 --out rates.csv\n"
        "  station apply SN42.cal.json readings.csv > rates.csv\n"
        "  station apply SN42.cal.json counts.csv --counts --out rates.h5 --json\n"
        "  station apply SN42.cal.json readings.csv --temperature-column temp --out acc.csv\n"
        "  station apply SN42.cal.json sessions/SN42.h5 --temperature 318.15 --out acc.csv\n"
        "  station apply SN42.cal.json readings.csv --temperature 360 --extrapolate > acc.csv"
    )
    p.add_argument("calibration", type=Path, help="calibration file (from `station solve`)")
    p.add_argument("data", type=Path, help="readings: a session file (.h5) or a CSV file")
    p.add_argument("--out", type=Path, help="output .csv or .h5 (default: CSV on stdout)")
    p.add_argument("--stream", help="stream of a session file (default: the stream the "
                                    "calibration was solved from, else imu)")
    p.add_argument("--counts", action="store_true",
                   help="CSV readings are raw counts (divided by the calibration's counts per "
                        "unit)")
    p.add_argument("--sigma", action="store_true",
                   help="add the 1-sigma of each component from the calibration's uncertainty")
    p.add_argument("--temperature", type=float, metavar="KELVIN",
                   help="the unit's temperature (K) for every sample (a calibration with a "
                        "temperature model)")
    p.add_argument("--temperature-column", metavar="NAME",
                   help="the column (CSV) or stream channel (session) holding the unit's "
                        "temperature in K (default: the one column or channel in K)")
    p.add_argument("--extrapolate", action="store_true",
                   help="apply the temperature model outside its calibrated range (warns)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    no_check_argument(p)
    p.add_argument("--json", action="store_true", help="print a machine-readable summary")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.calfiles.calfile import load

    if args.json and args.out is None:
        raise InputError("--json prints a summary; give --out for the vectors")
    if args.out is not None:
        new_file(args.out, force=args.force)
    cal = load(existing_file(args.calibration, "a calibration file (.cal.json)"))
    check_temperature_options(args, cal)
    data = existing_file(args.data, "readings (CSV or a session .h5)")
    if data.suffix.lower() in HDF5_SUFFIXES:
        existing_session(data, check=not args.no_check)
        time, z, temp = read_session(data, args.stream or solved_stream(cal), cal,
                                     args.temperature_column)
    else:
        time, z, temp = read_csv(data, cal, args.counts, args.temperature_column)
    extrapolated = 0
    if cal.temperature is not None:
        temp = np.full(len(z), args.temperature) if args.temperature is not None else temp
        if temp is None:
            raise InputError(f"{args.calibration} holds a temperature model and {data} has no "
                             "channel in K; give the unit's temperature: --temperature-column "
                             "NAME or --temperature KELVIN")
        extrapolated = check_range(cal.temperature, temp, args.extrapolate, data)
    with np.errstate(over="ignore", invalid="ignore"):
        # rows of the files = instants = columns of the model
        v = (cal.apply(z.T) if cal.temperature is None else cal.apply_at(z.T, temp)).T
    if not np.all(np.isfinite(v)):
        from station.calfiles.calfile import CalibrationFileError

        row = int(np.flatnonzero(~np.all(np.isfinite(v), axis=1))[0])
        raise CalibrationFileError(f"{data}: the readings of row {row + 1} overflow when "
                                   f"calibrated ({z[row].tolist()}); they are not {cal.units[0]} "
                                   "a sensor can read: check their unit")
    sigma = None
    if args.sigma:
        sigma = np.sqrt(np.diagonal(cal.vector_covariance(z.T, temp), axis1=1, axis2=2)) \
            if len(z) else np.zeros_like(v)
    if args.out is None:
        sys.stdout.write(csv_text(time, v, cal.vector_unit, sigma))
    elif args.out.suffix.lower() in HDF5_SUFFIXES:
        write_hdf5(args.out, time, v, cal, args.data, sigma,
                   temp if cal.temperature is not None else None)
    else:
        args.out.write_text(csv_text(time, v, cal.vector_unit, sigma))
    if args.json:
        norm = np.linalg.norm(v, axis=1)
        print(json.dumps({"out": str(args.out), "rows": len(v), "d": v.shape[1],
                          "units": cal.vector_unit, "frame": cal.frame,
                          "unit_serial": cal.unit_serial,
                          "norm_mean": float(norm.mean()) if len(v) else None,
                          "temperature_model": cal.temperature is not None,
                          "extrapolated": extrapolated}, indent=2,
                         allow_nan=False))
    return 0


def check_temperature_options(args, cal) -> None:
    """Refuse temperature options a calibration without a temperature model cannot use, both
    sources at once, and a fixed temperature that is not kelvin."""
    given = [f"--{k.replace('_', '-')}" for k in ("temperature", "temperature_column",
                                                  "extrapolate")
             if getattr(args, k) not in (None, False)]
    if cal.temperature is None:
        if given:
            raise InputError(f"{args.calibration} has no temperature model (calibrated at one "
                             f"temperature, or a file before version 6); drop {', '.join(given)}")
        return
    if args.temperature is not None and args.temperature_column is not None:
        raise InputError("give either --temperature or --temperature-column, not both")
    if args.temperature is not None:
        check_kelvin(args.temperature, "--temperature")


def check_range(model, temp, extrapolate: bool, data) -> int:
    """How many samples lie outside the model's calibrated range: refused (InputError naming the
    range) unless `extrapolate`, then warned about on stderr."""
    outside = model.outside(temp)
    count = int(outside.sum())
    if not count:
        return 0
    worst = temp[outside][np.argmax(np.abs(temp[outside] - model.t_ref))]
    where = (f"{data}: {count} of {len(temp)} samples (e.g. {worst:.2f} K) lie outside the "
             f"calibrated range {model.t_min:.2f} .. {model.t_max:.2f} K")
    if not extrapolate:
        raise InputError(f"{where}; the temperature model is not valid there: calibrate over "
                         "that range, or give --extrapolate to apply it anyway")
    print(f"warning: {where}; extrapolating the temperature model (--extrapolate)",
          file=sys.stderr)
    return count


def solved_stream(cal) -> str:
    """The stream the calibration file says it was solved from (its `session` record; a text
    from an untrusted file, checked against the session's streams when read), else "imu"."""
    stream = (cal.session or {}).get("stream")
    return stream if isinstance(stream, str) else "imu"


def read_session(path, stream: str, cal, temperature_column: str | None = None) -> tuple:
    """(time (k,), SI readings (k, m), temperatures (k,) K or None) of a session's stream,
    checked against the calibration. The temperatures: from the channel `temperature_column`, or
    (a calibration with a temperature model) the stream's one channel in K, else None."""
    from station.calfiles.calfile import CalibrationFileError
    from station.reduce.timeline import sample_times
    from station.session import Session

    with Session.open(path) as session:
        if stream not in session.specs:
            raise CalibrationFileError(f"{path} has no stream {stream!r}; choose one of "
                                       f"{sorted(session.specs)} with --stream")
        spec = session.specs[stream]
        missing = [s for s in cal.sensors if s not in spec.channels]
        if missing:
            raise CalibrationFileError(f"{path}: stream {stream!r} lacks the calibration's "
                                       f"sensors {missing}; give the session (and --stream) it "
                                       "was solved from")
        cols = [spec.channels.index(s) for s in cal.sensors]  # e.g. the accelerometers of a
        units = session.reading_units(stream)  # stream that holds gyros too
        cal.check_unit(session.unit_serial, cal.sensors,
                       [units[i] for i in cols], where=str(path))
        temp_col = _temperature_channel(spec, cal, temperature_column, path, stream)
        data = session.stream(stream)
    time = sample_times(data.seq, data.host_time, spec.rate_hz) if len(data.seq) else np.zeros(0)
    si = data.to_si()
    return time, si[:, cols], None if temp_col is None else si[:, temp_col]


def _temperature_channel(spec, cal, name, path, stream) -> int | None:
    """Index of the stream's temperature channel (`name`, or its one channel in K when the
    calibration has a temperature model), None when none is asked for and the model has a
    fixed --temperature or there is no model."""
    from station.calfiles.calfile import CalibrationFileError

    if name is not None:
        if name not in spec.channels:
            raise CalibrationFileError(f"{path}: stream {stream!r} has no channel {name!r} "
                                       f"(channels {list(spec.channels)}); name its temperature "
                                       "channel with --temperature-column")
        col = spec.channels.index(name)
        if spec.units[col] != "K":
            raise CalibrationFileError(f"{path}: channel {name!r} is in {spec.units[col]!r}, "
                                       "not K; give the unit's temperature in kelvin")
        return col
    kelvin = [i for i, u in enumerate(spec.units) if u == "K"]
    return kelvin[0] if cal.temperature is not None and len(kelvin) == 1 else None


def read_csv(path, cal, counts: bool = False, temperature_column: str | None = None) -> tuple:
    """(time (k,) or None, SI readings (k, m) in the calibration's sensor order, temperatures
    (k,) K from the column `temperature_column` or None) from a CSV file with a header row (see
    the module docstring)."""
    from station.calfiles.calfile import CalibrationFileError

    def fail(problem):
        return CalibrationFileError(f"{path}: {problem}")

    if counts and cal.counts_per_unit is None:
        raise fail("--counts needs the counts per unit, which this calibration file lacks; give "
                   "SI readings")
    with open(path, newline="", encoding="utf-8") as f:
        header = next(csv.reader(f), None)
        if header is None:
            raise fail("empty file; the first row must name the columns")
        names, units = _parse_header(header, fail)
        body = f.read()
    kelvin = [n for n, u in zip(names, units, strict=True) if u == "K"]
    if temperature_column is None and cal.temperature is not None and len(kelvin) == 1:
        temperature_column = kelvin[0]
    expected_unit = "counts" if counts else cal.units[0]
    wrong = {n: u for n, u in zip(names, units, strict=True) if u is not None and n != "time"
             and u != ("K" if n == temperature_column else expected_unit)}
    if wrong:
        raise fail(f"columns {wrong} are not in {expected_unit}; convert them (or use --counts "
                   "for raw counts)")
    if temperature_column is not None and temperature_column not in names:
        raise fail(f"no column {temperature_column!r} (--temperature-column) in {names}")
    extra = sorted(set(names) - set(cal.sensors) - {"time", temperature_column})
    missing = [s for s in cal.sensors if s not in names]
    if extra or missing:
        raise fail(f"the calibration's sensors {list(cal.sensors)} lack columns {missing}, and "
                   f"columns {extra} are unknown; name one column per sensor (plus 'time')")
    try:
        values = np.loadtxt(io.StringIO(body), delimiter=",", ndmin=2, comments=None)
    except ValueError as exc:
        raise fail(f"not a table of numbers ({exc})") from None
    if values.size == 0:
        values = np.zeros((0, len(names)))
    if values.shape[1] != len(names) or not np.all(np.isfinite(values)):
        raise fail(f"rows must hold {len(names)} finite numbers each")
    z = values[:, [names.index(s) for s in cal.sensors]]
    if counts:
        z = z / cal.counts_per_unit
    time = values[:, names.index("time")] if "time" in names else None
    temp = None if temperature_column is None else values[:, names.index(temperature_column)]
    return time, z, temp


def _parse_header(header, fail) -> tuple:
    names, units = [], []
    for cell in header:
        match = _HEADER.match(cell)
        if not match:
            raise fail(f"header cell {cell!r}: write `name` or `name [unit]`")
        names.append(match[1])
        units.append(match[2])
    if len(set(names)) != len(names):
        raise fail(f"header {names} repeats a column name")
    return names, units


def csv_text(time, v, unit: str, sigma=None) -> str:
    """CSV of the calibrated vectors (with a time column when time is given, and their 1-sigma
    columns when sigma is given)."""
    d = v.shape[1]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow((["time [s]"] if time is not None else [])
                    + [f"{axis} [{unit}]" for axis in AXES[:d]]
                    + ([f"sigma_{axis} [{unit}]" for axis in AXES[:d]]
                       if sigma is not None else []))
    rows = np.column_stack([x for x in (time, v, sigma) if x is not None])
    writer.writerows(rows.tolist())
    return out.getvalue()


def write_hdf5(path, time, v, cal, source, sigma=None, temperature=None) -> None:
    """An HDF5 file: datasets `v` (k, d), `time` (k,) (when known), `v_sigma` (k, d) (when
    given) and `temperature` (k,) K (the unit's temperature the model was applied at, when it
    was), with units and origin."""
    import h5py

    tmp = f"{path}.tmp{os.getpid()}"
    with h5py.File(tmp, "w", libver=("v110", "v110")) as f:
        f.attrs.update(format="imu-station-calibrated", format_version=1,
                       unit_serial=cal.unit_serial, frame=cal.frame, source=str(source),
                       calibration_checksum=cal.to_document()["checksum"])
        ds = f.create_dataset("v", data=v)
        ds.attrs.update(units=cal.vector_unit, columns=list(AXES[:v.shape[1]]))
        if time is not None:
            f.create_dataset("time", data=time).attrs["units"] = "s"
        if temperature is not None:
            f.create_dataset("temperature", data=temperature).attrs.update(
                units="K", meaning="the unit's temperature the temperature model was applied at")
        if sigma is not None:
            f.create_dataset("v_sigma", data=sigma).attrs.update(
                units=cal.vector_unit, columns=list(AXES[:v.shape[1]]),
                meaning="1-sigma from the calibration's uncertainty, readings' noise excluded")
    os.replace(tmp, path)
