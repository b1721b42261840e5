"""`station solve`: a recorded session -> a calibration file.

Rotary sessions: reduces the raw stream to the readings matrix M (Eq. 18 of Rupniewski: rotating
minus static mean per position, whole revolutions by the table angle), calibrates it (closed form,
then maximum likelihood, weighted by each entry's standard error) with the table rate as the
magnitude. Eq. (18) readings carry no bias, so the biases come from the static windows: b_i = mean
over positions of the static means, 1-sigma = their scatter / sqrt(n) (which also holds whatever
varies between positions, e.g. the Earth's rate).

Iron and free-static sessions: the means of the still poses (`station.reduce.still`) are
calibrated with the biases estimated (Hwangbo & Kanade's factorization with the faces' constraints,
or the ellipsoid / joint-bias closed form), then maximum likelihood; the magnitude is the recorded
local gravity, the frame the recorded nominal layout (or --nominal). Free-static sessions
calibrate the accelerometer channels only.

Imported recordings (`station import`, protocol "import"): every still pose found in the data is a
pose of the free-static path (`station.reduce.imported`); the stream calibrated is the one in m/s^2
(or --stream), the magnitude --magnitude or standard gravity (said in the output), the frame the
canonical one of Eq. (19). An imported magnetometer stream (in T, or counts:T) is solved from blocks
of its continuous rotation (docs/hand-turns.md), with --magnitude the local field in T, or without
it to the local field's unit sphere. The still-pose detector's settings (--rest, --threshold,
--still-channels, --min-still; docs/stillness.md) apply to every still-pose session; the output
lists the poses found and every candidate rejected, with the reason. --faces: the poses of an import
are the faces of a right-angle block (one mounting), solved with the right-angle constraints of
Eq. (15) (needed when they are only the six axis-aligned directions). --stream GYRO of an import
(a gyro triad in rad/s): the accelerometer calibrated first, then the gyro from the hand turns
between its still poses (gravity carried through each turn, Tedaldi et al.; docs/hand-turns.md), in
the accelerometer's frame.

A thermal campaign (its directory or `campaign.json`, `station record` with a [chamber]): one soak
per session (its gyro channels' Eq. 18 readings and static-window biases, at the mean of its
recorded temperature channel), the temperature model fitted over them with its orders chosen by
likelihood ratio (`station.solve.temperature`), written as DIR/campaign.cal.json (version 6); the
summary gives the orders and each tempco with its 1-sigma.
The calibration file (`station.calfiles.calfile`) holds the result with its uncertainties.

--repeatability COMBINED.cal.json (a file of `station combine` over earlier sessions of the unit):
each class's between-session tau (biases, scale factors, axis angles, entries of a) is added to
this session's own 1-sigma, widened for the few degrees of freedom tau rests on
(`station.calfiles.combined.with_repeatability`): every 1-sigma written is then the figure for this
session as a unit re-seated and switched on again, not only the scatter within it. Several
combined files, one per unit of the same model, pool their taus (weighted by dof): a model's tau
from a lot of units rests on many more dof than one unit's, so it is widened far less. The file
says so (`fit.repeatability_included`: each combined file's name and sha256, each tau) and so does
the output.
"""

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

NO_NOISE = "no_noise_figures"
"""The key of the calibration file's `session` record that says why `noise` is null."""


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    from station.commands import (
        channels_argument,
        db_arguments,
        faces_argument,
        no_check_argument,
        still_arguments,
    )

    p.description = __doc__
    p.epilog = (
        "examples:\n  station solve sessions/SN42.h5\n"
        "  station solve SN42.h5 --out SN42.cal.json --nominal layout.csv --json\n"
        "  station solve SN42.h5 --tolerances bench.toml   # PASS/FAIL against [tolerances]\n"
        "  station solve xsens.h5 --magnitude 9.81744 --rest 0:50 --store   # an import\n"
        "  station solve fer.h5 --magnitude 9.81 --faces   # an import on a block's faces\n"
        "  station solve xsens.h5 --stream gyro --rest 0:50   # its gyro, from the turns\n"
        "  station solve campaigns/SN42   # a thermal campaign: the temperature model\n"
        "  station combine exp_1.cal.json exp_2.cal.json --out exp_12.cal.json\n"
        "  station solve exp_3.h5 --repeatability exp_12.cal.json   # + the spread between "
        "sessions\n"
        "  station solve u1.h5 --repeatability lot/*.cal.json   # the tau of the model's units\n"
        "  station solve array.h5 --channels imu3_ax,imu3_ay,imu3_az   # one IMU of an array\n"
        "  station solve lot/*.h5   # a batch: one line per session, failures per session\n"
        "  station solve --from-list today.txt --json   # a batch from a list, JSON lines\n\n"
        "exit code 0: written (and PASS when judged); 1: the unit FAILED its tolerances or is\n"
        "MARGINAL (within 2 sigma of a limit), or the fit is suspect, or the session file could\n"
        "not be checked (--no-check skips the check); 2: bad input (a damaged file included).\n"
        "A batch: the largest of its sessions' codes (0 only when every session is written)"
    )
    p.add_argument("session", type=Path, nargs="*",
                   help="session file (.h5) recorded by `station record` or `station import`; "
                        "several: a batch, solved in one process, one line each")
    p.add_argument("--from-list", type=Path, metavar="FILE",
                   help="a batch of the session files listed in FILE, one path a line (relative "
                        "to FILE's folder; blank lines and lines starting with # skipped), after "
                        "any given as arguments")
    p.add_argument("--out", type=Path,
                   help="calibration file to write (default: SESSION with suffix .cal.json); not "
                        "in a batch, whose files are written beside their sessions")
    p.add_argument("--stream", help="sample stream to calibrate (default imu; an import: its one "
                                    "stream in m/s^2; an import's gyro stream: from the turns "
                                    "between the still poses)")
    p.add_argument("--accelerometer", metavar="NAME",
                   help="with --stream GYRO: the accelerometer stream whose still poses carry "
                        "the gyro (default: the session's one stream in m/s^2; several: the "
                        "error names them)")
    p.add_argument("--nominal", type=Path,
                   help="CSV of the nominal layout (d rows x m columns): report a aligned to it "
                        "(physical frame) instead of the canonical frame of Eq. (19)")
    p.add_argument("--magnitude", type=float,
                   help="stimulus magnitude |v| (default: the session's table rate in rad/s, or "
                        "its local gravity in m/s^2; an import: standard gravity 9.80665; an "
                        "imported magnetometer: unknown, the local field's unit sphere)")
    still_arguments(p)
    faces_argument(p)
    channels_argument(p)
    p.add_argument("--store", action="store_true",
                   help="also store the result in the session as results/solve-<k>, with its "
                        "settings (`station report` then shows it and its poses)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    p.add_argument("--accept-suspect", action="store_true",
                   help="write a fit that fails the quality gate (chi2, outliers), marked "
                        "suspect with the reasons, instead of refusing it")
    p.add_argument("--tolerances", type=Path, metavar="FILE.toml",
                   help="judge the unit against the [tolerances] table of this TOML file (e.g. the "
                        "bench profile); default: the recorded bench profile's, if any")
    p.add_argument("--repeatability", type=Path, nargs="+", metavar="COMBINED.cal.json",
                   help="a combined calibration file of earlier sessions of the unit (`station "
                        "combine`): its between-session spread tau is added to every 1-sigma; "
                        "several (one per unit of the same model): their taus pooled")
    p.add_argument("--repeatability-from-db", metavar="QUERY",
                   help="instead of --repeatability files: the combined calibrations of the "
                        "record store (--db) that the query picks, e.g. \"model=imu12-serial "
                        "since=2026-11-01\" (docs/records.md)")
    no_check_argument(p)
    db_arguments(p)
    p.add_argument("--json", action="store_true", help="machine-readable summary")
    p.set_defaults(run=run)


def run(args) -> int:
    paths = session_paths(args.session, args.from_list)
    if len(paths) == 1 and args.from_list is None:
        args.session = paths[0]
        return _run_one(args)
    return run_batch(args, paths)


def session_paths(given: list, listed) -> list:
    """The sessions of the command line, then those of the --from-list file (`read_list`); at
    least one."""
    from station.errors import InputError

    paths = list(given) + ([] if listed is None else read_list(listed))
    if not paths:
        raise InputError("no session given: name one or more session files, or --from-list FILE "
                         "(one path a line)")
    return paths


def read_list(path) -> list:
    """The session paths listed in `path`: one a line, relative to its folder; blank lines and
    lines starting with # skipped."""
    from station.commands import existing_file

    path = existing_file(path, "a list of session files, one path a line")
    lines = (line.strip() for line in path.read_text(errors="replace").splitlines())
    return [path.parent / line for line in lines if line and not line.startswith("#")]


def run_batch(args, paths: list) -> int:
    """`station solve` of many sessions in one process: the options of the command line for each,
    every calibration file beside its session, one line per session as it is done (--json: one
    JSON object a line) with what failed for a session that failed; the structure checks of all
    the files in one child process (`station.session.check.survey_all`). The records of the
    files written are kept per folder at the end. Exit code: the largest of the sessions'."""
    from itertools import groupby

    from station.commands import keep_records
    from station.errors import InputError, StationError
    from station.session.campaign import is_campaign
    from station.session.check import survey_all

    if args.out is not None:
        raise InputError("--out names one calibration file; a batch writes each beside its "
                         "session (SESSION.cal.json): leave out --out")
    if not args.no_check:
        survey_all(paths)
    codes, written = [], []
    for path in paths:
        one = argparse.Namespace(**{**vars(args), "session": path})
        try:
            if is_campaign(path):
                raise InputError(f"{path} is a thermal campaign: solve it on its own "
                                 "(`station solve CAMPAIGN`), not in a batch")
            summaries, code = _solved(one)
        except (StationError, FileExistsError) as err:
            code = getattr(err, "exit_code", 2)
            words = " ".join(str(err).split())
            print(json.dumps({"session": str(path), "exit": code, "error": words}) if args.json
                  else f"{path}: failed (exit {code}): {words}", flush=True)
        else:
            written += [Path(s["calibration"]) for s in summaries]
            print(json.dumps({"session": str(path), "exit": code, "calibrations": summaries})
                  if args.json else f"{path}: " + "; ".join(map(batch_words, summaries)),
                  flush=True)
        codes.append(code)
    for _, files in groupby(sorted(written, key=lambda f: f.resolve().parent),
                            key=lambda f: f.resolve().parent):
        codes.append(keep_records(args, list(files)))
    return max(codes)


def batch_words(s: dict) -> str:
    """A calibration of a batch in a few words: file, sensors, positions, fit, gate, verdict."""
    verdict = s["verdict"]
    unit = f"unit {s['unit_serial']} (stream {s['stream']}): " if "stream" in s else ""
    return (f"{unit}written to {s['calibration']}: {len(s['sensors'])} sensors, "
            f"{s['positions']} positions, chi2/dof {s['chi2_per_dof']:.2f}"
            + (", SUSPECT" if s["status"] == "suspect" else "")
            + (f", verdict {verdict['overall']}" if verdict else ""))


def _run_one(args) -> int:
    """`station solve SESSION`: one session file or thermal campaign, its full summary."""
    from station.commands import keep_records
    from station.session.campaign import is_campaign

    if is_campaign(args.session):
        return _run_campaign(args)
    summaries, code = _solved(args)
    if "stream" in summaries[0]:
        print(json.dumps({"units": summaries}, indent=2) if args.json
              else "\n".join(unit_line(s) for s in summaries))
    else:
        print(json.dumps(summaries[0], indent=2) if args.json else _text(summaries[0]))
    return max(code, keep_records(args, [s["calibration"] for s in summaries]))


def _solved(args) -> tuple:
    """(summaries, exit code) of solving the session file `args.session` with the command line's
    options and writing its calibration file(s): one summary, or one per unit of a session with
    several (each with its `stream`); nothing printed, nothing recorded."""
    from station.commands import (
        existing_file,
        existing_session,
        new_file,
        queried_files,
        still_values,
    )
    from station.errors import InputError

    existing_session(args.session, check=not args.no_check)
    units = [] if args.stream is not None else session_units(args.session)
    outs = unit_files(args.out or args.session, units, args.force) if units else \
        [new_file(args.out or args.session.with_suffix(".cal.json"), force=args.force)]
    nominal = None if args.nominal is None else read_nominal(args.nominal)
    tolerances = None if args.tolerances is None else read_tolerances(
        existing_file(args.tolerances, "a TOML file with a [tolerances] table"))
    if args.repeatability and args.repeatability_from_db:
        raise InputError("give --repeatability files or --repeatability-from-db QUERY, not both")
    if args.repeatability_from_db:
        args.repeatability = queried_files(args.db, args.repeatability_from_db, "combined")
    repeatability = None if args.repeatability is None else [existing_file(
        path, "a combined calibration file (`station combine`)") for path in args.repeatability]
    options = {"nominal": nominal, "magnitude": args.magnitude,
               "accept_suspect": args.accept_suspect, "tolerances": tolerances,
               "still": still_values(args), "store": args.store, "faces": bool(args.faces),
               "repeatability": repeatability, "channels": args.channels,
               "accelerometer": args.accelerometer}
    if units:
        summaries = solve_units(args.session, units, outs, args.force, **options)
        return summaries, units_exit(summaries)
    cal = solve_session(args.session, args.stream, **options)
    cal.save(outs[0], overwrite=args.force)
    return [summarise(cal, outs[0])], verdict_exit(cal.verdict)


def session_units(path) -> list:
    """The units of a session recorded with several on one table
    (`station.session.units.SessionUnit`), [] for a one-unit session."""
    from station.session import Session
    from station.session.units import recorded_units

    with Session.open(path) as session:
        return recorded_units(session.metadata, session.specs, path)


def unit_files(base, units: list, force: bool | None = False) -> list:
    """The calibration file of each unit: BASE.<unit serial>.cal.json, BASE the session (or --out)
    without its .h5 or .cal.json suffix; refused (before anything is solved) where one exists."""
    from station.commands import new_file

    base = Path(base)
    name = base.name.removesuffix(".cal.json").removesuffix(".h5")
    return [new_file(base.with_name(f"{name}.{u.unit_serial}.cal.json"), force=force)
            for u in units]


def solve_units(path, units: list, outs: list, force: bool = False, **options) -> list:
    """Solve every unit's stream of a session with several units on one table (`solve_session`
    each, the same options) and write its calibration file `outs[k]`; the summaries, each with
    its `stream`. A unit whose fit is suspect gets no file; once every unit is done,
    SuspectFitError names those units (the others' files are written)."""
    from station.errors import SuspectFitError

    summaries, suspect = [], []
    for unit, out in zip(units, outs, strict=True):
        try:
            cal = solve_session(path, unit.stream, **options)
        except SuspectFitError as exc:
            suspect.append(f"unit {unit.unit_serial} (stream {unit.stream}): {exc}")
            continue
        cal.save(out, overwrite=force)
        summaries.append({"stream": unit.stream, **summarise(cal, out)})
    if suspect:
        written = ", ".join(s["calibration"] for s in summaries) or "none"
        raise SuspectFitError(f"{len(suspect)} of {len(units)} units have suspect fits and no "
                              f"calibration file (written: {written}): " + "; ".join(suspect))
    return summaries


def unit_line(s: dict) -> str:
    """One line on one unit of a session with several (`solve_units`' summary): serial, stream,
    fit, quality gate, verdict, file."""
    from station.solve.verdict import words

    gate_words = ("SUSPECT: " + "; ".join(s["status_reasons"]) if s["status"] == "suspect"
                  else "quality gate passed")
    verdict = s["verdict"]
    judged = f", verdict {verdict['overall']}" if verdict else ""
    failed = f"\n{words(verdict)}" if verdict and verdict["overall"] != "PASS" else ""
    return (f"unit {s['unit_serial']} (stream {s['stream']}): {len(s['sensors'])} sensors, "
            f"{s['positions']} positions, chi2/dof {s['chi2_per_dof']:.2f}, {gate_words}"
            f"{judged}; written to {s['calibration']}{failed}")


def units_exit(summaries: list) -> int:
    """The worst `verdict_exit` of the units' summaries."""
    return max(verdict_exit(s["verdict"]) for s in summaries)


def verdict_exit(verdict: dict | None) -> int:
    """0 without a verdict or for PASS; 1 for FAIL or MARGINAL."""
    return 0 if verdict is None or verdict["overall"] == "PASS" else 1


def solve_session(path, stream: str | None = None, nominal=None, magnitude: float | None = None,
                  accept_suspect: bool = False, tolerances=None, still: dict | None = None,
                  store: bool = False, faces: bool = False, repeatability=None,
                  channels: tuple | None = None, accelerometer: str | None = None):
    """The `station.calfiles.calfile.Calibration` of a recorded session file, through the station's
    one reduce-and-solve path (`station.replay.solve_recorded`); the kind's entry in
    `station.protocols.KINDS` says which channels it calibrates and where the biases come from.

    The fit passes the quality gate (`station.solve.quality.check_fit`) or SuspectFitError says
    why not; with `accept_suspect` it is returned marked suspect (fit status and reasons). The
    verdict (`station.solve.verdict`) judges the unit against `tolerances`, default the
    `[tolerances]` of the bench profile the session was recorded with; none: no verdict.
    still: the still-pose detector's settings (`station.commands.still_values`); store: the
    result is also stored in the session as results/solve-<k> with its settings; faces: an
    import's still poses are faces of a right-angle block (`station.replay.ReplaySettings`);
    repeatability: the paths of combined calibration files (`station combine`; one per unit of
    the model: pooled) whose between-session taus are added to every 1-sigma
    (`station.calfiles.combined.with_repeatability`,
    before the verdict, which then judges the unit with them); channels: names of the
    calibrated channels to calibrate (`station.replay.channel_rows`; None: all); accelerometer:
    the stream whose poses carry a gyro stream (`station.replay.solve_carried`)."""
    from station.calfiles.calfile import Calibration
    from station.protocols import lookup
    from station.replay import (
        ReplaySettings,
        calibrated_stream,
        carried,
        recorded_layout,
        recorded_noise,
        solve_recorded,
        solved_channels,
        stimulus,
    )
    from station.session import Session
    from station.session.units import unit_serial
    from station.solve.quality import check_fit
    from station.solve.verdict import recorded_tolerances, verdict

    with Session.open(path) as session:
        settings = ReplaySettings(stream=stream, magnitude=magnitude, faces=faces,
                                  channels=channels, accelerometer=accelerometer,
                                  **(still or {}))
        stream = calibrated_stream(session, settings)
        settings = dataclasses.replace(settings, stream=stream)
        kind = lookup(session.protocol, "reduce", f"{path} records a {session.protocol!r} "
                      "session", "station solve")
        spec = session.specs[stream]
        channels = solved_channels(session, settings)
        names = [spec.channels[i] for i in channels]
        units = [session.reading_units(stream)[i] for i in channels]
        info = {"path": str(Path(path).resolve()), "stream": stream,
                "protocol": session.protocol, "created": session.created,
                "software_version": session.software_version,
                "stimulus": stimulus(session, settings)[1]}
        file = {"unit_serial": unit_serial(session.metadata, session.specs, stream, path)
                               or session.unit_serial,
                "counts_per_unit": np.asarray(spec.counts_per_unit)[channels], "units": units,
                "stimulus": None if units == [spec.units[i] for i in channels] else
                spec.units[channels[0]]}
        tolerances = tolerances or recorded_tolerances(session.metadata, path)
        layout = nominal if nominal is not None else recorded_layout(session, settings, False)
        solved = None
        if accelerometer is not None and not carried(session, stream):
            from station.errors import InputError

            raise InputError(f"--accelerometer names the stream that carries a gyro stream "
                             f"through its turns; {stream!r} is not such a gyro stream (give "
                             "--stream GYRO, or leave out --accelerometer)")
        if carried(session, stream):
            cal = carried_calibration(session, settings, nominal, names, info, file, store,
                                      accept_suspect)
        else:
            readings, result = solve_recorded(session, settings, nominal, command="station solve")
            bias = kind.entry("bias")(readings) if kind.has("bias") else {
                "bias_source": f"estimated with the calibration ({session.protocol} protocol's "
                               "still poses)"}
            check = gate(check_fit(result, names, pose_term=kind.still), path, accept_suspect)
            cal = Calibration.from_result(
                result, file["unit_serial"], names, units, stimulus=file["stimulus"],
                counts_per_unit=file["counts_per_unit"], session={**info, **poses(readings)},
                status=check.status, status_reasons=check.problems, **bias)
            solved = readings, result
        noise, why = recorded_noise(session, stream, channels)
        cal = cal.with_noise(noise)
        if why is not None:  # the file and the summary say why it has no noise figures
            cal = dataclasses.replace(cal, session={**(cal.session or {}), NO_NOISE: why})
    if store and solved is not None:  # the session closed: it is written now
        _store(path, *solved, settings, channels)
    if repeatability is not None:
        from station.calfiles.combined import with_repeatability_files

        cal = with_repeatability_files(cal, repeatability)
    if tolerances is None or tolerances.empty:
        return cal
    return dataclasses.replace(cal, verdict=verdict(cal, tolerances, names, layout))


def gate(check, path, accept_suspect: bool):
    """The quality gate's `check` (`station.solve.quality.check_fit`), or SuspectFitError saying
    why the fit is suspect unless `accept_suspect`."""
    from station.errors import SuspectFitError

    if check.problems and not accept_suspect:
        raise SuspectFitError(
            f"{path}: the fit is suspect, so no calibration file was written: "
            f"{'; '.join(check.problems)}. `station report` shows the positions, `station "
            "diagnose` the effect; record those positions again, or give --accept-suspect to "
            "write the file marked suspect")
    return check


def carried_calibration(session, settings, nominal, names, info: dict, file: dict, store: bool,
                        accept_suspect: bool):
    """The calibration file content of an import's gyro triad (`station.replay.solve_carried`):
    the accelerometer calibrated first on its still poses (its fit through the quality gate), then
    the gyro by carrying gravity through the turns between them, in the accelerometer's frame
    (said in `session.frame`). info, file: the session record and the unit's serial, counts
    per unit and readings' units."""
    from station.calfiles.calfile import Calibration
    from station.errors import InputError
    from station.protocols import KINDS
    from station.replay import solve_carried
    from station.solve.quality import check_fit

    if store:
        raise InputError(f"--store keeps a still-pose result for `station report`, but stream "
                         f"{settings.stream!r} is a gyro calibrated from the turns (its "
                         "calibration file only): leave out --store (`station solve SESSION "
                         "--store` stores the accelerometer's)")
    acc_stream, readings, acc, carry = solve_carried(session, settings, nominal)
    acc_channels = KINDS[session.protocol].entry("channels")(session, acc_stream)
    acc_names = [session.specs[acc_stream].channels[i] for i in acc_channels]
    check = gate(check_fit(acc, acc_names, pose_term=True), session.path, accept_suspect)
    record = {**info, **poses(readings),
              "frame": f"the accelerometer's: the {acc.frame} frame of stream {acc_stream!r} "
                       "calibrated with it",
              "accelerometer": {"stream": acc_stream, "sensors": acc_names,
                                "scale_factors": acc.scale_factors.tolist(),
                                "bias": acc.bias.tolist(), "chi2_per_dof": acc.chi2 / acc.dof}}
    return Calibration.from_carry(
        carry, file["unit_serial"], names, frame=acc.frame, magnitude=acc.magnitude,
        counts_per_unit=file["counts_per_unit"], session=record, status=check.status,
        status_reasons=[f"accelerometer: {p}" for p in check.problems], units=file["units"][0])


def poses(readings) -> dict:
    """{"poses": found, "rejected": [[start s, end s, reason], ...]} of readings that kept their
    still-pose detection; {} for others. Times from the recording's first sample."""
    still = getattr(readings, "detection", None)
    if still is None:
        return {}
    t = readings.times - readings.times[0]
    return {"poses": len(still.intervals),
            "rejected": [[round(float(t[a]), 2), round(float(t[b - 1]), 2), why]
                         for a, b, why in still.rejected]}


def _store(path, readings, result, settings, channels) -> None:
    """The result stored in the session as results/solve-<k>, with the settings that made it and
    the stream's channels it calibrates."""
    from station.replay import free_name
    from station.session import write_results

    write_results(path, free_name(path, "solve"), settings.stream, readings.M, result,
                  readings.sigma, settings=dataclasses.asdict(settings),
                  channels=[int(i) for i in channels])


def read_tolerances(path):
    """The `[tolerances]` table of a TOML file (a bench profile, or a file of its own)."""
    from drivers.profile import ProfileError, load_profile
    from station.errors import InputError
    from station.solve.verdict import Tolerances

    try:  # sizes and nesting bounded as for every profile
        table = load_profile(Path(path)).tables
    except ProfileError as exc:
        raise InputError(f"cannot read tolerances from {path} ({exc}); give a TOML file with a "
                         "[tolerances] table") from None
    if "tolerances" not in table:
        raise InputError(f"{path} has no [tolerances] table (scale_factor, bias, "
                         "axis_angle_deg)")
    return Tolerances.from_table(table["tolerances"], f"{path}: [tolerances]")


def read_nominal(path) -> np.ndarray:
    """A nominal layout (d x m) from a CSV file of numbers."""
    from station.errors import CalibrationInputError

    try:
        a = np.loadtxt(path, delimiter=",", ndmin=2)
    except (OSError, ValueError) as exc:
        raise CalibrationInputError(f"cannot read the nominal layout {path} ({exc}).",
                                    "Give a CSV file of d rows and m columns of numbers.") from None
    if not (np.all(np.isfinite(a)) and a.shape[0] in (2, 3)):
        raise CalibrationInputError(f"nominal layout {path} has shape {a.shape}.",
                                    "Give d = 3 (or 2) rows, one column per sensor.")
    return a


def summarise(cal, out) -> dict:
    """What the command reports about a calibration file."""
    from station.calfiles.combined import INCLUDED

    return {
        "calibration": str(out), "unit_serial": cal.unit_serial, "sensors": list(cal.sensors),
        "units": cal.units[0], "frame": cal.frame, "method": cal.fit["method"],
        "positions": cal.fit["positions"], "chi2_per_dof": cal.fit["chi2"] / cal.fit["dof"],
        "status": cal.fit.get("status"), "status_reasons": cal.fit.get("status_reasons", []),
        "verdict": cal.verdict,
        "scale_factors": cal.scale_factors.tolist(),
        "scale_factors_sigma": cal.scale_factors_sigma.tolist(),
        "bias": cal.bias.tolist(), "bias_sigma": cal.bias_sigma.tolist(),
        "magnitude": cal.magnitude,
        **{key: (cal.session or {}).get(key) for key in ("stimulus", "poses", "rejected")
           if key in (cal.session or {})},
        **({"carry": cal.fit["carry"], "frame_words": cal.session["frame"]}
           if "carry" in cal.fit else {}),
        # the sigmas above are the total figure; the white-noise figure and the per-pose term
        "start": cal.fit.get("start"), "pose_sigma": cal.pose_sigma,
        "scale_factors_sigma_white": None if cal.white is None
        else cal.white["scale_factors_sigma"].tolist(),
        "bias_sigma_white": None if cal.white is None else cal.white["bias_sigma"].tolist(),
        "noise": None if cal.noise is None else cal.noise.to_document(cal.units[0]),
        NO_NOISE: None if cal.noise is not None else (cal.session or {}).get(NO_NOISE),
        "repeatability": cal.fit.get(INCLUDED),
        "weakly_determined": cal.fit.get("weakly_determined", []),
    }


def _text(s: dict) -> str:
    white = s["scale_factors_sigma_white"] is not None and s["bias_sigma_white"] is not None
    head = ("sensor", "scale factor", "1 sigma", "(white)", "bias", "1 sigma", "(white)")
    width = (8, 14, 10, 9, 12, 10, 9)
    kind = ("", ".6f", ".2g", ".2g", ".6g", ".2g", ".2g")
    keep = [i for i in range(len(head)) if white or head[i] != "(white)"]  # none: no columns
    blank = [None] * len(s["sensors"])
    table = zip(s["sensors"], s["scale_factors"], s["scale_factors_sigma"],
                s["scale_factors_sigma_white"] or blank, s["bias"], s["bias_sigma"],
                s["bias_sigma_white"] or blank, strict=True)
    rows = [" ".join(f"{head[i]:>{width[i]}}" for i in keep)]
    rows += [" ".join(f"{row[i]:>{width[i]}{kind[i]}}" for i in keep) for row in table]
    start = "" if s["start"] in (None, "closed form") else f" from the {s['start']} start"
    title = (f"unit {s['unit_serial']}: {s['positions']} positions, {s['method']}{start}, "
             f"{s['frame']} frame, chi2/dof {s['chi2_per_dof']:.2f} (bias in {s['units']})")
    if s["pose_sigma"]:
        title += (f"; 1 sigma = white noise + a per-pose error of {s['pose_sigma']:.2g} "
                  "(white: the white noise alone)")
    from station.solve.verdict import words

    suspect = [f"SUSPECT: {'; '.join(s['status_reasons'])}"] if s["status"] == "suspect" else []
    judged = [words(s["verdict"])] if s["verdict"] else []
    weak = [f"weakly determined by these poses (1 sigma beyond 10 % of a scale factor, 6 deg or "
            f"0.1 of the stimulus; the figures above say how loose): "
            f"{', '.join(s['weakly_determined'])}"] if s["weakly_determined"] else []
    return "\n".join([title, *pose_lines(s), *carry_lines(s), *rows, *weak,
                      *repeatability_lines(s), *noise_lines(s), *suspect,
                      f"written to {s['calibration']}", *judged, legend(white)])


def legend(white: bool) -> str:
    """The figures of `station solve`'s table in plain words, once (`white`: the table has the
    (white) columns)."""
    return ("legend: scale factor |a_i| and bias b_i of each sensor (z = a^T v + b, "
            "docs/conventions.md); 1 sigma: its standard uncertainty"
            + ("; (white): the same from the readings' white noise alone" if white else "")
            + "; chi2/dof: the residuals against the readings' noise, near 1 when the model "
            "explains the data (docs/quality.md)")


def repeatability_lines(s: dict) -> list:
    """Lines saying the 1-sigma figures include a combined file's repeatability, if they do."""
    rep = s.get("repeatability")
    if rep is None:
        return []
    taus = ", ".join(f"{k.replace('_', ' ')} {rep['tau'][k]:.3g}"
                     for k in ("bias", "scale_factors"))
    files = ", ".join(f"{f['file']} (sha256 {f['sha256'][:16]}..., unit {f['unit_serial']}, "
                      f"{f['sessions']} sessions)" for f in rep["files"])
    return [f"every 1 sigma includes the spread between sessions of {files}: tau {taus}, "
            f"widened x{rep['widening']['bias']:.3f} for its {rep['dof']['bias']} dof; this "
            f"session's own bias 1 sigma: median {np.median(rep['session_sigma']['bias']):.2g}"]


def noise_lines(s: dict) -> list:
    """One line on the noise figures stored (docs/noise.md), or on why there are none."""
    noise = s["noise"]
    if noise is None:
        return [f"no noise figures: {s[NO_NOISE]}"] if s[NO_NOISE] else []
    resolved = [t for t in ("bias_instability", "random_walk") if noise[t] is not None]
    return [f"noise from {noise['seconds']:.3g} s of static data: white-noise density "
            f"{min(noise['white']):.3g} .. {max(noise['white']):.3g} {noise['units']['white']}"
            + (f"; {' and '.join(t.replace('_', ' ') for t in resolved)} resolved" if resolved
               else "; bias instability and random walk not resolved (too short a rest)")
            + " (`station noise` for the table)"]


def carry_lines(s: dict) -> list:
    """Lines on a gyro calibrated by the gravity carry (`summarise`), none for others."""
    carry = s.get("carry")
    if carry is None:
        return []
    return [f"gyro from {carry['turns']} turns between the still poses, in {s['frame_words']}: "
            f"gravity carried through them lands {carry['error_rms_deg']:.3g} deg RMS (max "
            f"{carry['error_max_deg']:.3g}) from where it is measured, "
            f"{carry['error_start_rms_deg']:.3g} deg with the start (one common scale)"]


def pose_lines(s: dict) -> list:
    """Lines on the stimulus magnitude and the still poses of a summary (`summarise`)."""
    lines = [f"magnitude {s['magnitude']:.6g} ({s['stimulus']})"] if s.get("stimulus") else []
    if "poses" in s:
        lines.append(f"still poses found: {s['poses']}; candidates rejected: "
                     f"{len(s['rejected']) or 'none'}")
        lines += [f"  rejected {a:.2f}-{b:.2f} s: {why}" for a, b, why in s["rejected"]]
    return lines


CAMPAIGN_UNUSED = ("stream", "nominal", "magnitude", "store", "tolerances", "rest", "threshold",
                   "still_channels", "min_still", "faces", "repeatability",
                   "repeatability_from_db")
"""`station solve` options that a thermal campaign refuses (they choose what one session
calibrates)."""


def _run_campaign(args) -> int:
    """`station solve CAMPAIGN`: the temperature model of a thermal campaign."""
    from station.commands import keep_records, new_file
    from station.errors import InputError
    from station.session.campaign import manifest_path

    unused = [f"--{name.replace('_', '-')}" for name in CAMPAIGN_UNUSED
              if getattr(args, name) not in (None, False)]
    if unused:
        raise InputError(f"{', '.join(unused)}: not for a thermal campaign, whose sessions are "
                         "rotary sessions of its stream at their recorded table rate; solve one "
                         "session file with them instead")
    directory = manifest_path(args.session).parent
    out = new_file(args.out or directory / "campaign.cal.json", force=args.force)
    cal, fit = solve_campaign(args.session, args.accept_suspect)
    cal.save(out, overwrite=args.force)
    summary = summarise_campaign(cal, fit, out)
    print(json.dumps(summary, indent=2) if args.json else campaign_text(summary))
    return keep_records(args, [out], "campaign")


def solve_campaign(path, accept_suspect: bool = False) -> tuple:
    """(Calibration with the temperature model, TemperatureFit) of the thermal campaign at `path`
    (directory or manifest): one soak per session (`station.reduce.thermal`), the orders chosen
    by likelihood ratio (`station.solve.temperature.fit_temperature`). A fit whose soaks scatter
    about the model beyond their uncertainty is refused unless `accept_suspect`."""
    from station.calfiles.calfile import Calibration
    from station.errors import SuspectFitError
    from station.reduce.thermal import campaign_soaks
    from station.solve.temperature import fit_temperature

    c = campaign_soaks(path)
    fit = fit_temperature(c.soaks, c.rate, names=c.sensors)
    if fit.problems and not accept_suspect:
        raise SuspectFitError(f"{path}: the temperature fit is suspect, so no calibration file "
                              f"was written: {'; '.join(fit.problems)}; give --accept-suspect to "
                              "write it marked suspect")
    session = {"path": str(Path(path).resolve()), "stream": "imu", "protocol": "thermal campaign",
               "sessions": c.files, "stimulus": "recorded table rate"}
    cal = Calibration.from_temperature_fit(fit, c.unit_serial, c.sensors, c.units,
                                           counts_per_unit=c.counts_per_unit, session=session,
                                           bias_source="static windows of each soak's rotary "
                                                       "session, fitted over the soaks")
    return cal, fit


def summarise_campaign(cal, fit, out) -> dict:
    """What `station solve` reports about a campaign's calibration: the soaks, the chosen orders
    and every tempco with its 1-sigma."""
    model = fit.model
    return {"calibration": str(out), "unit_serial": cal.unit_serial, "sensors": list(cal.sensors),
            "units": cal.units[0], "soaks_K": [s.temperature for s in fit.soak_data],
            "t_ref": model.t_ref, "range_K": [model.t_min, model.t_max], "orders": model.orders,
            "bias_tempco": model.bias.tolist(), "bias_tempco_sigma": model.bias_sigma.tolist(),
            "scale_tempco": model.scale.tolist(),
            "scale_tempco_sigma": model.scale_sigma.tolist(),
            "chi2": fit.chi2, "dof": fit.dof, "status": cal.fit.get("status"),
            "status_reasons": list(fit.problems)}


def campaign_text(s: dict) -> str:
    """The campaign summary in words: orders, then per sensor the linear tempcos +- 1 sigma."""
    orders = s["orders"]
    lines = [f"unit {s['unit_serial']}: {len(s['soaks_K'])} soaks at "
             f"{', '.join(f'{t:.2f}' for t in s['soaks_K'])} K, T_ref {s['t_ref']:.2f} K; "
             f"orders chosen: bias {orders['bias']}, scale factor {orders['scale']} "
             f"(chi2 {s['chi2']:.1f} for {s['dof']} dof)",
             f"{'sensor':>8} {'bias tempco per K^p (' + s['units'] + ')':>36} "
             f"{'scale tempco per K^p':>32}"]
    for i, name in enumerate(s["sensors"]):
        bias = "  ".join(f"{v:+.3e} +- {e:.1e}" for v, e in
                         zip(s["bias_tempco"][i], s["bias_tempco_sigma"][i], strict=True))
        scale = "  ".join(f"{v:+.3e} +- {e:.1e}" for v, e in
                          zip(s["scale_tempco"][i], s["scale_tempco_sigma"][i], strict=True))
        lines.append(f"{name:>8} {bias or '-':>36} {scale or '-':>32}")
    if s["status"] == "suspect":
        lines.append(f"SUSPECT: {'; '.join(s['status_reasons'])}")
    return "\n".join([*lines, f"written to {s['calibration']}"])
