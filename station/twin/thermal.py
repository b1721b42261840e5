"""The virtual thermal bench (`station twin --chamber`): the rotary bench with its motorised fixture
(`station.twin.served.BenchTwin`), its 12-gyro unit streaming a temperature channel (device profile
imu12_serial_temp), inside a thermal chamber twin (`drivers.twins.chamber`, Modbus
TCP on 127.0.0.1), all on one clock.

The chamber's physics (`drivers.twins.thermal.ChamberPhysics`) gives the unit's temperature; the
unit's a and b follow it through the `temperature` effect (`station.sim.heated.HeatedUnit`, the
true tempcos `effect`), and its temperature sensor streams it with a little noise and the
profile's 0.01 K quantisation. `profile_text()` is a bench profile with the [chamber] section
(`station record` then records a thermal campaign; docs/protocols.md "Thermal sessions").
"""

import dataclasses
import json
from typing import Self

from station.model.effects.temperature import Temperature

SETPOINTS = (263.15, 283.15, 313.15, 333.15)
"""K: the default campaign (-10, 10, 40, 60 degC)."""
TRUTH = Temperature(bias=2e-5, scale=(1e-4, -5e-5) * 6, t_ref=0.5 * (SETPOINTS[0] + SETPOINTS[-1]))
"""The twin unit's true tempcos: 2e-5 rad/s/K biases, 50-100 ppm/K scale factors."""
PROTOCOL = {"static": 5.0, "revolutions": 1}
"""The rotary settings of the twin's profile: short windows, so a campaign takes minutes."""
FAST_CHAMBER = {"tau_air": 10.0, "heat_rate": 30.0, "cool_rate": 30.0, "tau_unit": 30.0}
"""A small, fast chamber and a small unit (s, K/min): a soak takes minutes of clock time."""


class ThermalTwin:
    """The virtual thermal bench (module docstring).

    seed, speed, positions, rate_hz, lifetime : those of BenchTwin
    setpoints, effect : the campaign the profile asks for (K) and the unit's true tempcos
    chamber   : ChamberPhysics arguments (default FAST_CHAMBER)
    soak      : the profile's [chamber] soak keys (stability, window, soak_timeout, poll, ramp,
                safe)
    spikes    : the fault knob of spiky first attempts (`station.sim.spikes`): the positions,
                counted over the campaign (soak s, position j: (s - 1) positions + j), or a chance
                per position
    """

    def __init__(self, seed: int = 1, speed: float | None = None, positions: int = 6,
                 rate_hz: float = 100.0, lifetime: float = 3600.0, setpoints=SETPOINTS,
                 effect: Temperature = TRUTH, chamber: dict | None = None,
                 soak: dict | None = None, spikes=None):
        from drivers.profile import SerialImuProfile
        from drivers.thermal_chamber import ChamberRegisterMap
        from drivers.twins.chamber import ChamberTwin
        from drivers.twins.thermal import ChamberPhysics
        from station.session import StreamSpec
        from station.sim.heated import HeatedUnit
        from station.twin.served import BenchTwin

        self.served = BenchTwin("serial", seed, speed, positions, rate_hz, lifetime,
                                spikes=spikes)
        b = self.served.bench
        profile = SerialImuProfile.load("imu12_serial_temp")
        b.profile = dataclasses.replace(profile, imu=dataclasses.replace(profile.imu,
                                                                          rate_hz=rate_hz))
        b.stream_spec = StreamSpec.from_profile(b.profile.imu)
        self.physics = ChamberPhysics(b.clock, **(chamber or FAST_CHAMBER))
        self.chamber = self.failures.watch(
            ChamberTwin(self.physics, ChamberRegisterMap.load("chamber_modbus"),
                        lifetime=lifetime), "thermal chamber")
        b.source = HeatedUnit(b.mounted, self.physics.unit_temperature, effect,
                              b.profile.imu.scale[-1], seed=seed)
        self.effect, self.setpoints = effect, tuple(setpoints)
        self.soak = {"ramp": 0.0, "stability": 0.1, "window": 60.0, "soak_timeout": 1200.0,
                     "poll": 2.0, **(soak or {})}

    @property
    def bench(self):
        """The VirtualBench (table twin, unit, clock)."""
        return self.served.bench

    @property
    def error(self):
        """What went wrong in the fixture's thread (None: nothing)."""
        return self.served.error

    @property
    def failures(self):
        """The failures of the bench's twins, the chamber's too
        (`drivers.twins.failure.Failures`)."""
        return self.served.failures

    def start(self) -> Self:
        self.chamber.start()
        try:
            self.served.start()
        except BaseException:
            self.chamber.close()
            raise
        return self

    def close(self) -> None:
        self.served.close()
        self.chamber.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, kind, exc, trace) -> None:
        self.close()
        self.failures.after(exc)

    def addresses(self) -> dict:
        """Where the station finds the devices (BenchTwin's, and the chamber)."""
        return {**self.served.addresses(), "chamber": {"host": "127.0.0.1",
                                                       "port": self.chamber.port}}

    def toggle(self, device: str) -> bool:
        """Lose `device` ("imu", "table", or "chamber": silent) if it is there, else bring it
        back; True when it is now lost."""
        if device != "chamber":
            return self.served.toggle(device)
        self.chamber.silent = not self.chamber.silent
        return self.chamber.silent

    def profile_text(self, unit_serial: str | None = None) -> str:
        """The bench profile: BenchTwin's with the short rotary settings and the [chamber]
        section."""
        text = self.served.profile_text(unit_serial)
        positions = f"[protocol]\npositions = {self.served.positions}\n"
        extra = "".join(f"{k} = {v!r}\n" for k, v in PROTOCOL.items())
        chamber = {"host": "127.0.0.1", "port": self.chamber.port, "profile": "chamber_modbus",
                   "setpoints": list(self.setpoints), **self.soak}
        return (text.replace(positions, positions + extra) + "\n[chamber]\n"
                + "".join(f"{k} = {json.dumps(v)}\n" for k, v in chamber.items()))

    def truth(self) -> dict:
        """The simulated unit at t_ref, its true tempcos and the chamber now (JSON-ready)."""
        s = self.physics.state()
        return {**self.served.truth(), "temperature": dataclasses.asdict(self.effect),
                "chamber": {"air": s.air, "unit": s.unit, "setpoint": s.setpoint,
                            "running": s.running}}


def thermal_twin(options) -> ThermalTwin:
    """`station twin --chamber` (options: seed, speed, positions, rate_hz, lifetime, spikes)."""
    return ThermalTwin(options.seed, options.speed, options.positions, options.rate_hz,
                       options.lifetime, spikes=getattr(options, "spikes", None))
