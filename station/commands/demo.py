"""`station demo`: the main job. Until the virtual bench exists it calibrates a simulated
12-gyro unit (Rupniewski Section IV) and prints the calibration with its uncertainties."""

import json
import time

import numpy as np

A_MODEL = np.array(
    [
        [1, 0, 0, 0, 1, 0, 0, -1, 0, 1, 0, 0],
        [0, 1, 0, -1, 0, 0, 1, 0, 0, 0, 0, -1],
        [0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 1, 0],
    ],
    dtype=float,
)


def register(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="calibrate a simulated 12-gyro unit and print the result",
        description=__doc__,
        epilog="examples:\n  station demo\n  station demo --positions 30 --sigma 0.005 --json",
    )
    p.add_argument("--positions", type=int, default=20, help="number of positions n (default 20)")
    p.add_argument("--sigma", type=float, default=0.01, help="noise of the averaged readings, rad/s")
    p.add_argument("--rate", type=float, default=1.0, help="table rate magnitude c, rad/s")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(run=run)


def run(args) -> int:
    import station

    t0 = time.perf_counter()
    rng = np.random.default_rng(args.seed)
    a_true = A_MODEL * (1 + 0.02 * rng.standard_normal(12)) + 0.01 * rng.standard_normal((3, 12))
    v = rng.standard_normal((3, args.positions))
    v *= args.rate / np.linalg.norm(v, axis=0)
    readings = a_true.T @ v + args.sigma * rng.standard_normal((12, args.positions))
    res = station.calibrate(readings, args.rate, sigma=args.sigma, nominal=A_MODEL)
    eps = station.eps(a_true, res.a)
    bound = float(np.sqrt(np.trace(station.crlb(a_true, v, args.sigma))))
    summary = {
        "method": res.method,
        "frame": res.frame,
        "scale_factors": res.scale_factors.tolist(),
        "scale_factors_sigma": res.scale_factors_sigma.tolist(),
        "eps": eps,
        "sqrt_trace_crlb": bound,
        "eps_over_sqrt_crlb": eps / bound,
        "chi2_per_dof": res.chi2 / res.dof,
        "wall_seconds": time.perf_counter() - t0,
    }
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"12-gyro calibration, {args.positions} positions ({res.method}, {res.frame} frame)")
    for col in ("sensor", "scale factor", "1 sigma", "true", "angle to nominal axis (deg)"):
        table.add_column(col, justify="right")
    nominal_unit = A_MODEL / np.linalg.norm(A_MODEL, axis=0)
    for i in range(12):
        u = res.a[:, i] / res.scale_factors[i]
        table.add_row(
            str(i + 1), f"{res.scale_factors[i]:.5f}", f"{res.scale_factors_sigma[i]:.5f}",
            f"{np.linalg.norm(a_true[:, i]):.5f}",
            f"{np.degrees(np.arccos(np.clip(u @ nominal_unit[:, i], -1, 1))):.3f}",
        )
    console = Console()
    console.print(table)
    console.print(
        f"eps = {eps:.4f}, sqrt(trace CRLB) = {bound:.4f}, ratio {eps / bound:.2f}; "
        f"chi2/dof = {summary['chi2_per_dof']:.2f}; {summary['wall_seconds']:.2f} s"
    )
    return 0
