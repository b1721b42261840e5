"""A session planned on a mounting fixture: the bench profile's [fixture] section, the plan
(`station.solve.plan`) over the fixture's reachable poses (`station.model.fixture`), and the
technician's instructions in the fixture's words. Rotary sessions (gyros) and free-static ones
(accelerometers: the same cube set still on the table, biases estimated, each pose once since the
static protocol refuses a pose it has seen).

    [fixture]
    layout = [[...], [...], [...]]   # the unit's nominal sensitive axes: 3 rows, a column per
                                     # channel (default the identity for a triad)
    noise_density = 1.7e-4           # white noise of a channel, SI unit / sqrt(Hz)
    mounting = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]  # cube frame -> unit frame (default identity)
    wedge = true                     # a 45-degree wedge is on the bench (diagonal poses)
    wedge_deg = 45.0                 # its slope
    threshold = 0.025                # stop when one more position lowers the eps by less
    # [protocol] positions = 40      # with a fixture: the most positions the plan may use

For a static session the layout is the [protocol] layout (the accelerometers'), and the count is
the plan's (`poses` is not used). The noise of one position's Eq. (18) reading is that of a
rotating-window mean over the whole turns (2 pi revolutions / |c| s) minus a static-window mean
(`static` s): for white noise of density N, sigma^2 = N^2 (|c| / (2 pi revolutions) + 1 /
static); a still pose's reading is the mean of `hold` s: sigma^2 = N^2 / hold.

On a two-axis table (docs/protocols.md "Two-axis sessions") the table sets every position itself:
no fixture, and the profile's [plan] section gives what the planner needs (layout, noise_density,
threshold, as above). The candidates are the rate axis at position angles every `GRID_DEG` (the
cone of `station.model.two_axis`) and a spin of the position axis (c); `two_axis_plan` gives the
cone positions' angles and the count of spins. A spin's reading is that of a rate-axis position of
the same settings (the same rate, whole turns and static window), so it has the same noise.
"""

from collections import Counter
from dataclasses import dataclass

import numpy as np

from station.acquire.operator import Instruction
from station.errors import CalibrationInputError, InputError
from station.model import two_axis
from station.model.fixture import Fixture, picture

GRID_DEG = 5.0
"""Spacing (deg) of the position angles a two-axis plan chooses from."""


@dataclass(frozen=True)
class PlanSpec:
    """What the planner needs of the unit: the [plan] section of a two-axis bench profile, and the
    planning keys of a [fixture] section (`FixtureSpec.from_section`)."""

    layout: np.ndarray  # (3, m) nominal axes
    noise_density: float
    threshold: float = 0.025

    @classmethod
    def from_section(cls, section, channels: int, layout=None) -> "PlanSpec":
        """Parse the keys layout (unless `layout` is given: the nominal layout the profile gave
        elsewhere, static: [protocol] layout), noise_density and threshold of a
        `drivers.profile.Section`, then refuse any key nobody read; `channels`: the calibrated
        channels' count."""
        from drivers.profile import ProfileError

        if layout is None:
            default = np.eye(3).tolist() if channels == 3 else None
            layout = section.get_rows("layout", 3, channels, default)
        if layout is None:
            raise section.error("layout", f"missing; the unit has {channels} channels: give "
                                f"their nominal axes, 3 lists of {channels} numbers")
        spec = cls(np.array(layout, float), section.get("noise_density", float),
                   section.get("threshold", float, default=0.025))
        if not 0 < spec.noise_density < np.inf or not 0 <= spec.threshold < 1:
            raise ProfileError(f"{section.source}: [{section.name}] noise_density must be "
                               "positive and finite (SI unit / sqrt(Hz)) and threshold in [0, 1)")
        if not np.all(np.isfinite(spec.layout)):
            raise section.error("layout", "must be finite numbers")
        if np.linalg.matrix_rank(spec.layout) < 3:
            raise section.error("layout", "the axes must span 3 dimensions")
        section.finish()
        return spec

    def table(self) -> dict:
        """The section as TOML values (for a bench profile written by a twin)."""
        return {"layout": self.layout.tolist(), "noise_density": self.noise_density,
                "threshold": self.threshold}


@dataclass(frozen=True)
class FixtureSpec:
    """The [fixture] section of a bench profile: the fixture and what the plan needs."""

    fixture: Fixture
    layout: np.ndarray  # (3, m) nominal axes
    noise_density: float
    threshold: float = 0.025

    @classmethod
    def from_section(cls, section, channels: int, layout=None) -> "FixtureSpec":
        """Parse a `drivers.profile.Section`: the fixture's keys, then the planning keys
        (`PlanSpec.from_section`, whose arguments these are)."""
        from drivers.profile import ProfileError

        try:
            fixture = Fixture(np.array(section.get_rows("mounting", 3, 3, np.eye(3).tolist())),
                              section.get("wedge", bool, default=False),
                              section.get("wedge_deg", float, default=45.0))
        except InputError as exc:
            raise ProfileError(f"{section.source}: [fixture] {exc}") from None
        plan = PlanSpec.from_section(section, channels, layout)
        return cls(fixture, plan.layout, plan.noise_density, plan.threshold)

    def table(self) -> dict:
        """The section as TOML values (for a bench profile written by a twin)."""
        return {**PlanSpec(self.layout, self.noise_density, self.threshold).table(),
                "mounting": self.fixture.mounting.tolist(), "wedge": self.fixture.wedge,
                "wedge_deg": self.fixture.wedge_deg}


@dataclass(frozen=True)
class FixturePlan:
    """The planned positions: fixture poses in order, the per-count and final expected eps."""

    poses: list  # station.model.fixture.Pose
    expected: np.ndarray
    eps: float
    sigma: float  # one position's reading noise, SI units

    def prompt(self) -> str:
        """What the technician is told before the session."""
        return (f"plan: {len(self.poses)} positions on the fixture, expected eps {self.eps:.3g} "
                "(Eq. 19, sqrt of the Cramer-Rao bound)")

    def repeats(self) -> str:
        """Why poses repeat, in words ("" when none does)."""
        counts = Counter(p.words for p in self.poses)
        again = sorted(counts.values(), reverse=True)
        if again[0] == 1:
            return ""
        times = ", ".join(f"{n} of them {k} times" for k, n in sorted(
            Counter(c for c in again if c > 1).items(), reverse=True))
        return (f"{len(self.poses)} positions in {len(counts)} distinct poses ({times}): of the "
                "poses the fixture can set, repeating these lowers the expected eps more than "
                "adding any other (a repeat averages its noise down; station/solve/plan.py)")

    def instructions(self) -> list:
        """{"words", "picture", "orientation"} per position, as the session metadata keeps them
        (`station.protocols.rotary.RotaryProtocol`, fixture_poses)."""
        return [{"words": p.words, "picture": picture(p), "orientation": p.orientation.tolist()}
                for p in self.poses]

    def guided(self) -> list:
        """(name, up, words) per position, as `station.protocols.static.StaticProtocol` asks."""
        return [(f"{'wedge ' if p.wedge else ''}{p.down}/{p.front}", p.up,
                 f"set the cube {p.words}") for p in self.poses]


def reading_noise(noise_density: float, settings) -> float:
    """One position's Eq. (18) reading noise for `RotarySettings` (module docstring)."""
    turns = 2 * np.pi * settings.revolutions / abs(settings.rate)
    return float(noise_density * np.sqrt(1 / turns + 1 / settings.static))


def rotary_plan(spec: FixtureSpec, settings, most: int) -> FixturePlan:
    """The plan of a rotary session (`RotarySettings`) on the fixture, at most `most` positions."""
    return _plan(spec, reading_noise(spec.noise_density, settings), abs(settings.rate),
                 most=most)


def static_plan(spec: FixtureSpec, settings) -> FixturePlan:
    """The plan of a free-static session (`StaticSettings`: gravity, hold) on the fixture: each
    pose at most once, biases estimated."""
    return _plan(spec, spec.noise_density / np.sqrt(settings.hold), settings.gravity,
                 most=len(spec.fixture.poses()), estimate_bias=True, distinct=True)


@dataclass(frozen=True)
class TwoAxisPlan:
    """The planned positions of a two-axis session: the cone positions' angles of the position
    axis in increasing order (so that it moves little), then `spins` spins of the position axis;
    the per-count and final expected eps."""

    phis: np.ndarray  # (n,) rad
    spins: int
    expected: np.ndarray
    eps: float
    sigma: float  # one position's reading noise, SI units

    def axes(self) -> np.ndarray:
        """(n + spins, 3) unit-frame spin axes in the order of the session
        (`station.model.two_axis.spin_axes`)."""
        return two_axis.spin_axes(self.phis, self.spins)

    def prompt(self) -> str:
        """What the technician is told before the session."""
        return (f"plan: {len(self.phis)} positions on the cone and {self.spins} spin(s) of the "
                f"position axis, expected eps {self.eps:.3g} (Eq. 19, sqrt of the Cramer-Rao "
                "bound)")

    def words(self) -> list:
        """Each position in the technician's words, as the session will set it."""
        n = len(self.phis) + self.spins
        return [f"position {j + 1}/{n}: position axis to {np.degrees(phi):.1f} deg, the rate "
                "axis spins" for j, phi in enumerate(self.phis)] + \
               [f"position {j + 1}/{n}: the position axis spins"
                for j in range(len(self.phis), n)]


def two_axis_plan(spec: PlanSpec, settings, most: int) -> TwoAxisPlan:
    """The plan of a two-axis session (`RotarySettings`), at most `most` positions: the rate axis
    at position angles every GRID_DEG, or a spin of the position axis (its +c and -c carry the
    same information; the session alternates them, `two_axis.spin_signs`)."""
    from station.solve.plan import plan

    grid = np.radians(np.arange(0.0, 360.0, GRID_DEG))
    up = np.vstack([two_axis.rate_axis(grid), two_axis.position_axis()])
    sigma = reading_noise(spec.noise_density, settings)
    try:
        chosen = plan(spec.layout, up, sigma, abs(settings.rate), threshold=spec.threshold,
                      most=most)
    except CalibrationInputError:
        raise InputError(f"no plan of at most {most} positions on the two-axis table identifies "
                         "the [plan] layout: allow more ([protocol] positions), or check the "
                         "layout") from None
    cone = chosen.chosen[chosen.chosen < len(grid)]
    return TwoAxisPlan(np.sort(grid[cone]), int(np.sum(chosen.chosen == len(grid))),
                       chosen.expected, chosen.eps, sigma)


def _plan(spec: FixtureSpec, sigma: float, magnitude: float, **options) -> FixturePlan:
    from station.solve.plan import plan

    up, poses = spec.fixture.reachable_up()
    chosen = plan(spec.layout, up, sigma, magnitude, threshold=spec.threshold, **options)
    return FixturePlan([poses[k] for k in chosen.chosen], chosen.expected, chosen.eps, sigma)


def fixture_instruction(position: int, n: int, pose: dict) -> Instruction:
    """The technician's instruction for position `position` (0-based) of n, a fixture pose of
    `FixturePlan.instructions`."""
    return Instruction(f"position {position + 1}/{n}: set the cube {pose['words']}\n"
                       f"{pose['picture']}", np.array(pose["orientation"], float))
