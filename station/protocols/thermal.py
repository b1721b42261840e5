"""The thermal campaign: one rotary session per thermal chamber setpoint (docs/protocols.md,
"Thermal sessions").

For each setpoint of the bench profile's `[chamber]` section not yet done (the campaign manifest,
`station.session.campaign`): the chamber is commanded (ramp, setpoint, run), the unit SOAKS until
its OWN temperature channel (a channel in K of the IMU stream, not the chamber's air) changes by
less than `stability` K/min, the slope of a straight line fitted to the last `window` seconds of its
readings, the chamber reporting itself at its setpoint over that whole window; then a normal rotary
session is recorded into its own file (`station.acquire.bench.record`), its metadata holding the
setpoint, the soak's measured unit temperature and the chamber's readings during the soak. A soak
that has not settled after `soak_timeout` seconds is a SoakTimeout naming the setpoint, the rate
still seen and what to do.

On every fault and on Ctrl-C the chamber is commanded to its `safe` setpoint (the driver's
`safe_kelvin`, which says on the error whether that worked) and the table to stop (the rotary
session stops it itself; `stop_table` once more, as `station resume` does); the manifest then says
which soaks are done, and `station resume DIR` continues at the first that is not (a session left
partial is soaked again, then resumed from its last completed position). At the end the chamber
is sent to its safe setpoint too.

The chamber's watchdog (`[chamber.watchdog]`) is fed for the whole campaign, the table's for each
session (`station.acquire.watchdog.fed`): a killed or hung station leaves them to their
controllers, which stop the table and send the chamber to the watchdog's safe setpoint by
themselves. A campaign whose devices have no watchdog is refused unless the technician says
`--no-watchdog` (`station.acquire.watchdog.require_watchdogs`, called by `station record` and
`station resume`).
"""

import dataclasses
import math
import threading
from dataclasses import dataclass

import numpy as np

from station.acquire import interrupts
from station.errors import RecordingError, SoakTimeout

ROOM = 296.15
"""K: the default safe setpoint (23 degC)."""


@dataclass(frozen=True)
class ChamberSettings:
    """The bench profile's `[chamber]` section (keys as the fields; docs/protocols.md).

    host, port / serial_port : the chamber's controller over Modbus TCP, or Modbus RTU on a port
    register_map : its `drivers.thermal_chamber.ChamberRegisterMap` (key `profile`, a device
                   profile with a [chamber] section; default the bundled chamber_modbus)
    setpoints    : K, in the order soaked (2 to station.session.campaign.MAX_SOAKS)
    ramp         : K/min the chamber's setpoint moves at (0: as fast as it can)
    stability    : K/min: the soak is over when the unit's temperature changes more slowly
    window       : s over which that rate is measured (a straight-line fit)
    soak_timeout : s after which a soak that has not settled is an error
    safe         : K the chamber is left at on a fault, on Ctrl-C and at the end
    poll         : s between two readings of the chamber
    reply_timeout: wall s the driver waits for each reply (default `drivers.clock.reply_timeout`:
                   0.5 s on a real-time clock, 30 s in lockstep); a slow RS-485 line wants more
    retries      : extra tries after a timeout or a bad reply (default 2)
    """

    register_map: object
    setpoints: tuple
    host: str | None = None
    port: int = 502
    serial_port: str | None = None
    ramp: float = 2.0
    stability: float = 0.05
    window: float = 120.0
    soak_timeout: float = 7200.0
    safe: float = ROOM
    poll: float = 2.0
    reply_timeout: float | None = None
    retries: int = 2

    @classmethod
    def from_section(cls, s, device) -> "ChamberSettings":
        """Parse the [chamber] Section `s`; device(name) resolves a device profile's name."""
        from drivers.thermal_chamber import ChamberRegisterMap
        from station.session.campaign import MAX_SOAKS

        register_map = ChamberRegisterMap.load(device(s.get("profile", str,
                                                            default="chamber_modbus")))
        fields = {"register_map": register_map,
                  "setpoints": tuple(s.get_list("setpoints", float))}
        if s.has("host") == s.has("serial_port"):
            raise s.error("host", "give the chamber's host (and port: Modbus TCP) or its "
                                  "serial_port (Modbus RTU), one of them")
        if s.has("host"):
            fields.update(host=s.get("host", str), port=s.get("port", int, default=502))
        else:
            fields["serial_port"] = s.get("serial_port", str)
        for f in ("ramp", "stability", "window", "soak_timeout", "safe", "poll", "reply_timeout"):
            if s.has(f):
                fields[f] = s.get(f, float)
        if s.has("retries"):
            fields["retries"] = s.get("retries", int)
        settings = cls(**fields)
        low, high = register_map.setpoint_range
        temps = settings.setpoints + (settings.safe,)
        if not (2 <= len(settings.setpoints) <= MAX_SOAKS
                and all(low <= t <= high for t in temps)):
            raise s.error("setpoints", f"give 2 to {MAX_SOAKS} setpoints and a safe setpoint in "
                                       f"kelvin within the chamber's {low:.2f}..{high:.2f} K; got "
                                       f"{list(settings.setpoints)}, safe {settings.safe}")
        if not 0 <= settings.ramp <= register_map.ramp_max:
            raise s.error("ramp", f"must be 0..{register_map.ramp_max} K/min (the chamber's "
                                  "limit)")
        positive = ("stability", "window", "soak_timeout", "poll")
        if not all(math.isfinite(getattr(settings, f)) and getattr(settings, f) > 0
                   for f in positive):
            raise s.error("stability", f"{', '.join(positive)} must be positive numbers")
        if settings.reply_timeout is not None and not 0 < settings.reply_timeout <= 600:
            raise s.error("reply_timeout", "must be 0 < seconds <= 600 (the wait for each reply)")
        if not 0 <= settings.retries <= 10:
            raise s.error("retries", "must be 0..10 (extra tries after a lost reply)")
        s.finish()
        return settings

    def chamber(self, clock):
        """The chamber's driver (not connected), sent to `safe` when left on an exception."""
        from drivers.thermal_chamber import ThermalChamber

        where = ({"host": self.host, "port": self.port} if self.host is not None
                 else {"serial_port": self.serial_port})
        return ThermalChamber(self.register_map, **where, safe_kelvin=self.safe, clock=clock,
                              timeout=self.reply_timeout, retries=self.retries)


@dataclass(frozen=True)
class SoakResult:
    """A soak that settled: the unit's mean temperature over the last window (K), its rate then
    (K/min), the clock seconds it took, and the chamber's readings and the unit's temperature at
    each poll (`trace`: lists time, air, setpoint, unit)."""

    setpoint: float
    unit_temperature: float
    rate: float
    seconds: float
    trace: dict

    def metadata(self) -> dict:
        """What a soak's session file records about it (`thermal` metadata; a unit temperature
        not yet read at a poll is null)."""
        from station.files.jsonable import jsonable

        return jsonable(dataclasses.asdict(self))


def temperature_column(units) -> int:
    """Index of the stream's temperature channel (the first in K); ProfileError without one."""
    from drivers.profile import ProfileError

    kelvin = [i for i, u in enumerate(units) if u == "K"]
    if not kelvin:
        raise ProfileError("a thermal campaign soaks on the unit's own temperature: the IMU's "
                           "device profile needs a temperature channel (unit K, e.g. "
                           "imu12_serial_temp)")
    return kelvin[0]


def soak(chamber, imu, settings: ChamberSettings, setpoint: float, clock, column: int,
         counts_per_kelvin: float) -> SoakResult:
    """Bring the unit to `setpoint` (module docstring): command the chamber, read the IMU's
    temperature channel `column` until it settles; SoakTimeout when it does not in time,
    RecordingError when the IMU sends nothing for `window` seconds. The chamber's alarm and door
    bits are checked at every poll (ChamberAlarm, ChamberDoorOpen)."""
    chamber.set_setpoint(setpoint, settings.ramp)
    chamber.run()
    start = clock.now()
    times, temps = [], []  # one point per block of samples: its mean
    trace = {"time": [], "air": [], "setpoint": [], "unit": []}
    steady_since, rate = None, math.nan
    while True:
        block = imu.read_block(timeout=settings.poll)
        if block is not None and len(block):
            times.append(float(np.mean(block.host_time)))
            temps.append(float(np.mean(block.counts[:, column])) / counts_per_kelvin)
        now = clock.now()
        if now - (times[-1] if times else start) > settings.window:
            raise RecordingError(f"the IMU sent no sample for {settings.window:g} s during the "
                                 f"soak at {setpoint:.2f} K: its temperature cannot be watched. "
                                 "Check its cable and power, then `station resume` the campaign")
        if trace["time"] and now - trace["time"][-1] < settings.poll:
            continue
        reading = chamber.check()
        unit = temps[-1] if temps else math.nan
        for key, value in (("time", now), ("air", reading.temperature),
                           ("setpoint", reading.setpoint), ("unit", unit)):
            trace[key].append(round(value, 4))
        if not reading.at_setpoint:
            steady_since = None
        elif steady_since is None:
            steady_since = now
        rate = _rate(times, temps, now - settings.window)
        if (steady_since is not None and now - steady_since >= settings.window
                and abs(rate) < settings.stability):
            window = np.asarray(times) >= now - settings.window
            return SoakResult(setpoint, float(np.mean(np.asarray(temps)[window])), rate,
                              now - start, trace)
        if now - start > settings.soak_timeout:
            raise SoakTimeout(
                f"the soak at {setpoint:.2f} K has not settled after {settings.soak_timeout:g} s: "
                f"the unit's temperature ({unit:.2f} K) still changes by {abs(rate):.3f} K/min "
                f"(threshold {settings.stability:g} K/min over {settings.window:g} s; chamber "
                f"air {reading.temperature:.2f} K, "
                f"{'at' if reading.at_setpoint else 'not at'} its setpoint). Check the unit's "
                "thermal contact and the chamber, lengthen [chamber] soak_timeout or raise "
                "stability, then `station resume` the campaign")


def _rate(times: list, temps: list, since: float) -> float:
    """K/min: the slope of a straight line through the points after `since` (NaN with fewer than
    3)."""
    t, u = np.asarray(times), np.asarray(temps)
    keep = t >= since
    if keep.sum() < 3:
        return math.nan
    return 60.0 * float(np.polyfit(t[keep] - t[keep][0], u[keep], 1)[0])


def run_campaign(bench, campaign, operator) -> dict:
    """Soak and record every soak of `campaign` (a station.session.campaign.Campaign) not done, on
    the devices of the bench profile `bench` (with its `chamber`); returns a summary. Faults and
    Ctrl-C leave the chamber at its safe setpoint and the table stopped (module docstring)."""
    from station.acquire.bench import bench_clock
    from station.acquire.watchdog import fed

    settings = bench.chamber
    clock = bench_clock(bench)
    recorded = []
    try:
        with settings.chamber(clock) as chamber, fed(chamber):
            while (k := campaign.next_soak()) is not None:
                recorded.append(_soak_and_record(k, campaign, bench, chamber, clock, operator))
            chamber.safe(settings.safe)
    except BaseException as exc:
        cause = _leave_safe(exc, bench, settings, campaign)
        if cause is exc:
            raise
        raise cause from exc
    return {"campaign": str(campaign.directory), "recorded": recorded,
            "soaks": campaign.soaks, "safe_setpoint": settings.safe}


def _soak_and_record(k: int, campaign, bench, chamber, clock, operator) -> str:
    """Soak k of `campaign`, then its rotary session (recorded, or resumed when its file exists)
    with the chamber watched; the manifest updated after each step. Returns the session's path."""
    from station.acquire.bench import imu_driver, record, resume

    settings, setpoint = bench.chamber, campaign.soaks[k]["setpoint"]
    operator.prompt(f"soak {k + 1} of {len(campaign.soaks)}: chamber to {setpoint:.2f} K")
    column = temperature_column(bench.imu.imu.units)
    with imu_driver(bench, clock) as imu:
        result = _soak(chamber, imu, settings, setpoint, clock, column,
                       bench.imu.imu.scale[column])
    campaign.update(k, state="soaked", unit_temperature=result.unit_temperature,
                    rate_K_per_min=result.rate, soak_seconds=result.seconds)
    path = campaign.directory / campaign.soaks[k]["file"]
    thermal = {**result.metadata(), "soak": k + 1, "chamber_before": _reading(chamber.check())}
    watch = ChamberWatch(chamber, settings.poll, clock)
    try:
        with watch:
            if path.exists():
                resume(bench, path, operator, clock)
            else:
                record(bench, path, operator, extra={"thermal": thermal}, clock=clock)
    finally:
        campaign.update(k, chamber_during=watch.trace)
    watch.check(path)
    campaign.update(k, state="done", chamber_after=_reading(chamber.check()))
    return str(path)


class ChamberWatch:
    """Reads the chamber every `poll` clock seconds in a thread while a rotary session records
    (the main thread does not use the chamber meanwhile): `trace` (lists time, air, setpoint,
    alarm, door_open). The first fault (alarm, door open, no answer) stops the session at once:
    it is delivered to the main thread (`station.acquire.interrupts.deliver`), whose next poll
    raises it, so the protocol aborts the position with the table stopped and the positions done
    are kept for `station resume`. `check` after a session that ended before that poll refuses it
    (the fault came in its last moments)."""

    def __init__(self, chamber, poll: float, clock):
        self.chamber, self.poll, self.clock = chamber, poll, clock
        self.trace = {"time": [], "air": [], "setpoint": [], "alarm": [], "door_open": []}
        self.error = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="chamber-watch", daemon=True)

    def __enter__(self) -> "ChamberWatch":
        self.clock.enlist(self._thread)  # a station thread on a lockstep clock
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self.clock.nudge()
        self._thread.join()
        if self.error is not None:
            interrupts.withdraw(self.error)

    def _run(self) -> None:
        from drivers.errors import ChamberError

        due = self.clock.now()
        while not self._stop.is_set():
            self.clock.sleep(due - self.clock.now(), self._stop)
            if self._stop.is_set():
                return
            due += self.poll
            try:
                r = self.chamber.state()
            except ChamberError as exc:
                exc.add_note("the chamber stopped answering during the session")
                self._fault(exc)
                return
            for key, value in (("time", r.time), ("air", r.temperature),
                               ("setpoint", r.setpoint), ("alarm", r.alarm),
                               ("door_open", r.door_open)):
                self.trace[key].append(round(value, 4) if isinstance(value, float) else value)
            if r.alarm or r.door_open:
                self._fault(self._bit_error())
                return

    def _fault(self, error: BaseException) -> None:
        """Keep `error` and stop the session with it."""
        self.error = error
        interrupts.deliver(error)

    def _bit_error(self):
        """The ChamberAlarm or ChamberDoorOpen of the trace's first fault bit."""
        from drivers.errors import ChamberAlarm, ChamberDoorOpen

        name, cls = next((n, c) for n, c in (("alarm", ChamberAlarm),
                                             ("door_open", ChamberDoorOpen)) if any(self.trace[n]))
        words = "raised its alarm" if name == "alarm" else "opened its door"
        return cls(f"{self.chamber.where}: {words} during the session at "
                   f"{self.trace['setpoint'][-1]:.2f} K, so the unit's temperature is not known "
                   "there: the session stopped (the positions recorded before are kept). Clear "
                   "the cause, then `station resume` the campaign (it soaks this setpoint again "
                   "and records what is missing)")

    def check(self, path) -> None:
        """After a session that ended before the watch's fault could stop it (the fault came in
        its last moments): move the session aside (`<name>.chamber-fault.h5`), so that the
        campaign records it again, and raise the fault."""
        if self.error is None:
            return
        aside = path.with_name(f"{path.stem}.chamber-fault.h5")
        path.replace(aside)
        self.error.add_note(f"the session had ended meanwhile: it was moved to {aside.name} and "
                            "will be recorded again")
        raise self.error


def _leave_safe(exc: BaseException, bench, settings: ChamberSettings,
                campaign) -> BaseException:
    """After `exc` (the chamber already sent to its safe setpoint by its driver): stop the
    table, and say on the error to raise (`exc`, or the interrupt it stands for:
    station.acquire.interrupts.handling, where a second Ctrl-C is remembered, not raised) what
    was done and how to go on; returns that error."""
    from station.acquire import interrupts
    from station.acquire.bench import stop_table

    with interrupts.handling(exc) as cause:
        if cause is not exc and getattr(exc, "chamber_safe", False):
            cause.chamber_safe = True
        exc = cause
        try:
            exc.table_stopped = stop_table(bench.source)
        except Exception as stop_error:  # noqa: BLE001 - said on the error being raised
            exc.add_note(f"the table could not be stopped ({stop_error}); stop it by hand")
    if getattr(exc, "chamber_safe", False):
        exc.add_note(f"the chamber was sent to its safe setpoint {settings.safe:.2f} K")
    k = campaign.next_soak()
    if k is not None:
        exc.add_note(f"the campaign {campaign.directory} goes on at soak {k + 1} "
                     f"({campaign.soaks[k]['setpoint']:.2f} K) with `station resume "
                     f"{campaign.directory}`")
    return exc


def _soak(chamber, imu, settings, setpoint, clock, column, counts_per_kelvin) -> SoakResult:
    """`soak`, an IMU lost during it said as such on the error."""
    from drivers.errors import LinkError

    try:
        return soak(chamber, imu, settings, setpoint, clock, column, counts_per_kelvin)
    except LinkError as exc:
        exc.add_note(f"the IMU was lost during the soak at {setpoint:.2f} K: its temperature "
                     "cannot be watched; reconnect it, then `station resume` the campaign")
        raise


def _reading(reading) -> dict:
    """A chamber reading as metadata."""
    return dataclasses.asdict(reading)
