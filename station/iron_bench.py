"""The virtual right-angle-iron bench: a 4-accelerometer unit in an iron, turned by a technician,
streaming through the real serial wire protocol.

    with IronBench(seed=1, speed=40) as bench, bench.driver() as imu:
        ...  # imu: drivers.serial_imu.SerialImu on the twin's pseudo-terminal
        bench.technician  # IronTechnician: turns the iron from face to face, re-mounts the unit
        bench.truth()     # what the station should find

One `ScaledClock` drives everything. The unit (`ACC4`: three orthogonal accelerometers and one skew
one, `station.sim.layouts.accelerometer_triad` noise, biases and quantisation) sits in an `IronRig`:
the unit is fixed in the iron in a mounting B (iron frame -> unit frame), the iron stands on one
of its faces, and every change of face or mounting is a smooth turn of `turn_time` seconds (a
raised-cosine slerp), so the station sees real motion between the still poses. The rig is the
`source(times)` of `drivers.twin_serial.SerialTwin`; the profile is the bundled binary serial
profile with an `[imu]` section for the four accelerometers.

The iron is square to `squareness_deg` (default 0.0002 deg, 0.7 arc second): Hwangbo & Kanade's
constraints (same face 1, perpendicular 0, opposite -1) hold only as well as the iron is square, and
an error of e rad acts like a reading error of about g e. A 5 s mean of this unit has a standard
error of 4.4e-4 m/s^2 = g x 4.5e-5: at 0.002 deg (3.5e-5 rad) the chi2 per degree of freedom rose
to 1.3 and gains moved by up to 3.8 sigma in simulation, so the simulated iron is ten times better.
"""

import contextlib
import dataclasses
from dataclasses import dataclass
from typing import Self

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from drivers.profile import ImuSection, SerialImuProfile
from drivers.serial_imu import SerialImu
from drivers.twin_serial import SerialTwin
from station.clock import ScaledClock
from station.operator import SimulatedTechnician
from station.session import StreamSpec
from station.sim.earth import normal_gravity
from station.sim.layouts import accelerometer_triad

ACC4 = np.column_stack([np.eye(3), np.ones(3) / np.sqrt(3)])
"""Nominal layout of the iron bench's unit: an orthogonal triad and one skew accelerometer."""

G0 = 9.80665


def acc4_profile(rate_hz: float) -> SerialImuProfile:
    """The bundled binary serial profile carrying four accelerometer channels (4096 counts per g)."""
    base = SerialImuProfile.load("imu12_serial")
    imu = ImuSection("acc4-serial", ("a1", "a2", "a3", "a4"), ("m/s^2",) * 4, (4096 / G0,) * 4,
                     float(rate_hz))
    return dataclasses.replace(base, imu=imu)


class IronRig:
    """A sensor unit fixed in a right-angle iron: `times -> counts (k, m)` for the serial twin.

    `orientation` (set by the technician) is the iron's attitude, world -> iron frame: its third
    column is the iron-frame direction pointing up. `remount(b)` fixes the unit anew (b: iron ->
    unit frame). Each change starts a turn now, lasting `turn_time` clock seconds; the stimulus is
    the specific force g C(t) e_z in the unit frame, C = b W the world -> unit attitude.
    """

    def __init__(self, unit, clock, gravity: float, turn_time: float = 2.0):
        self.next_turn = None  # clock time the next turn starts at (None: when it is asked for)
        self.unit = unit
        self.clock = clock
        self.gravity = float(gravity)
        self.turn_time = float(turn_time)
        self.mounting = np.eye(3)
        self._iron = np.eye(3)
        self._turns = [(-np.inf, Rotation.identity(), Rotation.identity())]  # (start, from, to)
        self.poses = []  # world -> unit attitude after each turn the technician made
        self.pose_mounting = []

    @property
    def orientation(self) -> np.ndarray:
        return self._iron

    @orientation.setter
    def orientation(self, iron) -> None:
        self._iron = np.asarray(iron, float)
        self._turn()

    def remount(self, mounting) -> None:
        """Take the unit out and fix it in the iron as `mounting` (iron -> unit frame)."""
        self.mounting = np.asarray(mounting, float)
        self._turn()

    def attitude(self, times) -> np.ndarray:
        """(k, 3, 3) world -> unit attitude at `times` (clock seconds)."""
        times = np.atleast_1d(np.asarray(times, float))
        starts = np.array([t for t, _, _ in self._turns])
        out = np.empty((times.size, 3, 3))
        which = np.searchsorted(starts, times, side="right") - 1
        for i in np.unique(which):
            start, a, b = self._turns[i]
            x = np.clip((times[which == i] - start) / self.turn_time, 0.0, 1.0)
            s = 0.5 * (1 - np.cos(np.pi * x))
            out[which == i] = Slerp([0.0, 1.0], Rotation.concatenate([a, b]))(s).as_matrix()
        return out

    def __call__(self, times) -> np.ndarray:
        times = np.atleast_1d(np.asarray(times, float))
        v = self.gravity * self.attitude(times)[:, :, 2]
        return self.unit.sample(v, times)

    def _turn(self) -> None:
        start = max(self.clock.now(), self.next_turn or -np.inf)
        target = self.mounting @ self._iron
        current = Rotation.from_matrix(self.attitude(start)[0])
        self._turns.append((start, current, Rotation.from_matrix(target)))
        self.poses.append(target)


class IronTechnician(SimulatedTechnician):
    """The iron bench's technician: `SimulatedTechnician` turning an `IronRig`.

    An instruction with an orientation (the iron's attitude, world -> iron) stands the iron on a
    face, with the iron's squareness error; one without an orientation is a re-mounting of the unit
    in the iron (the iron protocol's only such instruction): the next of `mountings`.

    With a `period`, the technician works to a metronome: each turn starts at the first multiple of
    `period` clock seconds at least `handling_time` after the request (the answer comes two
    seconds before it). The recording then does not depend on when a loaded host got round to each
    step (unless it is late by more than the slack), and a seeded session replays the same samples.
    """

    def __init__(self, rig: IronRig, clock, mountings, handling_time: float = 3.0,
                 squareness_deg: float = 0.0002, rng=None, period: float | None = None):
        super().__init__(rig, clock, 0.0, squareness_deg, rng)
        self.mountings = np.asarray(mountings, float)
        self.handling_time = float(handling_time)
        self.period = period
        self.remounts = 0

    def wait(self, instruction) -> None:
        start = self.clock.now() + self.handling_time
        if self.period:
            start = self.period * np.ceil(start / self.period)
        self.clock.sleep(start - 2.0 - self.clock.now())
        self.mounted.next_turn = start
        if instruction.orientation is not None:
            super().wait(instruction)
            return
        self.prompt(instruction.text)
        self.mounted.remount(self.mountings[self.remounts % len(self.mountings)])
        self.remounts += 1


@dataclass(frozen=True)
class IronTruth:
    """What the simulated unit is and the stimuli it felt.

    a (3, m) true sensitivity (dimensionless, SI readings); bias (m,) m/s^2; gravity m/s^2;
    up (P, 3) the up direction in the unit frame after each turn (faces and re-mountings);
    a_nominal (3, m).
    """

    a: np.ndarray
    bias: np.ndarray
    gravity: float
    up: np.ndarray
    a_nominal: np.ndarray


class IronBench:
    """Starts the simulated iron bench; `close()` (or leaving the `with`) stops it.

    seed          : seed of the unit, the mountings and the technician
    speed         : clock speed, simulated seconds per wall second
    rate_hz       : IMU sample rate
    mountings     : (K, 3, 3) iron -> unit rotations used in turn, or a count of random ones
    handling_time : simulated seconds the technician takes before each turn
    period        : the technician's metronome (see IronTechnician), None: none
    turn_time     : seconds each turn of the iron lasts
    squareness_deg: the iron's squareness error (standard deviation per axis), degrees
    latitude_deg  : site latitude (normal gravity)
    """

    def __init__(self, seed: int = 1, speed: float = 40.0, rate_hz: float = 200.0, mountings=3,
                 handling_time: float = 3.0, period: float | None = None, turn_time: float = 2.0,
                 squareness_deg: float = 0.0002, latitude_deg: float = 52.2):
        rng = np.random.default_rng(seed)
        self.clock = ScaledClock(speed)
        self.profile = acc4_profile(rate_hz)
        self.stream_spec = StreamSpec.from_profile(self.profile.imu)
        self.gravity = normal_gravity(latitude_deg)
        self.unit = accelerometer_triad(rng, ACC4, fs=rate_hz,
                                        counts_per_unit=self.profile.imu.scale)
        if np.ndim(mountings) == 0:
            mountings = Rotation.random(int(mountings), random_state=rng).as_matrix()
        self.rig = IronRig(self.unit, self.clock, self.gravity, turn_time)
        self.technician = IronTechnician(self.rig, self.clock, mountings, handling_time,
                                         squareness_deg, np.random.default_rng([seed, 1]), period)
        self.twin = None

    def start(self) -> Self:
        """Start the IMU stream."""
        # frame n is sampled at clock n / rate_hz: with the technician's metronome, the same
        # samples whatever the host's load (frames before the driver opens the port are lost)
        self.twin = SerialTwin(self.profile, self.rig, self.clock, max_lag=np.inf).start(0.0)
        return self

    def close(self) -> None:
        """Stop the IMU stream (idempotent)."""
        if self.twin is not None:
            twin, self.twin = self.twin, None
            twin.stop()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    @contextlib.contextmanager
    def driver(self):
        """The station's real serial driver on the twin's port, closed on exit."""
        with SerialImu(self.twin.port, self.profile, self.clock) as imu:
            yield imu

    def truth(self) -> IronTruth:
        """The true unit and the up direction (unit frame) after each turn so far."""
        up = np.array([c[:, 2] for c in self.rig.poses]).reshape(-1, 3)
        return IronTruth(self.unit.a.copy(), self.unit.bias.copy(), self.gravity, up, ACC4)


def record_session(path, seed: int = 1, speed: float = 40.0, mountings: int = 2,
                   rate_hz: float = 200.0, settings=None, unit_serial: str | None = None,
                   period: float | None = 20.0):
    """Record an iron session on a new bench into `path` (a new .h5), solve it and keep the result
    as `results/live`; returns (IronTruth, IronReadings, CalibrationResult)."""
    from station.protocols.iron import (
        IronProtocol,
        IronSettings,
        StreamTap,
        calibrate_iron,
        iron_readings,
    )
    from station.recorder import Recorder
    from station.session import Session, SessionWriter, write_results

    with IronBench(seed=seed, speed=speed, rate_hz=rate_hz, period=period) as bench, \
            bench.driver() as imu:
        settings = settings or IronSettings(gravity=bench.gravity, mountings=mountings)
        protocol = IronProtocol(bench.technician, bench.clock, ACC4, settings)
        tap = StreamTap(imu, bench.stream_spec.rate_hz, bench.stream_spec.counts_per_unit)
        metadata = {**protocol.metadata(), "unit_serial": unit_serial or f"SIM-ACC4-{seed}",
                    "bench": {"kind": "iron", "seed": seed, "speed": speed}}
        writer = SessionWriter.create(path, metadata, {"imu": bench.stream_spec},
                                      clock=bench.clock)
        with writer, Recorder(writer, tap, clock=bench.clock) as recorder:
            protocol.run(recorder, tap)
        truth = bench.truth()
    with Session.open(path) as session:
        readings = iron_readings(session)
    result = calibrate_iron(readings, settings.gravity, nominal=ACC4)
    write_results(path, "live", "imu", readings.M, result, readings.sigma)
    return truth, readings, result
