"""`station simulate`: write a simulated recording (.npz) and its truth (.truth.json)."""

import numpy as np

from station.files import npz
from station.model.effects import EFFECTS, parse_all
from station.sim.iron import simulate_iron
from station.sim.layouts import A_MODEL, TRIAD, accelerometer_triad, gyro_array
from station.sim.profile import RotaryTiming
from station.sim.rotary import simulate_rotary
from station.sim.static import simulate_static


def register(subparsers) -> None:
    """Add the `simulate` subcommand."""
    p = subparsers.add_parser(
        "simulate",
        help="simulate a session of the digital twin",
        description="Simulate a rotary (12-gyro array), right-angle-iron or free-static "
        "(accelerometer triad) session; the truth goes to FILE.truth.json.",
    )
    p.add_argument("--protocol", choices=("rotary", "iron", "static"), default="rotary")
    p.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="NAME[=k=v,...]",
        help=f"add an effect: none, {', '.join(EFFECTS)} (see docs/simulator.md)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the numpy Generator")
    p.add_argument("--out", required=True, metavar="FILE.npz", help="data file to write")
    p.add_argument(
        "--positions",
        type=int,
        default=None,
        help="rotary positions (20), iron mountings (3) or static poses (20)",
    )
    p.add_argument("--fs", type=float, default=200.0, help="sample rate, Hz")
    p.add_argument("--rate", type=float, default=np.pi / 2, help="rotary: commanded rate, rad/s")
    p.add_argument(
        "--turn-deg",
        type=float,
        default=None,
        help="iron: simulate a gyro triad turned by this angle on each face",
    )
    p.set_defaults(run=run)


def simulate(args):
    """The Simulation the arguments describe."""
    rng = np.random.default_rng(args.seed)
    effects = parse_all(args.effect)
    if args.protocol == "rotary":
        unit = gyro_array(rng, fs=args.fs)
        return simulate_rotary(
            unit,
            args.positions or 20,
            RotaryTiming(rate=args.rate),
            effects=effects,
            a_nominal=A_MODEL,
        )
    if args.protocol == "iron":
        unit = (
            gyro_array(rng, TRIAD, fs=args.fs)
            if args.turn_deg
            else accelerometer_triad(rng, fs=args.fs)
        )
        return simulate_iron(
            unit, args.positions or 3, turn_deg=args.turn_deg, effects=effects, a_nominal=TRIAD
        )
    unit = accelerometer_triad(rng, fs=args.fs)
    return simulate_static(unit, args.positions or 20, effects=effects, a_nominal=TRIAD)


def run(args) -> int:
    """Simulate and write; bad effect specs or parameters are reported, not raised."""
    try:
        sim = simulate(args)
        data, truth = npz.write(args.out, sim)
    except ValueError as err:
        print(f"station simulate: {err}")
        return 2
    print(f"wrote {data} {sim.arrays['y'].shape} and {truth}")
    return 0
