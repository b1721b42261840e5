"""`station plan`: the positions of a rotary (or free-static) session on the bench's mounting
fixture, chosen before the session (`station.protocols.planned`, `station.solve.plan`), with their
expected error.

The bench profile's [fixture] section describes the fixture (a cube with lettered faces A-F,
optionally a 45-degree wedge), how the unit sits in it, the unit's nominal layout and its noise
density. The planner picks, one at a time, the fixture pose that lowers the Cramer-Rao bound of
Eq. (19) the most, stops when one more position would lower the expected eps by less than the
threshold, and improves the set by exchanges. `station record` with the same profile asks for
exactly these poses, in these words. docs/protocols.md, "Fixture and plan", gives the words'
convention.
"""

import json
from pathlib import Path

from station.errors import InputError


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.description = __doc__
    p.epilog = ("examples:\n  station plan --profile bench.toml\n"
                "  station plan --profile bench.toml --pictures\n"
                "  station plan --profile bench.toml --json")
    p.add_argument("--profile", type=Path, required=True,
                   help="bench profile (TOML) with a [fixture] section")
    p.add_argument("--pictures", action="store_true",
                   help="draw each pose (ASCII) under its words")
    p.add_argument("--json", action="store_true", help="machine-readable plan")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.acquire.bench import BenchProfile
    from station.commands import existing_file
    from station.protocols.planned import rotary_plan, static_plan

    bench = BenchProfile.load(existing_file(args.profile, "a bench profile (.toml)"))
    if bench.fixture is None:
        raise InputError(f"{args.profile} describes no fixture: add a [fixture] section "
                         "(docs/protocols.md, \"Fixture and plan\") to plan a session")
    plan = (static_plan(bench.fixture, bench.settings) if bench.protocol == "static" else
            rotary_plan(bench.fixture, bench.settings, bench.positions))
    steps = plan.instructions()
    if args.json:
        print(json.dumps({
            "profile": str(args.profile), "unit_serial": bench.unit_serial,
            "positions": len(steps), "expected_eps": plan.eps, "reading_sigma": plan.sigma,
            "expected_eps_by_count": [None if e == float("inf") else e for e in plan.expected],
            "poses": [{"words": s["words"], "up": [row[2] for row in s["orientation"]],
                       "orientation": s["orientation"]} for s in steps]}, indent=2))
        return 0
    print(f"plan for unit {bench.unit_serial}: {len(steps)} positions on the fixture, expected "
          f"eps {plan.eps:.3g} (Eq. 19; one position's reading noise {plan.sigma:.3g})")
    for j, s in enumerate(steps):
        print(f"{j + 1:3d}. {s['words']}")
        if args.pictures:
            print(s["picture"])
    counts = ", ".join(f"{n + 1}: {e:.3g}" for n, e in enumerate(plan.expected)
                       if e != float("inf"))
    print(f"expected eps by count (greedy): {counts}")
    return 0
