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

On a two-axis table (docs/protocols.md "Two-axis sessions") the table sets every position itself;
the profile's [plan] section (the unit's nominal layout, noise density, threshold) plans the
position axis' angles, at which the rate axis spins, and the spins of the position axis itself.
"""

import json
from pathlib import Path

from station.errors import InputError


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.description = __doc__
    p.epilog = ("examples:\n  station plan --profile bench.toml\n"
                "  station plan --profile bench.toml --pictures\n"
                "  station plan --profile bench.toml --json\n"
                "  station plan --profile two_axis_bench.toml   # a two-axis table's [plan]")
    p.add_argument("--profile", type=Path, required=True,
                   help="bench profile (TOML) with a [fixture] section, or a [plan] section "
                        "(a two-axis table)")
    p.add_argument("--pictures", action="store_true",
                   help="draw each pose (ASCII) under its words")
    p.add_argument("--json", action="store_true", help="machine-readable plan")
    p.set_defaults(run=run)


def run(args) -> int:
    from station.acquire.bench import BenchProfile
    from station.commands import bench_profile
    from station.protocols.planned import rotary_plan, static_plan

    bench = BenchProfile.load(bench_profile(args.profile))
    if bench.plan is not None:
        return _two_axis(args, bench)
    if bench.fixture is None:
        if bench.table_map is not None and bench.table_map.two_axis:
            raise InputError(f"{args.profile} is a two-axis table's bench without a [plan] "
                             "section: add one (layout, noise_density; docs/protocols.md, "
                             "\"Two-axis sessions\") to plan its positions")
        raise InputError(f"{args.profile} describes no fixture: add a [fixture] section "
                         "(docs/protocols.md, \"Fixture and plan\") to plan a session; the "
                         "bundled bench_cube has one (`station plan --profile bench_cube`)")
    plan = (static_plan(bench.fixture, bench.settings) if bench.protocol == "static" else
            rotary_plan(bench.fixture, bench.settings, bench.positions))
    steps = plan.instructions()
    if args.json:
        print(json.dumps({
            "profile": str(args.profile), "unit_serial": bench.unit_serial,
            "positions": len(steps), "expected_eps": plan.eps, "reading_sigma": plan.sigma,
            "expected_eps_by_count": _by_count(plan.expected),
            "distinct_poses": len({s["words"] for s in steps}), "repeats": plan.repeats(),
            "poses": [{"words": s["words"], "up": [row[2] for row in s["orientation"]],
                       "orientation": s["orientation"]} for s in steps]}, indent=2))
        return 0
    print(f"plan for unit {bench.unit_serial}: {len(steps)} positions on the fixture, expected "
          f"eps {plan.eps:.3g} (Eq. 19; one position's reading noise {plan.sigma:.3g})")
    for j, s in enumerate(steps):
        print(f"{j + 1:3d}. {s['words']}")
        if args.pictures:
            print(s["picture"])
    if plan.repeats():
        print(plan.repeats())
    _print_by_count(plan.expected)
    return 0


def _two_axis(args, bench) -> int:
    """The plan of a two-axis table's session (`station.protocols.planned.two_axis_plan`)."""
    import numpy as np

    from station.protocols.planned import two_axis_plan

    plan = two_axis_plan(bench.plan, bench.settings, bench.positions)
    words = plan.words()
    if args.json:
        print(json.dumps({
            "profile": str(args.profile), "unit_serial": bench.unit_serial, "table": "two-axis",
            "positions": len(words), "phis_deg": np.round(np.degrees(plan.phis), 9).tolist(),
            "phis_rad": plan.phis.tolist(), "spins": plan.spins, "expected_eps": plan.eps,
            "reading_sigma": plan.sigma, "expected_eps_by_count": _by_count(plan.expected),
            "steps": words}, indent=2))
        return 0
    print(f"plan for unit {bench.unit_serial}: {len(words)} positions on the two-axis table "
          f"({len(plan.phis)} on the cone, {plan.spins} spin(s) of the position axis), expected "
          f"eps {plan.eps:.3g} (Eq. 19; one position's reading noise {plan.sigma:.3g})")
    for line in words:
        print(f"  {line}")
    _print_by_count(plan.expected)
    return 0


def _by_count(expected) -> list:
    """The expected eps by greedy count as JSON: null while the layout is not identified."""
    return [None if e == float("inf") else float(e) for e in expected]


def _print_by_count(expected) -> None:
    counts = ", ".join(f"{n + 1}: {e:.3g}" for n, e in enumerate(expected) if e != float("inf"))
    print(f"expected eps by count (greedy): {counts}")
