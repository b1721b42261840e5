"""The virtual benches `station twin` serves to a separate `station record`: the devices of a bench
on a pty and a Modbus server, and a fixture or technician that follows the protocol by itself.

- `BenchTwin`: the rotary bench (`station.twin.rotary_bench.VirtualBench`) whose motorised
  fixture, commanded by the station through the table's controller (profile table_fixture: the
  `mount` register), mounts the unit in position j of `suggested_axes(positions)` when asked for
  it (with `cube`: the planned pose j of a lettered cube on a wedge, the profile's [fixture]);
  with `two_axis` the bench's table is a two-axis one instead (profile table_two_axis): no fixture
  and nobody mounts anything, the station sets each orientation through the position axis (with
  `plan`: at the angles and spins its profile's [plan] plans);
- `HandTwin`: the hand bench (`station.twin.hand_bench.HandBench`) whose technician turns the
  unit on a metronome through the iron's or the free-static protocol's sequence; the static
  bench's triad streams over the serial link or MAVLink (a flight controller, pty or UDP).

`rotary_twin`, `iron_twin` and `static_twin` build them from `station twin`'s options: the
kinds' twin entries in `station.protocols.KINDS`.

Both can lose a device on the real wire and get it back (`toggle`; `station twin` on SIGUSR1 for the
IMU, SIGUSR2 for the table): the IMU's pty is closed (`drivers.twins.serial.SerialTwin.unplug`, the
station's serial driver gets an I/O error) and reopened behind the same port; the Modbus server
stops answering (`drivers.twins.table.TableTwin.silent`, the station's requests time out) and
answers again. The table's physics go on meanwhile: a table turning when its link died turns on.

A twin that cannot go on (an error in its thread) is told at once to the bench's `failures`
(`drivers.twins.failure`), named: the IMU streams and the table's Modbus server, and the fixture
or technician thread, whose failure takes the table's controller down (`BenchTwin`) or unplugs the
IMU (`HandTwin`). `station twin` ends then, its error line naming the twin and the cause.
"""

import dataclasses
import json
import os
import termios
import threading
import time
from pathlib import Path
from typing import Self

import numpy as np

from drivers.twins.failure import fail
from station.errors import InputError
from station.model.fixture import Fixture
from station.model.two_axis import position_axes
from station.protocols.planned import (
    FixtureSpec,
    PlanSpec,
    fixture_instruction,
    rotary_plan,
    static_plan,
    two_axis_plan,
)
from station.protocols.rotary import RotarySettings, instruction, suggested_axes
from station.session.units import unit_stream
from station.sim.layouts import ACCELEROMETER_TOLERANCES, GYRO_TOLERANCES

UNREAD_AFTER = 2.0
"""Wall seconds after which the served IMU counts its port as unread (the station ended or was
killed: `drivers.twins.serial.SerialTwin`): frames are lost meanwhile, as a real device's are, not
kept as a backlog for the resume. The recorder itself gives up on a silence that long
(`Recorder.busy_grace`), so a station that reads at all never loses a frame to it."""


def _clock_address(clock, server) -> dict:
    """How `station record` finds the bench's clock: the lockstep clock's socket, or the speed of
    a real-time one."""
    return {"lockstep": server.path} if server is not None else {"clock_speed": clock.speed}


def _clock_line(address: dict) -> str:
    """The [bench] line of a profile for `_clock_address`."""
    if "lockstep" in address:
        return f"lockstep = {_toml(address['lockstep'])}"
    return f"clock_speed = {address['clock_speed']!r}"


class PortWatch:
    """Tells (once) when a program opens the pty `port`: pyserial configures the terminal then."""

    def __init__(self, port: str):
        self._fd = os.open(port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        self._idle = termios.tcgetattr(self._fd)

    def opened(self) -> bool:
        if self._fd is None or termios.tcgetattr(self._fd) == self._idle:
            return False
        self.close()
        return True

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


class Served:
    """What a served twin (`BenchTwin`, `HandTwin`: `start`, `close` and a `bench`) shares: a
    context manager that closes it and then raises its twins' failures."""

    @property
    def failures(self):
        """The failures of the bench's twins (`drivers.twins.failure.Failures`)."""
        return self.bench.failures

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, kind, exc, trace) -> None:
        self.close()
        self.failures.after(exc)


class BenchTwin(Served):
    """A `VirtualBench` whose unit is mounted by a motorised fixture in the position the station
    asks for (the table controller's `mount` register).

    positions : the fixture follows `suggested_axes(positions)`, as the rotary protocol does
    cube      : the unit sits in a lettered cube with a 45-degree wedge (`station.model.fixture`);
                the bench profile gets its [fixture] section, the fixture follows the plan
                `station record` makes from it (`station.protocols.planned.rotary_plan`, at most
                `positions` positions) in the same words
    two_axis  : a two-axis table (`VirtualBench(two_axis=True)`), no fixture: `positions` on the
                cone, set by the station (`station.model.two_axis.position_angles`), then the
                profile's default spin of the position axis; `truth()["axes"]` are the unit-frame
                directions of those positions, exact (the geometry of `station.model.two_axis`)
    plan      : with two_axis, the bench profile gets a [plan] section (the unit's nominal layout
                and noise density) and the positions are the plan `station record` makes from it
                (`station.protocols.planned.two_axis_plan`, at most `positions`), `axes` theirs
    units     : units on one plate (`station.sim.live.Plate`): the bench's unit and units - 1
                more, unit k drawn from the seed [seed, 3, k] (its own sensitivities, biases and
                noise) and fixed on the plate at `plate_mounting(k)`; the fixture mounts the
                plate, the suggested axes being directions in the plate frame = unit 1's; each
                unit streams on its own pty (serial), or all on the bench's one virtual CAN bus,
                unit k at id_offset PLATE_ID_STEP * k (can: in this process only)
    spikes    : the fault knob of spiky first attempts (`VirtualBench`, `station.sim.spikes`; one
                unit only: a plate's units stream unspiked)
    """

    def __init__(self, imu: str = "serial", seed: int = 1, speed: float | None = None,
                 positions: int = 20, rate_hz: float = 200.0, lifetime: float = 3600.0,
                 cube: bool = False, two_axis: bool = False, units: int = 1,
                 plan: bool = False, spikes=None):
        from station.twin.rotary_bench import VirtualBench

        if cube and two_axis:
            raise InputError("a two-axis table sets the unit's orientation itself: --cube and "
                             "--two-axis exclude each other")
        if plan and not two_axis:
            raise InputError("--plan plans the positions of a two-axis table: give --two-axis "
                             "(--cube plans a fixture's poses)")
        if units < 1 or (units > 1 and (cube or imu not in ("serial", "can"))):
            raise InputError(f"--units {units}: the twin serves 1 or more units, several on a "
                             "plate with serial or CAN links only (no --cube)")
        self.bench = VirtualBench(imu, seed=seed, speed=speed, rate_hz=rate_hz, remount_time=0.0,
                                  lifetime=lifetime, fixture=not two_axis, two_axis=two_axis,
                                  spikes=spikes)
        self.seed = seed
        self.positions = positions
        self.cube = _cube(self.bench.unit) if cube else None
        self.plan = _unit_plan(self.bench.unit) if plan else None
        if two_axis:
            self.axes = (position_axes(positions, 1) if self.plan is None else
                         two_axis_plan(self.plan, RotarySettings(), positions).axes())
            self.instructions = []
        elif self.cube is None:
            self.axes = suggested_axes(positions)
            self.instructions = [instruction(j, positions, u) for j, u in enumerate(self.axes)]
        else:
            steps = rotary_plan(self.cube, RotarySettings(), positions).instructions()
            self.instructions = [fixture_instruction(j, len(steps), s)
                                 for j, s in enumerate(steps)]
            self.axes = np.array([i.orientation[:, 2] for i in self.instructions])
        self.mounted = []  # the positions mounted, 1-based, in order
        self.plate = _plate(self.bench, units) if units > 1 else None
        self.error = self.on_error = None  # the fixture thread's (drivers.twins.failure)
        self.failures.watch(self, "fixture")
        self.clock_server = None  # serves the lockstep clock (speed None) to `station record`
        self._streams = []  # [PortWatch or None, SerialTwin] of each unit: started when the port
        # opens (lockstep time: at once, time moving only while a station takes part)
        self._can_units = []  # the CanImuTwin of each unit of a CAN plate
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._fixture, name="fixture", daemon=True)

    def start(self) -> Self:
        """Serve the table; the serial IMU streams from the moment the station opens its port
        (a twin streaming to nobody would hand the station a stale backlog, computed late)."""
        from drivers.twins.serial import SerialTwin

        b = self.bench
        if not b.clock.realtime:
            from drivers.clock_link import ClockServer

            self.clock_server = ClockServer(b.clock)
        if b.fixture is not None:
            self._mount(1)
            if not b.clock.realtime:
                b.fixture.on_request = self._mount_at_once
        if b.kind == "serial":
            b.table_twin.start()
            sources = [b.streamed()] if self.plate is None else self.plate.units
            twins = [SerialTwin(b.profile, source, b.clock, max_lag=np.inf,
                                unread_after=UNREAD_AFTER) for source in sources]
            for k, twin in enumerate(twins):
                b.failures.watch(twin, _imu_name("serial", k, twins))
            b.imu_twin = twins[0]
            if b.clock.realtime:
                self._streams = [[PortWatch(twin.port), twin] for twin in twins]
            else:
                self._streams = [[None, twin.start(b.clock_start)] for twin in twins]
        elif self.plate is not None:
            self._start_can_plate()
        else:
            b.start()
        b.clock.enlist(self._thread, producer=True)
        self._thread.start()
        return self

    def _start_can_plate(self) -> None:
        """Every unit of the plate streaming on the bench's virtual CAN bus, unit k's frames at
        id_offset PLATE_ID_STEP * k (`drivers.can_imu.CanSection`)."""
        from drivers.twins.can import CanImuTwin

        b = self.bench
        b.table_twin.start()
        for k, source in enumerate(self.plate.units):
            twin = CanImuTwin(b.can_channel, plate_can_profile(b.profile, k), source, b.clock)
            b.failures.watch(twin, _imu_name("CAN", k, self.plate.units))
            self._can_units.append(twin.start(b.clock_start))
        b.imu_twin = self._can_units[0]

    def close(self) -> None:
        self._stop.set()
        self.bench.clock.nudge()
        if self._thread.is_alive():
            self._thread.join()
        for watch, twin in self._streams:
            if watch is not None:
                watch.close()
            if twin is not self.bench.imu_twin:
                twin.stop()
        for twin in self._can_units[1:]:
            twin.stop()
        self.bench.close()
        if self.clock_server is not None:
            self.clock_server.close()

    def addresses(self) -> dict:
        """Where the station finds the devices."""
        b = self.bench
        imu = {"link": "serial", "port": b.imu_twin.port} if b.kind == "serial" else \
            {"link": "can", "interface": "virtual", "channel": b.can_channel}
        served = {"profile": b.profile.source, "rate_hz": b.profile.imu.rate_hz}
        units = {} if self.plate is None else {"units": [
            {"link": "serial", "port": twin.port, **served} for _, twin in self._streams] or [
            {**imu, "id_offset": PLATE_ID_STEP * k, **served} for k in range(len(self._can_units))]}
        return {"imu": {**imu, **served},
                "table": {"host": "127.0.0.1", "port": b.table_twin.port,
                          "profile": "table_two_axis" if b.two_axis else "table_fixture",
                          **({} if b.table_reply is None else {"reply_timeout": b.table_reply})},
                **_clock_address(b.clock, self.clock_server), **units}

    def toggle(self, device: str) -> bool:
        """Lose `device` ("imu": unplugged, "table": silent) if it is there, else bring it back;
        True when it is now lost."""
        b = self.bench
        if device == "table":
            b.table_twin.silent = not b.table_twin.silent
            return b.table_twin.silent
        twins = {unit_stream(k): twin for k, (_, twin) in enumerate(self._streams)}
        if device != "imu" and device not in twins:
            raise InputError(f"the bench has no device {device!r}; it has the table and "
                             f"{sorted(twins) or ['imu']}")
        return _toggle_imu(twins.get(device, b.imu_twin))

    def profile_text(self, unit_serial: str | None = None) -> str:
        """A bench profile (`station record --profile`) pointing at these devices."""
        a = self.addresses()
        serial = unit_serial or f"SIM-{self.seed}"
        imu = "[imu]\n" + "\n".join(f"{k} = {_toml(v)}" for k, v in a["imu"].items())
        if self.plate is not None:
            imu = "\n\n".join(
                "[[imu]]\n" + "\n".join(f"{k} = {_toml(v)}" for k, v in unit.items())
                + f"\nunit_serial = {_toml(plate_serial(serial, k))}\n"
                f"mounting = {json.dumps(np.round(mounting, 15).tolist())}"
                for k, (unit, mounting) in enumerate(zip(a["units"], self.plate.mountings,
                                                         strict=True)))
        table = "\n".join(f"{k} = {_toml(v)}" for k, v in a["table"].items())
        from station.twin.rotary_bench import MARGINS

        margins = self.bench.with_margins(RotarySettings())  # waits the fast clock multiplies
        return (f"# Bench profile of the virtual bench (station twin), written {time.ctime()}.\n"
                f"[bench]\nunit_serial = {_toml(serial)}\n{_clock_line(a)}\n\n"
                f"{imu}\n\n[table]\n{table}\n\n"
                f"[protocol]\npositions = {self.positions}\n"
                + "".join(f"{k} = {getattr(margins, k)!r}\n" for k in MARGINS)
                + _planning_section("fixture", self.cube)
                + _planning_section("plan", self.plan)
                + _tolerances_section(GYRO_TOLERANCES))

    def truth(self) -> dict:
        """The simulated unit and the mountings made (JSON-ready)."""
        t = self.bench.truth()
        axes = {"axes": self.axes.tolist()} if self.bench.two_axis else {}
        units = {} if self.plate is None else {"units": [
            {"stream": unit_stream(k), "a": unit.unit.a.tolist(), "bias": unit.unit.bias.tolist(),
             "mounting": mounting.tolist(),
             "orientations": (mounting @ t.orientations).tolist(),
             **({"axes": (self.axes @ mounting.T).tolist()} if self.bench.two_axis else {})}
            for k, (unit, mounting) in enumerate(zip(self.plate.units, self.plate.mountings,
                                                     strict=True))]}
        return {"a": t.a.tolist(), "bias": t.bias.tolist(), "a_nominal": t.a_nominal.tolist(),
                "orientations": t.orientations.tolist(), "mounted": self.mounted, **axes,
                **units}

    def _mount(self, position: int) -> None:
        """Mount the unit in `position` (1-based; beyond the plan: the plan's position modulo
        its length) and report it held. The fixture is repeatable: its placement error belongs
        to the fixture position (drawn from the seed and the position), so a position mounted
        again has the orientation it had the first time."""
        j = (position - 1) % len(self.instructions)
        self.bench.technician.rng = np.random.default_rng([self.seed, 2, j])
        self.bench.technician.wait(self.instructions[j])
        self.mounted.append(position)
        self.bench.fixture.done(position)

    def _mount_at_once(self, position: int) -> None:
        """`_mount` inside the station's request (lockstep time); a failure kept in `error`."""
        try:
            self._mount(position)
        except Exception as exc:  # noqa: BLE001 - reported by the command
            self.error = exc

    def _fixture(self) -> None:
        """Start the serial stream when the station opens the port; mount the unit in each
        position the station asks for."""
        try:
            while not self._stop.is_set():
                self.bench.clock.idle(0.002, self._stop)  # lockstep: until a move or a command
                for watch, twin in self._streams:
                    if watch is not None and watch.opened():
                        twin.start()
                if self.bench.fixture is not None and \
                        (position := self.bench.fixture.pending()) is not None:
                    self._mount(position)
        except Exception as exc:  # noqa: BLE001 - told at once: the table's controller dies
            fail(self, exc, self.bench.table_twin.die)


def plate_mounting(k: int) -> np.ndarray:
    """The twin's mounting of unit k (0-based) on the plate, plate frame -> unit frame: unit 0
    square to the plate, unit k turned 110k degrees about (1, 2, 2) / 3 (a generic rotation: each
    unit sees every position's axis in another direction of its frame)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.radians(110.0 * k) * np.array([1.0, 2.0, 2.0]) / 3.0
                                ).as_matrix()


PLATE_ID_STEP = 0x10
"""The id offset between two units of the twin's CAN plate (the example DBC's ids 0x180-0x182)."""


def plate_can_profile(profile, k: int):
    """The CAN device profile of unit k (0-based) of the twin's plate: id_offset PLATE_ID_STEP k."""
    return dataclasses.replace(profile, can=dataclasses.replace(profile.can,
                                                                id_offset=PLATE_ID_STEP * k))


def plate_serial(serial: str, k: int) -> str:
    """The serial the twin's profile gives unit k (0-based) of the plate `serial`."""
    return f"{serial}-U{k + 1}"


def _plate(bench, units: int):
    """The bench's unit and units - 1 more (seeds [seed, 3, k]) on one `Plate`, which the
    technician (the fixture), or a two-axis table's position axis, now moves; on a two-axis
    table each unit also turns about the position axis, in its frame its mounting times unit
    0's."""
    from station.sim.layouts import gyro_array
    from station.sim.live import MountedUnit, Plate

    mountings = [plate_mounting(k) for k in range(units)]
    inner = bench.mounted.inner
    extra = [MountedUnit(gyro_array(np.random.default_rng([bench.seed, 3, k]), fs=bench.rate_hz,
                                    counts_per_unit=bench.profile.imu.scale), bench.table,
                         orientation=mountings[k] @ bench.mounted.orientation,
                         inner=None if inner is None else (inner[0], mountings[k] @ inner[1]))
             for k in range(1, units)]
    plate = Plate([bench.mounted, *extra], mountings)
    bench.technician.mounted = plate
    return plate


def _unit_plan(unit) -> PlanSpec:
    """What the planner needs of the twin's unit: its nominal layout and noise density."""
    from station.sim.layouts import A_MODEL

    return PlanSpec(A_MODEL, float(np.max(unit.noise_density)))


def _cube(unit) -> FixtureSpec:
    """The twin's fixture: a lettered cube holding the unit square, on a 45-degree wedge; the
    plan's layout and noise are the unit's nominal ones (`_unit_plan`)."""
    plan = _unit_plan(unit)
    return FixtureSpec(Fixture(wedge=True), plan.layout, plan.noise_density)


def _planning_section(name: str, spec, layout: bool = True) -> str:
    """The [fixture] or [plan] section of a bench profile from a FixtureSpec or PlanSpec ("" for
    None); layout False: without the layout (a static profile gives it in [protocol])."""
    if spec is None:
        return ""
    lines = [f"{k} = {json.dumps(v) if isinstance(v, bool | list) else _toml(v)}"
             for k, v in spec.table().items() if layout or k != "layout"]
    return f"\n[{name}]\n" + "\n".join(lines) + "\n"


def _tolerances_section(table: dict) -> str:
    """The [tolerances] section of a bench profile: the simulated unit type's limits, so that
    `station record --solve` on a twin gives a PASS/FAIL verdict (station.solve.verdict)."""
    return "\n[tolerances]\n" + "".join(f"{k} = {_toml(v)}\n" for k, v in table.items())


class HandTwin(Served):
    """A `station.twin.hand_bench.HandBench` whose technician follows the protocol on a metronome.

    protocol  : "static" (a triad turned by hand through the first `poses` guided poses, 5 deg
                off each) or "iron" (the ACC4 unit in an iron square to 0.0002 deg, `mountings`
                re-mountings, each followed by the six faces)
    speed     : a real-time clock that many times faster than the wall; None (the default):
                lockstep time, served to `station record` (`drivers.clock_link`)
    period    : clock seconds between the technician's turns; each turn starts on a multiple of
                it, and the first after the station opened the port (lockstep: at clock 0, time
                standing still until the station takes part). The technician does not hear the
                station: on a real-time clock `station record` must keep up (a pose takes it
                about `hold` + 3 s), and then records the turns in order.
    cube      : static: the triad sits in a lettered cube set on the table or a 45-degree wedge
                (`station.model.fixture`, 1 deg off each pose); the bench profile gets its
                [fixture] section and the technician sets the poses `station record` plans
                from it (`station.protocols.planned.static_plan`), in order
    link      : "serial" (binary frames on a pty) or "mavlink" (a flight controller's SCALED_IMU
                on a pty, or with `udp` over UDP to 127.0.0.1; the triad of the static bench
                only): the technician's first turn is then timed from the station's stream
                request instead of its opening the port
    """

    def __init__(self, protocol: str = "static", seed: int = 1, speed: float | None = None,
                 poses: int = 18, mountings: int = 2, rate_hz: float = 200.0,
                 period: float = 20.0, cube: bool = False, link: str = "serial",
                 udp: bool = False):
        from station.twin.hand_bench import ACC4, TRIAD, HandBench

        static = protocol == "static"
        self.protocol, self.seed = protocol, seed
        if udp and link != "mavlink":
            raise InputError("--udp serves the MAVLink link (--link mavlink)")
        if udp:
            from drivers.twins.mavlink import free_udp_port
        self.bench = HandBench(seed, speed, rate_hz, layout=TRIAD if static else ACC4,
                               mountings=[np.eye(3)] if static else mountings, period=period,
                               placement_deg=(1.0 if cube else 5.0) if static else 0.0002,
                               link=link, udp_port=free_udp_port() if udp else None)
        self.cube = FixtureSpec(Fixture(wedge=True), TRIAD, float(
            np.max(self.bench.unit.noise_density))) if cube and static else None
        if self.cube is None:
            self.instructions = _hand_instructions(protocol, poses, mountings)
        else:
            from station.acquire.operator import Instruction
            from station.protocols.rotary import mounting
            from station.protocols.static import StaticSettings

            guided = static_plan(self.cube, StaticSettings(gravity=self.bench.gravity)).guided()
            self.instructions = [Instruction(words, mounting(up)) for _, up, words in guided]
            poses = len(guided)
        self.settings = {"poses": poses} if static else {"mountings": mountings}
        self.turns = 0
        self.error = self.on_error = None  # the technician thread's (drivers.twins.failure)
        self.failures.watch(self, "technician")
        self.clock_server = None  # serves the lockstep clock (speed None) to `station record`
        self._watch = None
        self._stop = threading.Event()
        self.bench.technician.stop = self._stop
        self._thread = threading.Thread(target=self._fixture, name="fixture", daemon=True)

    def start(self) -> Self:
        """Serve the serial IMU from the moment the station opens its port (MAVLink: the
        heartbeat at once, the IMU when the station asks for it)."""
        from drivers.twins.serial import SerialTwin

        b = self.bench
        if not b.clock.realtime:
            from drivers.clock_link import ClockServer

            self.clock_server = ClockServer(b.clock)
        if b.link == "mavlink":
            b.start(unread_after=UNREAD_AFTER)
        else:
            b.twin = b.failures.watch(SerialTwin(b.profile, b.rig, b.clock, max_lag=np.inf,
                                                 unread_after=UNREAD_AFTER), "serial IMU")
            if b.clock.realtime:
                self._watch = PortWatch(b.twin.port)
            else:  # lockstep: time stands still until the station takes part
                b.twin.start(0.0)
        b.clock.enlist(self._thread, producer=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self.bench.clock.nudge()
        self._thread.join(timeout=5.0)  # a turn being waited for ends within a period
        if self._watch is not None:
            self._watch.close()
        self.bench.close()
        if self.clock_server is not None:
            self.clock_server.close()

    def profile_text(self, unit_serial: str | None = None) -> str:
        """A bench profile (`station record --profile`) for this protocol and device."""
        b = self.bench
        imu = {"link": b.link, "profile": Path(b.profile.source).stem, "port": b.twin.port,
               "rate_hz": b.profile.imu.rate_hz}
        protocol = {"kind": self.protocol, "gravity": b.gravity, **self.settings}
        lines = [f"{k} = {_toml(v)}" for k, v in protocol.items()]
        if self.protocol == "iron":
            lines.append(f"layout = {json.dumps(b.layout.tolist())}")
        return (f"# Bench profile of the virtual hand bench (station twin), written "
                f"{time.ctime()}.\n[bench]\n"
                f"unit_serial = {_toml(unit_serial or f'SIM-{self.seed}')}"
                f"\n{_clock_line(_clock_address(b.clock, self.clock_server))}\n\n[imu]\n"
                + "\n".join(f"{k} = {_toml(v)}" for k, v in imu.items())
                + "\n\n[protocol]\n" + "\n".join(lines) + "\n"
                + _planning_section("fixture", self.cube, layout=False)
                + _tolerances_section(ACCELEROMETER_TOLERANCES))

    def toggle(self, device: str) -> bool:
        """Unplug the IMU (`device` "imu", the only one) if it is there, else plug it back; True
        when it is now lost."""
        if device != "imu":
            raise InputError(f"the hand bench has no {device}; it has an IMU only")
        return _toggle_imu(self.bench.twin)

    def addresses(self) -> dict:
        b = self.bench
        return {"imu": {"link": b.link, "port": b.twin.port, "rate_hz": b.profile.imu.rate_hz},
                **_clock_address(b.clock, self.clock_server)}

    def truth(self) -> dict:
        """The simulated unit, its gyro triad (MAVLink) and the up direction after each turn
        (JSON-ready)."""
        t, gyro = self.bench.truth(), self.bench.gyro
        return {"a": t.a.tolist(), "bias": t.bias.tolist(), "a_nominal": t.a_nominal.tolist(),
                "gravity": t.gravity, "up": t.up.tolist(), "turns": self.turns,
                **({"gyro": {"a": gyro.a.tolist(), "bias": gyro.bias.tolist()}} if gyro else {})}

    def _mount_at_once(self, position: int) -> None:
        """`_mount` inside the station's request (lockstep time); a failure kept in `error`."""
        try:
            self._mount(position)
        except Exception as exc:  # noqa: BLE001 - reported by the command
            self.error = exc

    def _streaming(self) -> bool:
        """Does the IMU stream? MAVLink: once the station asked for it; serial: once the station
        opened the port (lockstep time: from the start, time standing still until then)."""
        if self.bench.link == "mavlink":
            return self.bench.twin.streaming.is_set()
        return self._watch is None or self._watch.opened()

    def _fixture(self) -> None:
        """Start the stream when the station opens the port (MAVLink: wait for its stream
        request), then turn as instructed, in order."""
        try:
            while not self._streaming():
                if self._stop.wait(0.002):
                    return
            if self._watch is not None:
                self.bench.twin.start()
            for instruction in self.instructions:
                if self._stop.is_set():
                    return
                self.bench.technician.wait(instruction)
                self.turns += 1
        except Exception as exc:  # noqa: BLE001 - told at once: the IMU is unplugged
            fail(self, exc, self.bench.twin.unplug)


def _imu_name(link: str, k: int, units: list) -> str:
    """The words naming unit k's IMU twin (0-based) of `units` on the bench."""
    return f"{link} IMU" + (f" of unit {k + 1}" if len(units) > 1 else "")


def _toggle_imu(twin) -> bool:
    """Unplug the IMU twin (serial or MAVLink) if it is plugged, else plug it; True when now
    unplugged."""
    if twin.plugged:
        twin.unplug()
        return True
    twin.plug()
    return False


def _hand_instructions(protocol: str, poses: int, mountings: int) -> list:
    """What the hand bench's technician does, in order (as the protocol would ask)."""
    from station.acquire.operator import Instruction
    from station.protocols.iron import FACE_UP
    from station.protocols.rotary import mounting
    from station.protocols.static import GUIDED_POSES

    if protocol == "static":
        return [Instruction(words, mounting(up)) for _, up, words in GUIDED_POSES[:poses]]
    faces = [Instruction(f"face {f}", mounting(FACE_UP[f])) for f in FACE_UP]
    return [item for _ in range(mountings) for item in (Instruction("re-mount"), *faces)]


def rotary_twin(options) -> BenchTwin:
    """`station twin --protocol rotary`: a serial `BenchTwin` (options: seed, speed, positions,
    rate_hz, lifetime, cube, two_axis, units, plan, spikes)."""
    if getattr(options, "link", "serial") != "serial":
        raise InputError("the rotary bench's IMU streams over the serial link only (--link "
                         "mavlink serves the static bench)")
    return BenchTwin("serial", options.seed, options.speed, options.positions, options.rate_hz,
                     options.lifetime, getattr(options, "cube", False),
                     getattr(options, "two_axis", False), getattr(options, "units", 1),
                     getattr(options, "plan", False), getattr(options, "spikes", None))


def iron_twin(options) -> HandTwin:
    """`station twin --protocol iron`: the ACC4 unit in an iron (options: seed, speed, positions,
    mountings, rate_hz)."""
    if getattr(options, "link", "serial") != "serial":
        raise InputError("the iron bench's unit has 4 accelerometers: it streams over the serial "
                         "link only (--link mavlink serves the static bench's triad)")
    return HandTwin("iron", options.seed, options.speed, options.positions, options.mountings,
                    options.rate_hz)


def static_twin(options) -> HandTwin:
    """`station twin --protocol static`: a triad turned through `options.positions` (12 to 26)
    guided poses, or with `options.cube` the planned poses of a lettered cube; ValueError outside
    that range."""
    if not 12 <= options.positions <= 26:
        raise InputError("a static session has 12 to 26 poses (--positions)")
    return HandTwin("static", options.seed, options.speed, options.positions, options.mountings,
                    options.rate_hz, cube=getattr(options, "cube", False),
                    link=getattr(options, "link", "serial"), udp=getattr(options, "udp", False))


def _toml(value) -> str:
    """A TOML scalar (strings JSON-quoted: a valid TOML basic string)."""
    if isinstance(value, str):
        return json.dumps(value)
    return repr(float(value)) if isinstance(value, float) else repr(int(value))
