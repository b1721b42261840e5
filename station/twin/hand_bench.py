"""The virtual hand bench: an accelerometer unit turned by a technician - in a right-angle iron,
or freely - streaming through the real serial wire protocol.

    with HandBench(seed=1) as bench, bench.driver() as imu:
        ...  # imu: a drivers.ImuDriver (serial) on the twin's pseudo-terminal
        bench.technician  # HandTechnician: turns the unit (or its iron), re-mounts it in the iron
        bench.truth()     # what the station should find

One clock drives everything: lockstep time by default (`drivers.clock.SteppedClock`: the same
samples on any host), a `ScaledClock` with `speed` (for what must meet the wall clock). The unit (by
default `ACC4`: three orthogonal accelerometers and one skew one; `TRIAD` for a plain triad;
`station.sim.layouts.accelerometer_triad` noise, biases and quantisation) sits in a `HandRig`: the
unit is fixed in a mounting B (iron frame -> unit frame; the identity for free poses), the iron (or
the unit itself) is turned to an attitude, and every change of attitude or mounting is a smooth turn
of `turn_time` seconds (a raised-cosine slerp), so the station sees real motion between the still
poses. The rig is the `source(times)` of `drivers.twins.serial.SerialTwin`; the profile is the
bundled binary serial profile with an `[imu]` section for the accelerometers. With `link="mavlink"`
a triad streams through `drivers.twins.mavlink.MavlinkTwin` instead (a flight controller's
SCALED_IMU, profile `imu6_scaled_mavlink`, on a pty or over UDP), with a gyro triad beside it that
senses the turns (`HandRig.rates`), read by the station's MAVLink driver.

Each turn misses its target by a random rotation of `placement_deg` per axis (standard deviation).
In an iron that is the iron's squareness (default 0.0002 deg, 0.7 arc second): Hwangbo & Kanade's
constraints (same face 1, perpendicular 0, opposite -1) hold only as well as the iron is square, and
an error of e rad acts like a reading error of about g e. A 5 s mean of this unit has a standard
error of 4.4e-4 m/s^2 = g x 4.5e-5: at 0.002 deg (3.5e-5 rad) the chi2 per degree of freedom rose
to 1.3 and gains moved by up to 3.8 sigma in simulation, so the simulated iron is ten times better.
Free poses (`record_static_session`) only need to be different: there the hand errs by 5 deg.
"""

import contextlib
import dataclasses
from dataclasses import dataclass
from typing import Self

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from drivers import open_imu
from drivers.clock import ScaledClock, SteppedClock
from drivers.profile import SerialImuProfile
from drivers.twins.failure import Failures
from drivers.twins.serial import SerialTwin
from station.acquire.operator import SimulatedTechnician
from station.errors import InputError
from station.model import sensing
from station.model.earth import normal_gravity
from station.model.effects import from_json
from station.protocols.still import record_poses
from station.session import Session, StreamSpec, write_results
from station.sim.layouts import accelerometer_triad, gyro_array
from station.solve.still import calibrate_still

ACC4 = np.column_stack([np.eye(3), np.ones(3) / np.sqrt(3)])
"""Nominal layout of the bench's default unit: an orthogonal triad and one skew accelerometer."""

TRIAD = np.eye(3)
"""Nominal layout of a plain accelerometer triad."""


LINKS = ("serial", "mavlink")
"""How the hand bench's unit streams: binary serial frames, or MAVLink (a flight controller)."""


def accel_profile(m: int, rate_hz: float, link: str = "serial"):
    """The bundled profile of the unit at `rate_hz`: serial `acc<m>_serial` (m = 3 or 4
    accelerometers, 4096 counts per g) or MAVLink `imu6_scaled_mavlink` (a flight controller's
    accelerometer and gyro triads in SCALED_IMU, 1000 counts per g and per rad/s); InputError for
    a MAVLink unit of another m."""
    if link == "mavlink":
        from drivers.mavlink_imu import MavlinkProfile

        if m != 3:
            raise InputError(f"a MAVLink IMU message carries one accelerometer triad; this unit "
                             f"has {m} accelerometers: use the serial link")
        base = MavlinkProfile.load("imu6_scaled_mavlink")
    else:
        base = SerialImuProfile.load(f"acc{m}_serial")
    return dataclasses.replace(base, imu=dataclasses.replace(base.imu, rate_hz=float(rate_hz)))


class HandRig:
    """A sensor unit in the technician's hands: `times -> counts (k, m)` for the serial twin.

    `orientation` (set by the technician) is the iron's attitude, world -> iron frame: its third
    column is the iron-frame direction pointing up (without an iron: the unit's attitude, mounting
    the identity). `remount(b)` fixes the unit anew in the iron (b: iron -> unit frame). Each change
    starts a turn now, lasting `turn_time` clock seconds; the stimulus is the specific force g C(t)
    e_z in the unit frame, C = b W the world -> unit attitude. `effects` {name: parameters}: named
    sensor effects (station.model.sensing.LIVE_EFFECTS) in the unit's output chain. `gyro`: a gyro
    triad (a SensorUnit in rad/s) fixed to the unit, whose counts follow the accelerometers' on
    each row, sensing `rates`.
    """

    def __init__(self, unit, clock, gravity: float, turn_time: float = 2.0, effects=None,
                 gyro=None):
        self.next_turn = None  # clock time the next turn starts at (None: when it is asked for)
        self.unit, self.gyro = unit, gyro
        self.effects = dict(effects or {})
        sensing.refuse_batch_effects(self.effects)
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

    def rates(self, times) -> np.ndarray:
        """(k, 3) angular rate of the unit in its own frame at `times`, rad/s. A turn from A to
        B is C(t) = A exp(s(t) [phi x]) (scipy's Slerp; phi the rotation vector of A^T B, s the
        raised cosine), so C' = C s' [phi x]; with C' = -[w x] C for a world -> body attitude,
        w = -s' C phi. Zero at rest."""
        times = np.atleast_1d(np.asarray(times, float))
        starts = np.array([t for t, _, _ in self._turns])
        out = np.zeros((times.size, 3))
        which = np.searchsorted(starts, times, side="right") - 1
        for i in np.unique(which):
            start, a, b = self._turns[i]
            if not np.isfinite(start):
                continue
            x = (times[which == i] - start) / self.turn_time
            s_dot = np.where((x > 0) & (x < 1), 0.5 * np.pi * np.sin(np.pi * x), 0.0) \
                / self.turn_time
            phi = (a.inv() * b).as_rotvec()
            out[which == i] = -s_dot[:, None] * (self.attitude(times[which == i]) @ phi)
        return out

    def __call__(self, times) -> np.ndarray:
        times = np.atleast_1d(np.asarray(times, float))
        v = self.gravity * self.attitude(times)[:, :, 2]
        counts = self.unit.sample(v, times, self.effects)
        if self.gyro is None:
            return counts
        return np.hstack([counts, self.gyro.sample(self.rates(times), times)])

    def _turn(self) -> None:
        start = max(self.clock.now(), self.next_turn or -np.inf)
        target = self.mounting @ self._iron
        current = Rotation.from_matrix(self.attitude(start)[0])
        self._turns.append((start, current, Rotation.from_matrix(target)))
        self.poses.append(target)


class HandTechnician(SimulatedTechnician):
    """The hand bench's technician: `SimulatedTechnician` turning a `HandRig`.

    An instruction with an orientation (the iron's or the unit's attitude) turns the rig there, with
    a random error of `placement_deg`; one without an orientation is a re-mounting of the unit in
    the iron (the iron protocol's only such instruction): the next of `mountings`.

    With a `period`, the technician works to a metronome: each turn starts at the first multiple of
    `period` clock seconds at least `handling_time` after the request (the answer comes two
    seconds before it). The recording then does not depend on when a loaded host got round to each
    step (unless it is late by more than the slack), and a seeded session replays the same samples.
    """

    def __init__(self, rig: HandRig, clock, mountings, handling_time: float = 3.0,
                 placement_deg: float = 0.0002, rng=None, period: float | None = None):
        super().__init__(rig, clock, 0.0, placement_deg, rng)
        self.mountings = np.asarray(mountings, float)
        self.handling_time = float(handling_time)
        self.period = period
        self.remounts = 0
        self.stop = None  # a threading.Event that ends a wait for the next turn (a twin closing)

    def wait(self, instruction) -> None:
        start = self.clock.now() + self.handling_time
        if self.period:
            start = self.period * np.ceil(start / self.period)
        self.clock.sleep(start - 2.0 - self.clock.now(), self.stop)
        if self.stop is not None and self.stop.is_set():
            return
        self.mounted.next_turn = start
        if instruction.orientation is not None:
            super().wait(instruction)
            return
        self.prompt(instruction.text)
        self.mounted.remount(self.mountings[self.remounts % len(self.mountings)])
        self.remounts += 1


@dataclass(frozen=True)
class HandTruth:
    """What the simulated unit is and the stimuli it felt.

    a (3, m) true sensitivity (dimensionless, SI readings); bias (m,) m/s^2; gravity m/s^2;
    up (P, 3) the up direction in the unit frame after each turn (poses and re-mountings);
    a_nominal (3, m).
    """

    a: np.ndarray
    bias: np.ndarray
    gravity: float
    up: np.ndarray
    a_nominal: np.ndarray


class HandBench:
    """Starts the simulated hand bench; `close()` (or leaving the `with`) stops it.

    seed          : seed of the unit, the mountings and the technician
    speed         : clock speed, simulated seconds per wall second (a `ScaledClock`); None (the
                    default): lockstep time (`SteppedClock`), the same samples on any host
    rate_hz       : IMU sample rate
    layout        : (3, m) nominal layout of the accelerometers (ACC4, TRIAD, ...)
    mountings     : (K, 3, 3) iron -> unit rotations used in turn, or a count of random ones
    handling_time : simulated seconds the technician takes before each turn
    period        : the technician's metronome (see HandTechnician), None: none
    turn_time     : seconds each turn lasts
    placement_deg : how far each turn misses its target (standard deviation per axis), degrees
    latitude_deg  : site latitude (normal gravity)
    effects       : optional {name: {param: value}}: named effects in the unit's output chain
                    (`station.model.sensing.LIVE_EFFECTS`), e.g. {"saturation": {"range": 30.0}}
    link          : "serial" (`drivers.twins.serial.SerialTwin` on a pty) or "mavlink" (a flight
                    controller, `drivers.twins.mavlink.MavlinkTwin`, SCALED_IMU; a triad only,
                    with a gyro triad `gyro` beside it: `gyro_array` noise and biases, TRIAD)
    udp_port      : mavlink: send to the station over UDP on 127.0.0.1:udp_port, not a pty
    """

    def __init__(self, seed: int = 1, speed: float | None = None, rate_hz: float = 200.0,
                 layout=ACC4, mountings=3, handling_time: float = 3.0, period: float | None = None,
                 turn_time: float = 2.0, placement_deg: float = 0.0002,
                 latitude_deg: float = 52.2, effects: dict | None = None, link: str = "serial",
                 udp_port: int | None = None):
        rng = np.random.default_rng(seed)
        self.layout = np.asarray(layout, float)
        self.clock = SteppedClock() if speed is None else ScaledClock(speed)
        self.link, self.udp_port = link, udp_port
        self.profile = accel_profile(self.layout.shape[1], rate_hz, link)
        self.stream_spec = StreamSpec.from_profile(self.profile.imu)
        self.gravity = normal_gravity(latitude_deg)
        m = self.layout.shape[1]
        self.unit = accelerometer_triad(rng, self.layout, fs=rate_hz,
                                        counts_per_unit=self.profile.imu.scale[:m])
        # a flight controller's gyro triad beside the accelerometers (its own random stream)
        self.gyro = gyro_array(np.random.default_rng([seed, 3]), TRIAD, fs=rate_hz,
                               counts_per_unit=self.profile.imu.scale[m:]) \
            if len(self.profile.imu.channels) > m else None
        if np.ndim(mountings) == 0:
            mountings = Rotation.random(int(mountings), random_state=rng).as_matrix()
        self.rig = HandRig(self.unit, self.clock, self.gravity, turn_time,
                           effects=from_json(effects or {}), gyro=self.gyro)
        self.technician = HandTechnician(self.rig, self.clock, mountings, handling_time,
                                         placement_deg, np.random.default_rng([seed, 1]), period)
        self.source = self.rig  # what the IMU twin streams (a test may wrap it: tests/test_redo.py)
        self.twin = None
        self.failures = Failures()  # the IMU twin's, told at once (drivers.twins.failure)

    def start(self, unread_after: float | None = None) -> Self:
        """Start the IMU stream (MAVLink: the heartbeat; the IMU when the station asks for it);
        `unread_after`: see `drivers.twins.pty.PtyLink`."""
        if self.link == "mavlink":
            from drivers.twins.mavlink import MavlinkTwin

            self.twin = self.failures.watch(MavlinkTwin(
                self.profile, self.rig, self.clock, udp_port=self.udp_port, max_lag=np.inf,
                unread_after=unread_after), "MAVLink flight controller")
            self.twin.start()
            return self
        # frame n is sampled at clock n / rate_hz: with the technician's metronome, the same
        # samples whatever the host's load (frames before the driver opens the port are lost)
        self.twin = self.failures.watch(SerialTwin(self.profile, self.source, self.clock,
                                                   max_lag=np.inf, unread_after=unread_after),
                                        "serial IMU")
        self.twin.start(0.0)
        return self

    def close(self) -> None:
        """Stop the IMU stream (idempotent)."""
        if self.twin is not None:
            twin, self.twin = self.twin, None
            twin.stop()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, kind, exc, trace) -> None:
        """Close; the IMU twin's failure becomes a note on the error leaving the `with`, or a
        TwinError (`drivers.twins.failure.Failures.after`)."""
        self.close()
        self.failures.after(exc)

    @contextlib.contextmanager
    def driver(self):
        """The station's real driver of the link on the twin's port, closed on exit."""
        with open_imu(self.link, self.twin.port, self.profile, self.clock) as imu:
            yield imu

    def truth(self) -> HandTruth:
        """The true unit and the up direction (unit frame) after each turn so far."""
        up = np.array([c[:, 2] for c in self.rig.poses]).reshape(-1, 3)
        return HandTruth(self.unit.a.copy(), self.unit.bias.copy(), self.gravity, up, self.layout)


def record_iron_session(path, seed: int = 1, speed: float | None = None, mountings: int = 2,
                        rate_hz: float = 200.0, settings=None, unit_serial: str | None = None,
                        period: float | None = 20.0):
    """Record an iron session of the ACC4 unit on a new bench into `path` (a new .h5), solve it and
    keep the result as `results/live`; returns (HandTruth, IronReadings, CalibrationResult)."""
    from station.protocols.iron import IronProtocol, IronSettings
    from station.reduce.iron import iron_readings

    with HandBench(seed=seed, speed=speed, rate_hz=rate_hz, period=period) as bench:
        settings = settings or IronSettings(gravity=bench.gravity, mountings=mountings)
        protocol = IronProtocol(bench.technician, bench.clock, ACC4, settings)
        truth = _record(path, bench, protocol, unit_serial or f"SIM-ACC4-{seed}", seed, speed)
    readings = _reduce(path, iron_readings)
    result = calibrate_still(readings, settings.gravity, nominal=ACC4)
    write_results(path, "live", "imu", readings.M, result, readings.sigma)
    return truth, readings, result


def record_static_session(path, seed: int = 1, speed: float | None = None, layout=TRIAD,
                          poses: int = 18, rate_hz: float = 200.0, settings=None,
                          unit_serial: str | None = None, period: float | None = 20.0,
                          placement_deg: float = 5.0):
    """Record a free-static session of a unit on `layout` on a new bench into `path` (a new .h5),
    solve it and keep the result as `results/live`; returns (HandTruth, StillReadings,
    CalibrationResult)."""
    from station.protocols.static import StaticProtocol, StaticSettings
    from station.reduce.static import static_readings

    with HandBench(seed=seed, speed=speed, rate_hz=rate_hz, layout=layout, mountings=[np.eye(3)],
                   period=period, placement_deg=placement_deg) as bench:
        settings = settings or StaticSettings(gravity=bench.gravity, poses=poses)
        protocol = StaticProtocol(bench.technician, bench.clock, bench.layout,
                                  bench.stream_spec.units, settings)
        m = bench.layout.shape[1]
        truth = _record(path, bench, protocol, unit_serial or f"SIM-ACC{m}-{seed}", seed, speed)
    readings = _reduce(path, static_readings)
    result = calibrate_still(readings, settings.gravity, nominal=bench.layout)
    write_results(path, "live", "imu", readings.M, result, readings.sigma)
    return truth, readings, result


def _record(path, bench: HandBench, protocol, unit_serial: str, seed: int,
            speed: float | None):
    """Run `protocol` on the bench's serial driver into the new session `path`; the truth."""
    metadata = {**protocol.metadata(), "unit_serial": unit_serial,
                "bench": {"kind": protocol.metadata()["protocol"], "seed": seed, "speed": speed}}
    with bench.driver() as imu:
        record_poses(protocol, imu, bench.stream_spec, bench.clock, path, metadata)
    return bench.truth()


def _reduce(path, reduction):
    with Session.open(path) as session:
        return reduction(session)
