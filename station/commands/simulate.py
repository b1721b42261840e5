"""`station simulate`: write a simulated recording (.npz) and its truth (.truth.json)."""

import json

import numpy as np

from station.imports import npz
from station.model.effects import EFFECTS, parse_all
from station.protocols import KINDS, kinds_with


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.epilog = (
        "examples:\n  station simulate --out x.npz\n"
        "  station simulate --effect latency=delay=0.002 --seed 3 --out late.npz --json\n"
        "  station simulate --protocol static --effect bias_drift=warmup=0.02 --out hand.npz"
    )
    p.description = (
        "Simulate a session of a protocol kind (station.protocols.KINDS): rotary (12-gyro array), "
        "right-angle iron or free static (accelerometer triad); the truth goes to FILE.truth.json."
    )
    p.add_argument("--protocol", choices=kinds_with("simulate"), default="rotary",
                   help="protocol kind: " + "; ".join(f"{name} ({KINDS[name].title})"
                                                      for name in kinds_with("simulate")))
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
    p.add_argument("--json", action="store_true", help="print what was written as JSON")
    p.set_defaults(run=run)


def simulate(args):
    """The Simulation the arguments describe (the kind's simulate, `station.protocols.KINDS`)."""
    rng = np.random.default_rng(args.seed)
    return KINDS[args.protocol].entry("simulate")(rng, parse_all(args.effect), args)


def run(args) -> int:
    """Simulate and write; bad effect specs or parameters raise InputError."""
    from station.commands import given_values, working

    with given_values(), working(f"simulating a {args.protocol} session"):
        sim = simulate(args)
    data, truth = npz.write(args.out, sim)
    if args.json:
        print(json.dumps({"data": str(data), "truth": str(truth), "protocol": args.protocol,
                          "shape": list(sim.arrays["y"].shape),
                          "effects": [e.partition("=")[0] for e in args.effect]}))
    else:
        print(f"wrote {data} {sim.arrays['y'].shape} and {truth}")
    return 0
