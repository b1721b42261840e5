"""The virtual bench: every device of a calibration bench, simulated, behind its real wire protocol.

    with VirtualBench(imu="serial", seed=1, speed=40) as bench, bench.drivers() as (imu, table):
        ...  # imu: a drivers.ImuDriver (serial or CAN), table: drivers.rotary_table.RotaryTable
        bench.technician  # the simulated technician (station.acquire.operator.SimulatedTechnician)
        bench.truth()     # what the station should find

One clock drives everything (`drivers.clock`: lockstep time by default, the same samples on any
host; a `ScaledClock` with `speed`, for what must meet the wall clock): the rotary table physics
(`station.sim.table`) served over Modbus TCP on 127.0.0.1 (`drivers.twins.table.TableTwin`), a
12-gyro unit (`station.sim.layouts. gyro_array`, Rupniewski Section IV) mounted on that table
(`station.sim.live.MountedUnit`) and streaming through a pseudo-terminal
(`drivers.twins.serial.SerialTwin`) or a python-can virtual bus (`drivers.twins.can.CanImuTwin`),
and the technician who re-mounts the unit between positions. The station side opens the ordinary
drivers on the twins' addresses (`drivers()`).

A twin that cannot go on (an error in its thread: the source, the physics) goes silent at once and
is kept in the bench's `failures` (`drivers.twins.failure`), a warning logged at once: the error
that then ends the `with` (e.g. the recorder's "no IMU sample") carries a note naming the twin and
its error.

`record_rotary` records a rotary session on the bench; `resume_rotary` continues a session file
left by a killed or paused run on a new bench built from the file's `virtual_bench` metadata (or
the `bench` of `station demo`), its clock starting after the last recorded instant (the recorded
times stay in order).
"""

import contextlib
import dataclasses
import itertools
import os
from dataclasses import dataclass
from typing import Self

import numpy as np

from drivers import driver_class, open_imu
from drivers.clock import ScaledClock, SteppedClock
from drivers.rotary_table import RotaryTable as TableDriver
from drivers.rotary_table import TableRegisterMap
from drivers.twins.can import CanImuTwin
from drivers.twins.failure import Failures
from drivers.twins.serial import SerialTwin
from drivers.twins.table import TableTwin
from station import limits
from station.acquire.operator import SimulatedTechnician
from station.errors import InputError
from station.model.effects import from_json, to_json
from station.model.effects.rate_error import RateError
from station.model.two_axis import orientation, position_axis, spin_axes
from station.protocols import lookup
from station.protocols.rotary import RotaryProtocol, RotarySettings, continue_session
from station.session import Session, SessionWriter, StreamSpec
from station.sim.layouts import A_MODEL, gyro_array
from station.sim.live import MountedUnit
from station.sim.spikes import SpikySource, check_spikes
from station.sim.table import MountingFixture, PositionAxis, TablePhysics

IMU_KINDS = {"serial": "imu12_serial", "can": "imu12_can"}
_channels = itertools.count()
BENCH_KEYS = {"imu", "seed", "speed", "rate_hz", "remount_time", "placement_deg", "rate_error",
              "effects", "two_axis", "spikes"}
"""The `VirtualBench` arguments a session records (`VirtualBench.metadata`)."""
MARGINS = ("rest", "guard", "steady")
"""The rotary settings that must cover the host's latency (`VirtualBench.with_margins`)."""
HOST_LATENCY = 0.05
"""Wall seconds every protocol margin (rest, guard, steady) covers on the virtual bench. Sample
instants are estimated from the least delayed arrival, so they are late by the smallest host
latency of a segment (14 ms measured on a loaded 2-core host); the fast clock multiplies it, and
a shorter margin lets a window take samples of the previous mounting or of a ramp. In lockstep time
a sample reaches the station at most one step of the clock after it was taken, whatever the host:
the margins cover that step.
(docs/protocols.md)."""


@dataclass(frozen=True)
class BenchTruth:
    """What the simulated unit really is, and the stimulus it really felt.

    a            : (3, m) true sensitivity matrix (dimensionless: readings are in SI units)
    bias         : (m,) true biases, rad/s
    orientations : (n, 3, 3) the mountings the technician really made (table -> unit frame)
    a_nominal    : (3, m) the nominal layout
    """

    a: np.ndarray
    bias: np.ndarray
    orientations: np.ndarray
    a_nominal: np.ndarray

    def v(self, rate: float) -> np.ndarray:
        """(3, n) true stimuli of the positions at table rate `rate`: rate times the table axis."""
        return rate * self.orientations[:, :, 2].T


class BenchTechnician(SimulatedTechnician):
    """The simulated technician, who also plugs the IMU's cable back in when asked to do
    something that is not a mounting (`fixes_cables = False` models one who does not).

    With a `period` (clock s; `VirtualBench.metronome`), the technician works to a metronome:
    each mounting is done at the first multiple of `period` at least `remount_time` after the
    request, so every position starts on that grid whatever the host's timing before it."""

    def __init__(self, bench, *args):
        super().__init__(bench.mounted, bench.clock, *args)
        self.bench = bench
        self.fixes_cables = True
        self.period = None

    def wait(self, instruction) -> None:
        if self.period and instruction.orientation is not None:
            done = self.period * np.ceil((self.clock.now() + self.remount_time) / self.period)
            self.clock.sleep(done - self.remount_time - self.clock.now())
        super().wait(instruction)
        twin = self.bench.imu_twin
        if instruction.orientation is None and self.fixes_cables and hasattr(twin, "plug"):
            self.clock.sleep(self.remount_time)
            twin.plug()


class VirtualBench:
    """Starts the simulated devices; `close()` (or leaving the `with`) stops them all.

    imu           : "serial" (binary frames over a pty) or "can" (python-can virtual bus)
    seed          : seed of the unit, the table and the technician
    speed         : clock speed, simulated seconds per wall second (a `ScaledClock`); None (the
                    default): lockstep time (`SteppedClock`), as fast as the host allows
    rate_hz       : IMU sample rate (the profiles' 2 kHz is more than a demo needs)
    remount_time  : simulated seconds the technician takes to re-mount the unit
    placement_deg : the technician's placement error (standard deviation per axis), degrees
    lifetime      : wall seconds after which the Modbus server stops by itself
    clock_start   : clock time at start (a resumed session continues after its last instant)
    rate_error    : optional {"scale": ..., "spread": ...}: the table's hidden rate error
                    (`station.model.effects.rate_error`), drawn anew at every start
    effects       : optional {name: {param: value}}: named effects in the unit's output chain
                    (`station.model.sensing.LIVE_EFFECTS`), e.g. {"saturation": {"range": 3.0}}
    two_axis      : a two-axis table (profile table_two_axis, `station.model.two_axis` geometry):
                    the unit sits on the position axis and takes `two_axis.orientation(phi)` when
                    the axis reaches phi (no technician needed for the mountings); in its rate
                    mode the axis turns the unit about `two_axis.position_axis()`
    fixture       : the table's controller drives a motorised mounting fixture (profile
                    table_fixture): `self.fixture`, a `station.sim.table.MountingFixture`, holds
                    what the station asks for; whoever serves it (`station.twin.served.BenchTwin`)
                    mounts the unit
    spikes        : a fault knob: the positions (1-based, over the bench's life) whose first
                    attempt is spiky, or a chance per position (`station.sim.spikes`); None: none

    `table_reply` (attribute, default None): the wall seconds the station's table driver waits
    for each reply (`drivers`, and the [table] reply_timeout of `station twin`'s profile); None:
    `drivers.clock.reply_timeout` of the bench's clock.
    """

    table_reply: float | None = None

    def __init__(self, imu: str = "serial", seed: int = 1, speed: float | None = None,
                 rate_hz: float = 200.0, remount_time: float = 5.0, placement_deg: float = 0.5,
                 lifetime: float = 3600.0, clock_start: float = 0.0,
                 rate_error: dict | None = None, effects: dict | None = None,
                 two_axis: bool = False, fixture: bool = False, spikes=None):
        if imu not in IMU_KINDS:
            raise InputError(f"unknown IMU link {imu!r}; choose one of {sorted(IMU_KINDS)}")
        self.kind = imu
        self.seed, self.rate_hz = int(seed), float(rate_hz)
        self.remount_time, self.placement_deg = float(remount_time), float(placement_deg)
        self.clock = (SteppedClock(clock_start) if speed is None
                      else ScaledClock(speed, clock_start))
        self.clock_start = float(clock_start)
        profile = driver_class(imu).profile_type.load(IMU_KINDS[imu])
        self.profile = dataclasses.replace(
            profile, imu=dataclasses.replace(profile.imu, rate_hz=float(rate_hz)))
        self.stream_spec = StreamSpec.from_profile(self.profile.imu)
        self.rate_error = dict(rate_error) if rate_error else None
        self.table = TablePhysics(self.clock, max_accel=2.0, rate_noise=1e-4, seed=seed,
                                 rate_error=RateError(**self.rate_error) if rate_error else None)
        self.two_axis = bool(two_axis)
        self.table_map = TableRegisterMap.load(
            "table_two_axis" if two_axis else "table_fixture" if fixture else "table_modbus")
        self.unit = gyro_array(np.random.default_rng(seed), fs=rate_hz,
                               counts_per_unit=self.profile.imu.scale)
        live = from_json(effects or {})
        self.effects = to_json(live) or None  # every parameter, for the session's metadata
        self.position = PositionAxis(self.clock, on_move=self._turn_unit) if two_axis else None
        self.mounted = MountedUnit(self.unit, self.table, effects=live,
                                   orientation=orientation(0.0) if two_axis else None,
                                   inner=(self.position, position_axis()) if two_axis else None)
        self.technician = BenchTechnician(self, remount_time, placement_deg,
                                          np.random.default_rng([seed, 1]))
        self.fixture = MountingFixture() if fixture else None
        self.failures = Failures()  # of every twin of the bench, told at once
        self.table_twin = self.failures.watch(
            TableTwin(self.table, self.table_map, lifetime, position=self.position,
                      fixture=self.fixture), "rotary table")
        self.can_channel = f"virtual-bench-{os.getpid()}-{next(_channels)}"
        self.source = self.mounted  # what the IMU twin streams (station.twin.thermal: heated)
        check_spikes(spikes)
        self.spikes = list(spikes) if isinstance(spikes, list | tuple) else spikes
        self.imu_twin = None

    def _turn_unit(self, phi: float, arrival: float) -> None:
        """The position axis was commanded to `phi`: what it carries (the unit, or a plate of
        units: the technician's `mounted`) has that orientation from the clock time `arrival`
        on."""
        self.technician.mounted.mount(orientation(phi), arrival)

    def with_margins(self, settings: RotarySettings) -> RotarySettings:
        """`settings` with rest, guard and steady of at least HOST_LATENCY wall seconds of this
        bench's clock (2 s at 40x; a real bench at 1x keeps its settings), or one step of
        lockstep time."""
        least = HOST_LATENCY * self.clock.speed if self.clock.realtime else self.clock.step
        return dataclasses.replace(settings, **{name: max(getattr(settings, name), least)
                                                for name in MARGINS})

    def metronome(self, settings: RotarySettings, slack: float = 0.2) -> float:
        """A technician's period (clock s) for positions recorded with `settings` on this bench:
        the longest a position takes (re-mounting, every wait of the protocol with the bench's
        margins, the table's ramps at its acceleration and its settling, a poll at every step)
        plus `slack` of it for the host's delays."""
        s = self.with_margins(settings)
        ramp = abs(s.rate) / self.table.max_accel + self.table.settle_time
        turning = 2 * np.pi * (s.revolutions + 0.25) / abs(s.rate)
        polls = 8 * s.poll
        return (1 + slack) * (self.remount_time + 2 * s.rest + s.static + 2 * s.guard + s.steady
                              + 2 * ramp + turning + polls)

    def metadata(self) -> dict:
        """What a session records about the bench: enough to build it again (`from_metadata`)."""
        hidden = {k: v for k, v in (("rate_error", self.rate_error), ("effects", self.effects),
                                    ("two_axis", self.two_axis), ("spikes", self.spikes)) if v}
        return {"imu": self.kind, "seed": self.seed,
                "speed": self.clock.speed if self.clock.realtime else None,
                "rate_hz": self.rate_hz, "remount_time": self.remount_time,
                "placement_deg": self.placement_deg, **hidden}

    @classmethod
    def from_metadata(cls, bench: dict, **overrides) -> "VirtualBench":
        """The bench described by a session's `bench` metadata (`metadata()`), with `overrides`
        (e.g. clock_start, speed); every field checked first (`checked_bench`)."""
        return cls(**{**checked_bench(bench), **overrides})

    def streamed(self):
        """What the IMU twin streams: `source`, spiked by the `spikes` knob when it is set
        (`station.sim.spikes.SpikySource`)."""
        if not self.spikes:
            return self.source
        return SpikySource(self.source, self.mounted, self.spikes, self.profile.imu.scale,
                           self.seed)

    def start(self) -> Self:
        """Start the Modbus server and the IMU stream (or stop what started and raise)."""
        try:
            self.table_twin.start()
            if self.kind == "serial":
                self.imu_twin = SerialTwin(self.profile, self.streamed(), self.clock,
                                           max_lag=np.inf)  # flow control: never skip frames
            else:
                self.imu_twin = CanImuTwin(self.can_channel, self.profile, self.streamed(),
                                           self.clock)
            self.failures.watch(self.imu_twin, "CAN IMU" if self.kind == "can" else "serial IMU")
            # sample n is taken at clock_start + n / rate_hz, whenever the host gets round to it,
            # and the unit's noise is indexed by that instant: a seeded bench repeats its samples
            # (those sent before the driver listens are lost)
            self.imu_twin.start(self.clock_start)
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        """Stop the IMU stream and the Modbus server (idempotent)."""
        if self.imu_twin is not None:
            twin, self.imu_twin = self.imu_twin, None
            twin.stop()
        self.table_twin.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, kind, exc, trace) -> None:
        """Close; a twin's failure becomes a note on the error leaving the `with`, or a TwinError
        (`drivers.twins.failure.Failures.after`)."""
        self.close()
        self.failures.after(exc)

    @contextlib.contextmanager
    def drivers(self, reply: float | None = None):
        """(imu, table): the station's real drivers connected to the twins, closed on exit; the
        table driver stops the table on exit whatever happened. `reply`: wall seconds the table
        driver waits for each reply (default `table_reply`)."""
        table = TableDriver("127.0.0.1", self.table_twin.port, self.table_map,
                            timeout=self.table_reply if reply is None else reply,
                            clock=self.clock)
        with contextlib.ExitStack() as stack:
            imu = stack.enter_context(open_imu(self.kind, self.imu_address, self.profile,
                                               self.clock))
            yield imu, stack.enter_context(table)

    @property
    def imu_address(self):
        """Where the IMU driver finds the twin: the pty's path or the virtual CAN bus."""
        if self.kind == "serial":
            return self.imu_twin.port
        return {"interface": "virtual", "channel": self.can_channel}

    def truth(self) -> BenchTruth:
        """The true unit and the mountings made so far."""
        return BenchTruth(self.unit.a.copy(), self.unit.bias.copy(),
                          np.array(self.technician.orientations).reshape(-1, 3, 3), A_MODEL)


BENCH_LIMITS = {"seed": (0, 2**32 - 1), "speed": (0.1, 1e4), "rate_hz": (1.0, 1e4),
                "remount_time": (0.0, 600.0), "placement_deg": (0.0, 45.0),
                "rate_error": (-0.5, 0.5)}
"""Ranges of the recorded virtual bench's numbers (`checked_bench`): a seed numpy takes, a clock
between 0.1x and 10^4x, sample rates and re-mounting times a session can afford, placement errors
and table rate errors (relative: scale and spread) a technician and a table may have."""


def checked_bench(bench, where: str = "virtual_bench") -> dict:
    """A session's virtual bench description (`VirtualBench.metadata`) with every field checked
    against `BENCH_LIMITS`, before anything is built from it; InputError naming the first field
    out of range or of the wrong type (`station.limits`)."""
    if not isinstance(bench, dict) or not set(bench) <= BENCH_KEYS:
        raise InputError(f"the session's bench description {str(bench)[:80]} is not one of this "
                         f"station's virtual benches (an object with keys {sorted(BENCH_KEYS)})")
    out = dict(bench)
    if "imu" in bench:
        limits.choice(bench["imu"], f"{where}.imu", tuple(IMU_KINDS))
    if "seed" in bench:
        limits.whole(bench["seed"], f"{where}.seed", *BENCH_LIMITS["seed"])
    for key in ("rate_hz", "remount_time", "placement_deg"):
        if key in bench:
            out[key] = limits.number(bench[key], f"{where}.{key}", *BENCH_LIMITS[key])
    if bench.get("speed") is not None:
        out["speed"] = limits.number(bench["speed"], f"{where}.speed", *BENCH_LIMITS["speed"])
    if "two_axis" in bench:
        limits.choice(bench["two_axis"], f"{where}.two_axis", (True, False))
    if bench.get("rate_error") is not None:
        out["rate_error"] = _checked_rate_error(bench["rate_error"], f"{where}.rate_error")
    if bench.get("effects") is not None:
        out["effects"] = _checked_effects(bench["effects"], f"{where}.effects")
    return out


def _checked_rate_error(value, where: str) -> dict:
    """The table's hidden rate error of a bench description: {"scale", "spread"[, "encoder"]}."""
    if not isinstance(value, dict) or not set(value) <= {"scale", "spread", "encoder"}:
        raise InputError(f"{where} = {str(value)[:60]}: give an object with scale and spread "
                         "(relative errors) and optionally encoder (true or false)")
    out = {k: limits.number(value[k], f"{where}.{k}", *BENCH_LIMITS["rate_error"])
           for k in ("scale", "spread") if k in value}
    if "encoder" in value:
        out["encoder"] = limits.choice(value["encoder"], f"{where}.encoder", (True, False))
    return out


def _checked_effects(value, where: str) -> dict:
    """Named effects of a bench description, {name: {parameter: value}}, as the effects' own
    checks accept them (`station.model.effects.from_json`)."""
    if not (isinstance(value, dict) and all(isinstance(p, dict) for p in value.values())):
        raise InputError(f"{where} = {str(value)[:60]}: give an object {{effect: {{parameter: "
                         "value}}")
    try:
        from_json(value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: {' '.join(str(exc).split())[:160]}") from None
    return value


def record_rotary(bench: VirtualBench, path, settings=None, axes=None, unit_serial: str = "",
                  watch=None, view=None, phis=None, spins: int = 0) -> None:
    """Record a new rotary session file at `path` on the started `bench`.

    settings, axes : `station.protocols.rotary.RotaryProtocol`'s; unit_serial default SIM-<seed>
    phis, spins    : on a two-axis bench, the position-axis angles (rad) and the spins of the
                     position axis after them: the axes are then where they put the rate axis and
                     the position axis (`station.model.two_axis.spin_axes`), no technician
    watch          : optional callable(writer), called once the session file exists
    view           : optional `station.acquire.live_view.LiveView` shown while recording
    """
    with bench.drivers() as (imu, table):
        if phis is not None:
            axes = spin_axes(phis, spins)
        protocol = RotaryProtocol(table, bench.technician, bench.clock,
                                  bench.with_margins(settings or RotarySettings()), axes,
                                  phis=phis, spins=spins)
        metadata = {**protocol.metadata(), "unit_serial": unit_serial or f"SIM-{bench.seed}",
                    "virtual_bench": bench.metadata()}
        with SessionWriter.create(path, metadata, {"imu": bench.stream_spec},
                                  clock=bench.clock) as writer:
            if watch is not None:
                watch(writer)
            continue_session(writer, metadata, imu, table, bench.technician, bench.clock, view)


def resume_rotary(path, watch=None, **overrides) -> int:
    """Continue the rotary session at `path` (killed, paused or aborted) on a new virtual bench
    built from its `bench` metadata; returns the first position recorded now (the number of
    positions when none was left). overrides: VirtualBench arguments, e.g. speed."""
    with Session.open(path) as session:
        metadata = session.metadata
        end = session.last_instant()
    name = metadata.get("protocol")
    lookup(name, "resume", f"{path} holds a {name!r} session", "station resume")
    described = metadata.get("virtual_bench", metadata.get("bench"))
    if not (isinstance(described, dict) and set(described) <= BENCH_KEYS):
        raise InputError(f"{path} was not recorded on the virtual bench; resume it with its "
                         "real devices")
    if overrides.get("speed") is not None:
        limits.number(overrides["speed"], "--speed", *BENCH_LIMITS["speed"])
    RotaryProtocol.from_metadata(metadata, None, None, None)  # checked before the bench starts
    with VirtualBench.from_metadata(described, clock_start=end + 1.0, **overrides) as bench, \
            bench.drivers() as (imu, table), \
            SessionWriter.resume(path, clock=bench.clock) as writer:
        if watch is not None:
            watch(writer)
        return continue_session(writer, metadata, imu, table, bench.technician, bench.clock)
