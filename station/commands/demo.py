"""`station demo`: a whole calibration session on the virtual bench, through the real drivers.

The virtual bench (a 12-gyro unit streaming over a pseudo-terminal or a virtual CAN bus, a Modbus
rotary table on 127.0.0.1, a simulated technician) runs in lockstep time: the bench's clock moves on
only when the station has taken what the twins sent, so the session is the same on any host and runs
as fast as the host allows (`--speed X`: a real-time clock X times the wall's). The station runs the
rotary protocol through its ordinary drivers, records the session file, reduces it (Eq. 18 of
Rupniewski), calibrates, and compares the result with the simulator's truth: eps (Eq. 19) against
the Cramer-Rao bound sqrt(trace(CRLB)).
"""

import json
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from station.sim.layouts import GYRO_TOLERANCES
from station.solve.verdict import Tolerances

DEMO_TOLERANCES = Tolerances(**GYRO_TOLERANCES)
"""The simulated MEMS gyro type's limits (station.sim.layouts.GYRO_TOLERANCES)."""
TRIAD_PAIRS = [(t + i, t + k) for t in range(0, 12, 3) for i, k in ((0, 1), (0, 2), (1, 2))]
"""Sensor pairs within each of the four triads of Rupniewski's layout (nominally 90 deg apart)."""


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    from station.commands import db_arguments

    p.description = __doc__
    p.epilog = (
        "examples:\n  station demo\n  station demo --imu can --json\n"
        "  station demo --positions 12 --speed 80 --out demo.h5"
    )
    p.add_argument("--imu", choices=("serial", "can"), default="serial",
                   help="IMU link: binary frames over a pty (default) or a virtual CAN bus")
    p.add_argument("--positions", type=int, default=20, help="number of positions n (default 20)")
    p.add_argument("--speed", type=float, default=None,
                   help="a real-time clock this many times faster than the wall (simulated s per "
                        "wall s); default: lockstep time, the same session on any host, as fast "
                        "as it allows")
    p.add_argument("--seed", type=int, default=1, help="seed of the simulated unit (default 1)")
    p.add_argument("--out", type=Path,
                   help="keep the session file here (.h5; default: a temporary file, deleted)")
    p.add_argument("--live", action="store_true",
                   help="show the live view of the recording (phase, windows, table, link)")
    db_arguments(p)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.commands import new_file
    from station.commands.solve import verdict_exit
    from station.errors import InputError
    from station.solve.identifiability import check_positions

    if args.speed is not None and not (0 < args.speed < float("inf")):
        raise InputError("--speed must be positive and finite (simulated s per wall s)")
    if args.out is not None:
        new_file(args.out)
        if not args.no_db:  # the calibration file recorded is written beside it
            new_file(args.out.with_suffix(".cal.json"), "--out (its .cal.json exists)")
    check_positions((12, args.positions), 3)  # before recording, not after
    if args.out is None:
        with tempfile.TemporaryDirectory(prefix="station-demo-") as tmp:
            summary = run_demo(Path(tmp) / "demo.h5", args.imu, args.seed, args.positions,
                               args.speed, live=args.live)
            recorded = record_demo(args, Path(tmp) / "demo.h5", Path.cwd())
        summary["session"] = None  # deleted with the temporary directory
    else:
        summary = run_demo(args.out, args.imu, args.seed, args.positions, args.speed,
                           live=args.live)
        recorded = record_demo(args, args.out, None)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        _print(summary)
    return max(verdict_exit(summary["verdict"]), recorded)


def record_demo(args, session: Path, near) -> int:
    """Solve the demo's session into its calibration file (SESSION.cal.json) as `station solve`
    does, against the demo's tolerances, and record it in the record store (`keep_records`;
    default: station.db in the directory `near`, the working directory for a temporary session,
    else beside the session). Its exit code."""
    from station.commands import keep_records
    from station.commands.solve import solve_session

    if args.no_db:
        return 0
    out = session.with_suffix(".cal.json")
    solve_session(session, tolerances=DEMO_TOLERANCES).save(out)
    return keep_records(args, [out], near=near)


def run_demo(path, imu: str = "serial", seed: int = 1, positions: int = 20,
             speed: float | None = None,
             settings=None, live: bool = False) -> dict:
    """Record, reduce and calibrate one session on the virtual bench; the summary as a dict.
    live: show the live view (station.acquire.live_view) while recording. speed: None for lockstep
    time (`drivers.clock.SteppedClock`), else a real-time clock that many times the wall's."""
    import station
    from station.acquire.live_view import LiveView
    from station.acquire.progress import PositionProgress
    from station.commands import progress
    from station.protocols.rotary import RotarySettings, suggested_axes
    from station.reduce.rotary import static_bias
    from station.replay import ReplaySettings, solve_recorded
    from station.session import Session, write_results
    from station.solve.uncertainty import eps_tail_probability
    from station.solve.verdict import verdict
    from station.twin.rotary_bench import VirtualBench, record_rotary

    start = time.perf_counter()
    settings = settings or RotarySettings()
    with VirtualBench(imu, seed=seed, speed=speed) as bench:
        if bench.clock.realtime:  # positions on a seeded grid (lockstep time needs none)
            bench.technician.period = bench.metronome(settings)
        view = LiveView(bench.clock) if live else PositionProgress(progress)
        record_rotary(bench, path, settings, suggested_axes(positions), view=view)
        truth = bench.truth()
        simulated = bench.clock.now() - bench.clock_start
    recorded = time.perf_counter() - start
    with Session.open(path) as session:
        reduced, result = solve_recorded(session, ReplaySettings(), nominal=truth.a_nominal)
        link = next((e.detail["link"] for e in reversed(session.events())
                     if "link" in e.detail), {})
    c = abs(settings.rate)
    write_results(path, "rotary", "imu", reduced.M, result, reduced.sigma)
    judged = verdict(SimpleNamespace(**vars(result) | static_bias(reduced)), DEMO_TOLERANCES,
                     [f"g{i + 1}" for i in range(result.m)], truth.a_nominal)
    eps = station.eps(truth.a, result.a)
    crlb = station.crlb(truth.a, truth.v(c), reduced.sigma)
    bound = float(np.sqrt(np.trace(crlb)))
    true_angles = _angles(truth.a)
    return {
        "imu": imu, "positions": positions, "seed": seed, "speed": speed,
        "session": str(path), "samples": int(np.sum(reduced.n_static + reduced.n_rotating)),
        "link": link,
        "method": result.method, "frame": result.frame,
        "scale_factors": result.scale_factors.tolist(),
        "scale_factors_sigma": result.scale_factors_sigma.tolist(),
        "scale_factors_true": np.linalg.norm(truth.a, axis=0).tolist(),
        "axis_angles_deg": [
            {"pair": [i + 1, k + 1], "angle": np.degrees(result.axis_angles[i, k]),
             "sigma": np.degrees(result.axis_angles_sigma[i, k]),
             "true": np.degrees(true_angles[i, k])} for i, k in TRIAD_PAIRS],
        "readings_sigma_median": float(np.median(reduced.sigma)),
        "chi2_per_dof": result.chi2 / result.dof, "dof": result.dof,
        "eps": eps, "sqrt_trace_crlb": bound, "eps_over_sqrt_crlb": eps / bound,
        "eps_p_value": eps_tail_probability(eps, crlb),
        "verdict": judged,
        "record_seconds": recorded, "wall_seconds": time.perf_counter() - start,
        "simulated_seconds": simulated, "real_time_factor": simulated / recorded,
    }


def _angles(a) -> np.ndarray:
    """(m, m) angles between the columns of a, rad."""
    u = a / np.linalg.norm(a, axis=0)
    return np.arccos(np.clip(u.T @ u, -1.0, 1.0))


def _print(s: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    from station.solve.verdict import words

    console = Console()
    title = (f"12-gyro calibration on the virtual bench: {s['positions']} positions, "
             f"{s['imu']} IMU ({s['method']}, {s['frame']} frame)")
    table = Table(title=title)
    for col in ("sensor", "scale factor", "1 sigma", "true"):
        table.add_column(col, justify="right")
    for i, (k, sd, t) in enumerate(zip(s["scale_factors"], s["scale_factors_sigma"],
                                       s["scale_factors_true"], strict=True)):
        table.add_row(str(i + 1), f"{k:.6f}", f"{sd:.6f}", f"{t:.6f}")
    console.print(table)
    angles = Table(title="angles between the axes of each triad (deg)")
    for col in ("sensors", "angle", "1 sigma", "true"):
        angles.add_column(col, justify="right")
    for row in s["axis_angles_deg"]:
        angles.add_row("{}-{}".format(*row["pair"]), f"{row['angle']:.4f}",
                       f"{row['sigma']:.4f}", f"{row['true']:.4f}")
    console.print(angles)
    console.print(
        f"eps = {s['eps']:.3g}, sqrt(trace CRLB) = {s['sqrt_trace_crlb']:.3g}, ratio "
        f"{s['eps_over_sqrt_crlb']:.2f} (p = {s['eps_p_value']:.2g} for an efficient solver); "
        f"chi2/dof = {s['chi2_per_dof']:.2f}; {s['samples']} samples "
        f"used; {s['simulated_seconds']:.0f} s of bench time recorded in "
        f"{s['record_seconds']:.1f} s ({s['real_time_factor']:.0f}x real time, "
        f"{'lockstep' if s['speed'] is None else 'a real-time clock'}), total "
        f"{s['wall_seconds']:.1f} s wall")
    console.print(words(s["verdict"]), markup=False, soft_wrap=True)
    console.print(LEGEND, markup=False, soft_wrap=True)


LEGEND = """what the figures mean:
  1 sigma     the estimate's standard uncertainty (Fisher information of the fit)
  true        the simulated unit's value: known, because the bench is simulated
  eps         the error against that truth: the distance between the estimated and
              the true sensitivity matrices after the best rotation (Eq. 19)
  sqrt(trace CRLB)  the eps an ideal (efficient) solver gets on average at this
              noise, the Cramer-Rao bound; ratio: eps / bound, near 1 when efficient
  p           the chance that an efficient solver's eps is at least this large;
              a p below 0.001 would say the solver or the data fall short
  chi2/dof    the residuals against the readings' noise: near 1 when the model
              explains the data (docs/quality.md)
  VERDICT     the unit against its type's tolerances (docs/quality.md)"""
"""The demo's legend: every figure it prints, in plain words, once."""
