"""`station record`: a live rotary-table session with the devices of a bench profile.

The bench profile (TOML) says where the devices are and how to run the protocol:

    [bench]
    unit_serial = "SN42"          # serial number of the unit under calibration
    clock_speed = 1.0             # optional; > 1 only against `station twin --speed`

    [imu]
    link = "serial"               # or "can"
    profile = "imu12_serial"      # device profile: path (relative to this file) or bundled name
    port = "/dev/ttyUSB0"         # serial: device path or pyserial URL
    # interface = "socketcan"     # can: python-can interface, channel and optional bitrate
    # channel = "can0"
    # rate_hz = 200.0             # optional: overrides the device profile's sample rate

    [table]
    host = "192.168.0.50"         # Modbus TCP rotary table
    port = 502
    profile = "table_modbus"      # register map: path or bundled name

    [protocol]
    positions = 20                # any other key: a field of RotarySettings (rate, static, ...)

The technician follows the prompts (Enter when the unit is mounted; Ctrl-D or Ctrl-C aborts and
stops the table). The station runs the rotary protocol (`station.protocols.rotary`) through the
recorder into a crash-safe session file; `--solve` then writes its calibration file as
`station solve` does. Examples of bench profiles: drivers/profiles/bench_*.toml; `station twin`
writes one for its virtual devices.
"""

import argparse
import contextlib
import dataclasses
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser(
        "record", help="record a rotary-table session with the devices of a bench profile",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n  station record --profile bench.toml --out sessions/SN42.h5\n"
               "  station twin --speed 40 --profile-out twin.toml &   # then:\n"
               "  station record --profile twin.toml --out twin.h5 --solve --json")
    p.add_argument("--profile", type=Path, required=True, help="bench profile (TOML)")
    p.add_argument("--out", type=Path, help="session file to create (default: "
                   "sessions/<unit serial>-<date>.h5)")
    p.add_argument("--solve", action="store_true",
                   help="solve the session afterwards into <session>.cal.json")
    p.add_argument("--live", action="store_true",
                   help="show the live view (phase, windows, table, link) while recording")
    p.add_argument("--json", action="store_true", help="machine-readable summary")
    p.set_defaults(run=run)


@dataclass(frozen=True)
class BenchProfile:
    """A parsed bench profile; `imu` is a SerialImuProfile or CanProfile with the rate applied."""

    source: str
    unit_serial: str
    clock_speed: float
    link: str
    imu: object
    imu_address: dict  # serial: {"port"}; can: {"interface", "channel", "bitrate"?}
    table_host: str
    table_port: int
    table_map: object
    table_source: str  # the register map's profile file
    positions: int
    settings: object  # RotarySettings
    tables: dict  # the TOML tables, recorded in the session's metadata

    @classmethod
    def load(cls, path) -> "BenchProfile":
        """Read and check a bench profile; `drivers.profile.ProfileError` names any problem."""
        from drivers.can_imu import CanProfile
        from drivers.profile import ProfileError, Section, SerialImuProfile, load_profile
        from drivers.rotary_table import TableRegisterMap
        from station.protocols.rotary import RotarySettings

        profile = load_profile(path)
        base = Path(profile.source).parent

        def device(name: str) -> str:
            local = base / name
            return str(local) if local.exists() else name

        def section(name: str) -> Section:
            table = profile.tables.get(name)
            if not isinstance(table, dict):
                raise ProfileError(f"{path}: no [{name}] section; see `station record --help`")
            return Section(profile.source, name, table)

        unknown = sorted(set(profile.tables) - {"bench", "imu", "table", "protocol"})
        if unknown:
            raise ProfileError(f"{path}: unknown sections {unknown}; a bench profile has [bench], "
                               "[imu], [table] and [protocol]")
        bench, imu, table, proto = (section(n) for n in ("bench", "imu", "table", "protocol"))
        serial = bench.get("unit_serial", str)
        speed = bench.get("clock_speed", float, default=1.0)
        if not serial or not speed > 0:
            raise ProfileError(f"{path}: [bench] needs a non-empty unit_serial and a positive "
                               "clock_speed")
        link = imu.get("link", str, choices=("serial", "can"))
        loader = SerialImuProfile if link == "serial" else CanProfile
        dev = loader.load(device(imu.get("profile", str)))
        rate = imu.get("rate_hz", float, default=dev.imu.rate_hz)
        dev = dataclasses.replace(dev, imu=dataclasses.replace(dev.imu, rate_hz=rate))
        if link == "serial":
            address = {"port": imu.get("port", str)}
        else:
            address = {"interface": imu.get("interface", str), "channel": imu.get("channel", str)}
            if imu.has("bitrate"):
                address["bitrate"] = imu.get("bitrate", int)
        host, port = table.get("host", str), table.get("port", int)
        table_profile = load_profile(device(table.get("profile", str, default="table_modbus")))
        table_map = table_profile.section("table", TableRegisterMap.parse)
        positions = proto.get("positions", int)
        kinds = {f.name: type(f.default) for f in dataclasses.fields(RotarySettings)}
        given = {k: proto.get(k, kind) for k, kind in kinds.items() if proto.has(k)}
        try:
            settings = RotarySettings(**given)
        except ValueError as exc:
            raise ProfileError(f"{path}: [protocol] {exc}") from None
        for s in (bench, imu, table, proto):
            s.finish()
        if positions < 1:
            raise ProfileError(f"{path}: [protocol] positions must be at least 1")
        return cls(profile.source, serial, speed, link, dev, address, host, port, table_map,
                   table_profile.source, positions, settings, profile.tables)


def run(args) -> int:
    from drivers.profile import ProfileError
    from drivers.rotary_table import TableError
    from station.calfile import CalibrationFileError
    from station.errors import CalibrationInputError
    from station.operator import ConsoleOperator, OperatorAbort
    from station.protocols.rotary import ProtocolError
    from station.recorder import RecordingError

    try:
        bench = BenchProfile.load(args.profile)
    except ProfileError as exc:
        print(f"station record: {exc}", file=sys.stderr)
        return 2
    out = args.out or Path("sessions") / f"{bench.unit_serial}-{time.strftime('%Y%m%d-%H%M%S')}.h5"
    if out.exists():
        print(f"station record: {out} exists; choose another --out", file=sys.stderr)
        return 1
    out.parent.mkdir(parents=True, exist_ok=True)
    operator = ConsoleOperator(stdout=sys.stderr if args.json else sys.stdout)
    try:
        summary = record(bench, out, operator, live=args.live)
        if args.solve:
            summary["calibration"] = solve(out)
    except KeyboardInterrupt:
        print(f"station record: interrupted; the table was stopped; {out} keeps the completed "
              "positions", file=sys.stderr)
        return 130
    except OperatorAbort as exc:
        print(f"station record: {exc}; the table was stopped", file=sys.stderr)
        return 1
    except (CalibrationInputError, CalibrationFileError, ProtocolError, RecordingError,
            TableError, OSError) as exc:
        print(f"station record: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"recorded {summary['positions_done']} of {bench.positions} positions "
              f"({summary['samples']} samples) into {out} in {summary['wall_seconds']:.1f} s")
        if args.solve:
            print(f"calibration: {summary['calibration']['calibration']} (chi2/dof "
                  f"{summary['calibration']['chi2_per_dof']:.2f})")
    return 0


def record(bench: BenchProfile, out, operator, live: bool = False) -> dict:
    """Run the rotary protocol with the bench's devices and `operator` into the session `out`.
    live: show the live view (station.live_view) while recording."""
    from drivers.profile import load_profile
    from station.clock import ScaledClock, WallClock
    from station.live_view import LiveView
    from station.protocols.rotary import RotaryProtocol, continue_session, suggested_axes
    from station.session import Session, SessionWriter, StreamSpec

    start = time.perf_counter()
    clock = WallClock() if bench.clock_speed == 1.0 else ScaledClock(bench.clock_speed)
    with devices(bench, clock) as (imu, table):
        protocol = RotaryProtocol(table, operator, clock, bench.settings,
                                  suggested_axes(bench.positions))
        metadata = {**protocol.metadata(), "unit_serial": bench.unit_serial,
                    "bench": {"profile": bench.source, "tables": bench.tables},
                    "profiles": {"imu": load_profile(bench.imu.source).tables,
                                 "table": load_profile(bench.table_source).tables}}
        spec = StreamSpec.from_profile(bench.imu.imu)
        with SessionWriter.create(out, metadata, {"imu": spec}, clock=clock) as writer:
            continue_session(writer, metadata, imu, table, operator, clock,
                             LiveView(clock) if live else None)
    with Session.open(out) as session:
        done = session.last_completed_position()
        samples = len(session.stream("imu").seq)
    return {"session": str(out), "unit_serial": bench.unit_serial,
            "positions_done": 0 if done is None else done + 1, "samples": samples,
            "wall_seconds": time.perf_counter() - start}


def solve(path) -> dict:
    """Solve the recorded session as `station solve` does; its summary."""
    from station.commands.solve import solve_session, summarise

    out = Path(path).with_suffix(".cal.json")
    cal = solve_session(path)
    cal.save(out)
    return summarise(cal, out)


@contextlib.contextmanager
def devices(bench: BenchProfile, clock):
    """(imu, table): the drivers of the bench, opened; closed (and the table stopped) on exit."""
    import can

    from drivers.can_imu import CanImu
    from drivers.rotary_table import RotaryTable
    from drivers.serial_imu import SerialImu

    with contextlib.ExitStack() as stack:
        table = stack.enter_context(RotaryTable(bench.table_host, bench.table_port,
                                                bench.table_map, clock=clock))
        if bench.link == "serial":
            imu = stack.enter_context(SerialImu(bench.imu_address["port"], bench.imu, clock))
        else:
            bus = can.Bus(**bench.imu_address)
            stack.callback(bus.shutdown)
            imu = stack.enter_context(CanImu(bus, bench.imu, clock))
        yield imu, table
