"""A calibration bench: its profile (TOML, described in `station record --help` and
docs/protocols.md), its devices opened from it, and a session recorded or resumed on it.

`BenchProfile.load` checks a profile (`drivers.profile.ProfileError` names any problem); one
[imu] section, or an [[imu]] table per unit of several on one rotary table (`BenchUnit`: a driver
and a stream each, docs/protocols.md "Several units on one table");
`record` runs the profile's protocol kind (`station.protocols.KINDS`) with the bench's devices
into a new session file; `resume` continues a killed, paused or aborted session on the same bench.
The rotary table is commanded to stop as soon as its driver is connected and whenever it is closed,
and its watchdog is fed while a session holds it (`table_driver`); `stop_table` stops it before
anything else is loaded (`station resume`).
"""

import contextlib
import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from station.errors import InputError
from station.session.units import SERIAL, SessionUnit, unit_stream


@dataclass(frozen=True)
class BenchUnit:
    """One IMU of the bench: a unit on the table's plate (docs/protocols.md "Several units").

    unit_serial : its serial ([[imu]] unit_serial; one [imu]: the bench's)
    link, imu, address : its link, device profile (rate applied) and address, as `BenchProfile`'s
    stream      : its stream in the session ("imu", "imu2", ...: `unit_stream`)
    mounting    : (3, 3) rotation plate frame -> unit frame ([[imu]] mounting, rows), or None
    """

    unit_serial: str
    link: str
    imu: object
    address: str | dict
    stream: str = "imu"
    mounting: np.ndarray | None = None

    def session_unit(self) -> SessionUnit:
        """What the session file records about the unit (`station.session.units`)."""
        return SessionUnit(self.stream, self.unit_serial, self.mounting)


RECORDED = ("name", "lot")
"""Optional [bench] keys that only the calibration records read (station.records.sources,
docs/records.md): the bench's name (default: the profile's file name) and the units' lot."""


@dataclass(frozen=True)
class BenchProfile:
    """A parsed bench profile; `imu` is a SerialImuProfile, CanProfile or MavlinkProfile with the
    rate applied. `units`: every IMU (`BenchUnit`), the first the one `link`, `imu` and
    `imu_address` describe; several when the profile lists `[[imu]]` tables (rotary only)."""

    source: str
    unit_serial: str
    clock_speed: float
    link: str
    imu: object
    imu_address: str | dict  # serial, mavlink: the port (or udpin:); can: {"interface", ...}
    protocol: str  # a kind of station.protocols.KINDS that records (acquire)
    positions: int  # table kinds (rotary): positions; others: the settings' poses
    settings: object  # the kind's settings (RotarySettings, IronSettings, StaticSettings, ...)
    tables: dict  # the TOML tables, recorded in the session's metadata
    table_host: str | None = None  # kinds with a table (rotary) only
    table_port: int | None = None
    table_map: object = None
    table_source: str | None = None  # the register map's profile file
    table_reply: float | None = None  # [table] reply_timeout: wall s per reply (None: the driver's)
    layout: np.ndarray | None = None  # kinds without a table: (3, m_acc) accelerometer axes
    fixture: object = None  # rotary, static: station.protocols.planned.FixtureSpec of [fixture]
    plan: object = None  # rotary on a two-axis table: station.protocols.planned.PlanSpec of [plan]
    spins: int = 0  # rotary on a two-axis table: spins of the position axis after the positions
    lockstep: str | None = None  # `station twin`'s lockstep clock (its socket), instead of speed
    chamber: object = None  # rotary: station.protocols.thermal.ChamberSettings of [chamber]
    units: tuple = ()  # every BenchUnit (one [imu]: the one unit)

    @property
    def plate(self) -> bool:
        """Several units on the table, each with its own stream and serial ([[imu]] tables)."""
        return len(self.units) > 1

    @classmethod
    def load(cls, path) -> "BenchProfile":
        """Read and check a bench profile; `drivers.profile.ProfileError` names any problem."""
        from drivers.profile import ProfileError, Section, load_profile
        from station.protocols import KINDS, kinds_with
        from station.solve.verdict import Tolerances

        profile = load_profile(path)

        def device(name: str) -> str:
            return _device(profile, name)

        def section(name: str) -> Section:
            table = profile.tables.get(name)
            if not isinstance(table, dict):
                raise ProfileError(f"{path}: no [{name}] section; see `station record --help`")
            return Section(profile.source, name, table)

        unknown = sorted(set(profile.tables) - {"bench", "imu", "table", "protocol", "tolerances",
                                                "fixture", "plan", "chamber"})
        if unknown:
            raise ProfileError(f"{path}: unknown sections {unknown}; a bench profile has [bench], "
                               "[imu], [table] (rotary), [protocol], [fixture] (rotary, static), "
                               "[plan] (a two-axis table), [chamber] (a thermal campaign, "
                               "rotary) and [tolerances]")
        if "tolerances" in profile.tables:  # refused now, not after the session was recorded
            try:
                Tolerances.from_table(profile.tables["tolerances"], "[tolerances]")
            except InputError as exc:
                raise ProfileError(f"{path}: {exc}") from None
        bench, proto = section("bench"), section("protocol")
        serial = bench.get("unit_serial", str)
        speed = bench.get("clock_speed", float, default=1.0)
        lockstep = bench.get("lockstep", str, default=None)
        for key in RECORDED:  # read by the calibration records from the session's metadata
            bench.get(key, str, default=None)
        if lockstep is not None and "clock_speed" in bench.table:
            raise ProfileError(f"{path}: [bench] gives both lockstep (the virtual bench's stepped "
                               "clock) and clock_speed (a real-time clock); keep the one `station "
                               "twin` wrote")
        if not SERIAL.match(serial):
            raise bench.error("unit_serial", f"{serial!r}: give 1-64 letters, digits, '.', '_' or "
                                             "'-' (it names the session file)")
        if not 0 < speed < 1e4:
            raise bench.error("clock_speed", f"{speed!r}: give a number between 0 and 1e4 "
                                             "(simulated s per wall s; 1 on a real bench)")
        units = _units(profile, serial, path)
        dev = units[0].imu
        kind = proto.get("kind", str, default="rotary", choices=tuple(kinds_with("acquire")))
        if len(units) > 1 and (not KINDS[kind].table or "chamber" in profile.tables):
            raise ProfileError(f"{path}: several [[imu]] units share a rotary table's session; "
                               f"a {kind} session{' with a [chamber]' if KINDS[kind].table else ''}"
                               " records one unit: give one [imu]")
        fields = {"source": profile.source, "unit_serial": serial, "clock_speed": speed,
                  "lockstep": lockstep,
                  "link": units[0].link, "imu": dev, "imu_address": units[0].address,
                  "protocol": kind, "tables": profile.tables, "units": units}
        if KINDS[kind].table:
            table = section("table")
            fields.update(_table_fields(profile, table), **_settings(kind, proto, path))
            if "fixture" in profile.tables:
                from station.protocols.planned import FixtureSpec

                fields["fixture"] = FixtureSpec.from_section(section("fixture"),
                                                             len(dev.imu.channels))
            fields["spins"] = _spins(fields, proto, path)
            if "plan" in profile.tables:
                fields["plan"] = _plan(fields, section("plan"), len(dev.imu.channels), path)
            fields["positions"] = (proto.get("positions", int, default=40)
                                   if "fixture" in fields or "plan" in fields
                                   else proto.get("positions", int))
            table.finish()
            if "chamber" in profile.tables:
                fields["chamber"] = _chamber(section("chamber"), device, dev.imu)
            if fields["positions"] < 1:
                raise ProfileError(f"{path}: [protocol] positions must be at least 1")
        else:
            if "plan" in profile.tables:
                raise ProfileError(f"{path}: [plan] plans the positions of a two-axis table; a "
                                   f"{kind} session has none: remove the section")
            if "chamber" in profile.tables:
                raise ProfileError(f"{path}: a thermal campaign records rotary sessions; remove "
                                   f"the [chamber] section of this {kind} bench")
            if "fixture" in profile.tables and kind != "static":
                raise ProfileError(f"{path}: the {kind} protocol does not plan fixture poses; "
                                   "remove the [fixture] section (it serves rotary and static "
                                   "sessions)")
            if "table" in profile.tables:
                raise ProfileError(f"{path}: a {kind} session uses no rotary table; remove the "
                                   "[table] section (or set [protocol] kind = \"rotary\")")
            fields.update(_settings(kind, proto, path))
            fields["layout"] = _layout(proto, dev.imu, path)
            if not KINDS[kind].has("channels") and \
                    fields["layout"].shape[1] != len(dev.imu.channels):
                raise ProfileError(f"{path}: the {kind} protocol calibrates every channel of the "
                                   "stream; use a device profile with accelerometer channels only")
            fields["positions"] = fields["settings"].poses
            if "fixture" in profile.tables:
                from station.protocols.planned import FixtureSpec

                fields["fixture"] = FixtureSpec.from_section(
                    section("fixture"), fields["layout"].shape[1], fields["layout"])
        for s in (bench, proto):
            s.finish()
        return cls(**fields)


def _units(profile, serial: str, path) -> tuple:
    """The bench's `BenchUnit`s: one [imu] section (the bench's unit_serial), or the [[imu]]
    tables, each with its own unit_serial and optional mounting, their streams "imu", "imu2",
    ...; ProfileError names a repeated serial or address."""
    from drivers.profile import ProfileError, Section

    tables = profile.tables.get("imu")
    if isinstance(tables, dict):
        return (_unit(profile, Section(profile.source, "imu", tables), serial, 0),)
    if not (isinstance(tables, list) and tables and all(isinstance(t, dict) for t in tables)):
        raise ProfileError(f"{path}: no [imu] section (or [[imu]] tables, one per unit on the "
                           "table); see `station record --help`")
    units = tuple(_unit(profile, Section(profile.source, f"imu #{k + 1}", t), None, k)
                  for k, t in enumerate(tables))
    for what, values in (("unit_serial", [u.unit_serial for u in units]),
                         ("address", [repr(u.address) for u in units if u.link != "can"])):
        if len(set(values)) != len(values):
            raise ProfileError(f"{path}: the [[imu]] units repeat a {what} ({values}); each unit "
                               "has its own serial and its own port (CAN units may share a bus, "
                               "each at its own id_offset)")
    _check_shared_buses([u for u in units if u.link == "can"], path)
    return units


def _check_shared_buses(units: list, path) -> None:
    """Refuse CAN units on one bus (interface and channel) whose frame ids on the wire meet: each
    driver would decode the other's frames as its own."""
    from drivers.can_imu import FrameLayout
    from drivers.profile import ProfileError

    seen = {}
    for u in units:
        bus = (u.address["interface"], u.address["channel"])
        ids = {s.frame_id for s in FrameLayout(u.imu).slots}
        for other, other_ids in seen.get(bus, []):
            if ids & other_ids:
                raise ProfileError(
                    f"{path}: units {other.unit_serial} and {u.unit_serial} share the CAN bus "
                    f"{':'.join(bus)} and both send frame ids "
                    f"{', '.join(f'{i:#x}' for i in sorted(ids & other_ids))}; configure each "
                    "unit to its own node and give its [[imu]] table that id_offset")
        seen.setdefault(bus, []).append((u, ids))


def _unit(profile, imu, serial: str | None, k: int) -> BenchUnit:
    """Unit k of the bench from its [imu] section (`drivers.profile.Section`); serial: the
    bench's for a one-unit [imu], None for an [[imu]] table (its own unit_serial, mounting)."""
    from drivers import LINKS, driver_class
    from drivers.profile import ProfileError

    link = imu.get("link", str, choices=tuple(LINKS))
    dev = driver_class(link).profile_type.load(_device(profile, imu.get("profile", str)))
    rate = imu.get("rate_hz", float, default=dev.imu.rate_hz)
    if not 0 < rate <= 1e5:
        raise ProfileError(f"{imu.source}: [{imu.name}] rate_hz = {rate!r}; give the IMU's output "
                           "rate in Hz (0 < rate_hz <= 100000)")
    dev = dataclasses.replace(dev, imu=dataclasses.replace(dev.imu, rate_hz=rate))
    if link in ("serial", "mavlink"):  # mavlink: a serial port or udpin:HOST:PORT
        address = imu.get("port", str)
    else:
        address = {"interface": imu.get("interface", str), "channel": imu.get("channel", str)}
        if imu.has("bitrate"):
            address["bitrate"] = imu.get("bitrate", int)
        if imu.has("id_offset"):  # this unit's node: its ids on the shared bus
            from drivers.can_imu import FrameLayout

            offset = imu.get("id_offset", int)
            dev = dataclasses.replace(dev, can=dataclasses.replace(dev.can, id_offset=offset))
            try:
                FrameLayout(dev)
            except ProfileError as exc:
                raise imu.error("id_offset", str(exc).split(": ", 1)[-1]) from None
    mounting = None
    if serial is None:
        serial = imu.get("unit_serial", str)
        if not SERIAL.match(serial):
            raise imu.error("unit_serial", f"{serial!r}: 1-64 letters, digits, '.', '_' or '-' "
                                           "(it names the unit's calibration file)")
        if imu.has("mounting"):
            mounting = np.array(imu.get_rows("mounting", 3, 3), float)
            if not np.allclose(mounting @ mounting.T, np.eye(3), atol=1e-6) or \
                    np.linalg.det(mounting) < 0:
                raise imu.error("mounting", "must be a rotation (plate frame -> unit frame, 3 "
                                            "orthonormal rows, determinant +1)")
    imu.finish()
    return BenchUnit(serial, link, dev, address, unit_stream(k), mounting)


def _spins(fields: dict, proto, path) -> int:
    """[protocol] spins of a rotary session on a two-axis table: the spins of the position axis
    after `positions` positions on the cone (default 1: without one the directions lie on one
    cone, docs/protocols.md "Two-axis sessions"); 0 for a one-axis table, a fixture, or a [plan]
    (whose plan chooses them)."""
    from drivers.profile import ProfileError

    table = fields["table_map"]
    planned = "plan" in fields["tables"]
    if not table.two_axis or "fixture" in fields or planned:
        if proto.has("spins"):
            raise ProfileError(f"{path}: [protocol] spins: only a two-axis table (without a "
                               "[fixture]) spins its position axis, as many times as [plan] "
                               "says when there is one; remove the key")
        return 0
    _rate_mode(table, path)
    spins = proto.get("spins", int, default=1)
    if spins < 1:
        raise ProfileError(f"{path}: [protocol] spins = {spins}: a two-axis session needs at "
                           "least one spin of the position axis")
    return spins


def _rate_mode(table, path) -> None:
    """Refuse a two-axis register map `table` without the position axis' rate mode."""
    from drivers.profile import ProfileError

    if not table.rate_mode:
        raise ProfileError(f"{path}: the two-axis table's register map has no rate mode of the "
                           "position axis, which a two-axis session needs (positions on the rate "
                           "axis alone lie on one cone); use a profile with one, e.g. "
                           "table_two_axis (docs/devices.md)")


def _plan(fields: dict, section, channels: int, path):
    """The [plan] section's `station.protocols.planned.PlanSpec`: a two-axis table with the rate
    mode, no [fixture] (docs/protocols.md "Two-axis sessions")."""
    from drivers.profile import ProfileError
    from station.protocols.planned import PlanSpec

    if not fields["table_map"].two_axis or "fixture" in fields:
        raise ProfileError(f"{path}: [plan] plans the positions a two-axis table sets itself; "
                           "this table has no position axis or the profile has a [fixture] "
                           "(whose section plans its poses): remove the [plan] section")
    _rate_mode(fields["table_map"], path)
    return PlanSpec.from_section(section, channels)


def _device(profile, name: str) -> str:
    """A device profile named in the bench profile `profile`: a file next to it, else `name` (a
    path or a bundled profile)."""
    local = Path(profile.source).parent / name
    return str(local) if local.exists() else name


def _chamber(section, device, imu):
    """The [chamber] section's `station.protocols.thermal.ChamberSettings`, for an IMU stream
    with a temperature channel."""
    from station.protocols.thermal import ChamberSettings, temperature_column

    temperature_column(imu.units)
    return ChamberSettings.from_section(section, device)


def _table_fields(profile, table) -> dict:
    """The table's address, register map and reply timeout from the bench profile's [table]
    section `table`."""
    from drivers.profile import load_profile
    from drivers.rotary_table import TableRegisterMap

    table_profile = load_profile(_device(profile, table.get("profile", str,
                                                            default="table_modbus")))
    reply = table.get("reply_timeout", float, default=None)
    if reply is not None and not 0 < reply <= 600:
        raise table.error("reply_timeout", f"{reply!r}: give 0 < seconds <= 600 (the wall "
                                           "seconds to wait for each reply of the table)")
    return {"table_host": table.get("host", str), "table_port": table.get("port", int),
            "table_map": table_profile.section("table", TableRegisterMap.parse),
            "table_source": table_profile.source, "table_reply": reply}


def stop_table(path) -> bool:
    """Command the rotary table of the bench profile `path` to stop, before anything else is
    loaded or opened: a killed station may have left it turning (`station resume` calls it
    first). False for a bench without a [table]; TableError if the stop cannot be sent."""
    from drivers.errors import TableError
    from drivers.profile import Section, load_profile
    from drivers.rotary_table import RotaryTable

    profile = load_profile(path)
    if not isinstance(profile.tables.get("table"), dict):
        return False
    fields = _table_fields(profile, Section(profile.source, "table", profile.tables["table"]))
    table = RotaryTable(fields["table_host"], fields["table_port"], fields["table_map"],
                        timeout=fields["table_reply"])
    try:
        table.connect()
        table.stop()
    except TableError as exc:
        exc.add_note("the table may still be turning: stop it by hand")
        raise
    finally:
        table.close()
    return True


def _settings(kind: str, proto, path) -> dict:
    """{"settings": the protocol's settings dataclass} from the [protocol] keys named as its
    fields (lists for tuple fields)."""
    from drivers.profile import ProfileError
    from station.protocols import KINDS

    cls = KINDS[kind].entry("settings")
    given = {}
    for f in dataclasses.fields(cls):
        if proto.has(f.name):
            kind_ = type(f.default)
            given[f.name] = (proto.get_list(f.name, str) if kind_ is tuple
                             else proto.get(f.name, kind_))
    try:
        return {"settings": cls(**given)}
    except ValueError as exc:
        raise ProfileError(f"{path}: [protocol] {exc}") from None


def _layout(proto, imu, path) -> np.ndarray:
    """(3, m_acc) nominal axes of the stream's accelerometer channels: `layout`, default the
    identity for a triad."""
    from drivers.profile import ProfileError
    from station.errors import CalibrationInputError
    from station.reduce.static import accelerometer_channels

    try:
        m = len(accelerometer_channels(imu.units))
    except CalibrationInputError as exc:
        raise ProfileError(f"{path}: {exc}") from None
    default = np.eye(3).tolist() if m == 3 else None
    rows = proto.get_rows("layout", 3, m, default)
    if rows is None:
        raise ProfileError(f"{path}: [protocol] layout: missing; the device has {m} "
                           "accelerometer channels: give their nominal axes, 3 lists of "
                           f"{m} numbers (a column per channel)")
    a = np.array(rows, float)
    if np.linalg.matrix_rank(a) < 3 or np.any(np.linalg.norm(a, axis=0) == 0):
        raise ProfileError(f"{path}: [protocol] layout: the axes must span 3 dimensions and each "
                           "column be non-zero")
    return a


def bench_clock(bench: BenchProfile, start: float | None = None):
    """The clock of a session on `bench`: `station twin`'s lockstep clock when the profile names
    it ([bench] lockstep: `drivers.clock_link`), else the wall clock, scaled by clock_speed; a
    resumed session's goes on at `start` (after its last recorded instant)."""
    from drivers.clock import ScaledClock, WallClock

    if bench.lockstep is not None:
        from drivers.clock_link import connect

        return connect(bench.lockstep, start)
    if start is None:
        return WallClock() if bench.clock_speed == 1.0 else ScaledClock(bench.clock_speed)
    return ScaledClock(bench.clock_speed, start=start)


def record(bench: BenchProfile, out, operator, live: bool = False,
           extra: dict | None = None, clock=None, view=None) -> dict:
    """Run the bench's protocol (its kind's acquire, `station.protocols.KINDS`) with its devices
    and `operator` into the session `out`. live: show the live view (station.acquire.live_view)
    while recording, for kinds that have one; view: another watcher of the session
    (`station.acquire.watching`: the browser's); extra: more metadata (a thermal soak's); clock:
    the session's (default `bench_clock`; a thermal campaign's own)."""
    from drivers.profile import load_profile
    from station.acquire.live_view import LiveView
    from station.protocols import KINDS
    from station.session import Session, StreamSpec

    start = time.perf_counter()
    clock = clock or bench_clock(bench)
    spec = StreamSpec.from_profile(bench.imu.imu)
    metadata = {"unit_serial": bench.unit_serial,
                "bench": {"profile": bench.source, "tables": bench.tables},
                "profiles": {u.stream: load_profile(u.imu.source).tables
                             for u in bench.units}, **(extra or {})}
    if bench.plate:
        metadata["units"] = [u.session_unit().to_json() for u in bench.units]
    kind = KINDS[bench.protocol]
    with bench_devices(bench, clock, kind.table) as (imu, table), \
            plate_drivers(bench, clock) as others:
        kind.entry("acquire")(bench, imu, table, out, operator, clock, spec, metadata,
                              LiveView(clock, watchdog=watchdog_shown(bench)) if live else view,
                              **others)
    with Session.open(out) as session:
        done = session.last_completed_position()
        samples = {u.stream: len(session.stream(u.stream, columns=("seq",)).seq)
                   for u in bench.units}
        meta = session.metadata  # a fixture's plan fixes the count
        planned = len(meta.get("fixture_poses") or meta.get("axes") or ()) or bench.positions
    plate = {"units": [{"unit_serial": u.unit_serial, "stream": u.stream,
                        "samples": samples[u.stream]} for u in bench.units]} if bench.plate else {}
    return {"session": str(out), "unit_serial": bench.unit_serial, "protocol": bench.protocol,
            "positions_done": 0 if done is None else done + 1, "positions_planned": planned,
            "samples": sum(samples.values()), **plate,
            "wall_seconds": time.perf_counter() - start}


def watchdog_shown(bench: BenchProfile):
    """What the live view shows of the table's watchdog: its spec, False for none, None without
    a table."""
    return None if bench.table_map is None else (bench.table_map.watchdog or False)


def resume(bench: BenchProfile, path, operator, clock=None, view=None) -> int:
    """Continue the session `path` (killed, paused or aborted; a kind of `station.protocols.KINDS`
    with a `resume`) with the devices of `bench` from the position after its last completed one;
    returns that position (the number of positions when none was left).

    The session's own protocol settings and axes rule (the profile's [protocol] is not used); the
    profile must be for the same unit and give the same stream (channels, units, scales, rate),
    else the resumed counts would not mean what the recorded ones do. The clock continues after
    the session's last recorded instant (a reboot restarts the host's monotonic time), and a
    rotary table is commanded to stop as soon as it is connected (a killed station may have left it
    turning; `station resume` stops it even earlier, `stop_table`); a lockstep `clock` (a thermal
    campaign's) is moved forward to that instant. The IMU ports (every unit's)
    are opened last, once the session file is resumed, right before the recorder reads them: a
    port open and unread meanwhile starts the segment with a backlog (docs/protocols.md
    "Margins"). `view`: who watches the session (`station.acquire.watching`), or None.
    """
    from station.session import Session, SessionWriter, StreamSpec
    from station.session.units import recorded_units

    with Session.open(path) as session:
        metadata, specs, end = session.metadata, session.specs, session.last_instant()
        units = recorded_units(metadata, specs, path)
    kind = _check_same_bench(bench, path, metadata, specs.get("imu"),
                             StreamSpec.from_profile(bench.imu.imu))
    _check_same_units(bench, path, units, specs)
    if kind.table:  # the recorded protocol checked before any device is opened
        from station.protocols.rotary import RotaryProtocol

        RotaryProtocol.from_metadata(metadata, None, None, None)
    if clock is None or clock.realtime:
        clock = bench_clock(bench, start=end + 1.0)
    else:
        clock.advance_to(end + 1.0)
    with (table_driver(bench, clock) if kind.table else contextlib.nullcontext() as table,
          SessionWriter.resume(path, clock=clock) as writer,
          imu_driver(bench, clock) as imu, plate_drivers(bench, clock) as others):
        return kind.entry("resume")(writer, metadata, imu, table, operator, clock, view=view,
                                    **others)


def _check_same_bench(bench: BenchProfile, path, metadata: dict, recorded, spec):
    """The session's kind (`station.protocols.KINDS`) when the bench profile can continue it; else
    InputError naming the difference: a kind that does not resume, another protocol, another
    unit, another stream."""
    from station.protocols import lookup

    name = metadata.get("protocol")
    kind = lookup(name, "resume", f"{path} holds a {name!r} session", "station resume")
    if bench.protocol != name:
        raise InputError(f"{path} holds a {name!r} session and the profile a "
                         f"{bench.protocol!r} one: resume with the bench profile of that kind")
    if metadata.get("unit_serial") != bench.unit_serial:
        raise InputError(f"{path} recorded unit {metadata.get('unit_serial')!r}, "
                         f"the profile is for {bench.unit_serial!r}: mount the same unit, "
                         "or use its bench profile")
    if recorded is None:
        raise InputError(f"{path} has no imu stream to continue")
    differ = _stream_differences(recorded, spec)
    if differ:
        raise InputError(f"the profile's IMU stream differs from the recorded one in {differ}: "
                         "resume with the device profile and rate the session was recorded with")
    return kind


def _stream_differences(recorded, spec) -> list:
    """The fields of a recorded stream's StreamSpec that a profile's differs in (counts that
    would not mean what the recorded ones do)."""
    return [name for name in ("channels", "units", "counts_per_unit", "rate_hz")
            if getattr(recorded, name) != getattr(spec, name)]


def _check_same_units(bench: BenchProfile, path, units: list, specs: dict) -> None:
    """InputError unless the bench's units are the session's (serials and streams, in order;
    none for a one-unit session and bench) and each unit's stream the recorded one."""
    from station.session import StreamSpec

    recorded = [(u.stream, u.unit_serial) for u in units]
    mounted = [(u.stream, u.unit_serial) for u in bench.units] if bench.plate else []
    if recorded != mounted:
        raise InputError(f"{path} recorded the units {recorded or 'of one [imu]'}, the profile "
                         f"has {mounted or 'one [imu]'}: resume with the bench profile the "
                         "session was recorded with")
    for unit in bench.units[1:]:
        differ = _stream_differences(specs[unit.stream], StreamSpec.from_profile(unit.imu.imu))
        if differ:
            raise InputError(f"unit {unit.unit_serial}: the profile's IMU stream differs from "
                             f"the recorded one in {differ}: resume with the device profile and "
                             "rate the session was recorded with")


@contextlib.contextmanager
def plate_drivers(bench: BenchProfile, clock):
    """{"others": {stream: opened driver}} of the bench's units after the first (a plate of
    several units), {} for one unit: the keyword the rotary protocol takes; closed on exit."""
    from drivers import open_imu

    if not bench.plate:
        yield {}
        return
    with contextlib.ExitStack() as stack:
        yield {"others": {u.stream: stack.enter_context(open_imu(u.link, u.address, u.imu, clock))
                          for u in bench.units[1:]}}


@contextlib.contextmanager
def imu_driver(bench: BenchProfile, clock):
    """The bench's IMU driver, opened; closed on exit."""
    from drivers import open_imu

    with open_imu(bench.link, bench.imu_address, bench.imu, clock) as imu:
        yield imu


@contextlib.contextmanager
def bench_devices(bench: BenchProfile, clock, table: bool):
    """(imu, table) drivers of the bench, opened (table None unless `table`), the table first;
    closed on exit."""
    with contextlib.ExitStack() as stack:
        table = stack.enter_context(table_driver(bench, clock)) if table else None
        yield stack.enter_context(imu_driver(bench, clock)), table


@contextlib.contextmanager
def table_driver(bench: BenchProfile, clock):
    """The bench's rotary table driver, connected and commanded to stop (a killed station may
    have left it turning), its watchdog fed while held (`station.acquire.watchdog.fed`);
    stopped and closed on exit."""
    from drivers.rotary_table import RotaryTable
    from station.acquire.watchdog import fed

    with RotaryTable(bench.table_host, bench.table_port, bench.table_map,
                     timeout=bench.table_reply, clock=clock) as table:
        table.stop()
        with fed(table):
            yield table
