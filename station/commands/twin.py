"""`station twin`: the virtual bench's devices, for `station record` to talk to.

Starts the digital twin of a bench (the kind's twin in `station.protocols.KINDS`, from
`station.twin.served`: a `station.twin.rotary_bench.VirtualBench`): a 12-gyro unit streaming
binary frames through a pseudo-terminal, and a Modbus TCP rotary table on 127.0.0.1 whose registers
follow the simulated table's physics. The unit sits in a motorised fixture driven by the table's
controller (register map table_fixture): `station record` asks it for each position of the rotary
protocol (`station.protocols.rotary.suggested_axes`) and it mounts the unit there, so nobody
touches anything and `station record` runs the whole session without a key press. With `--cube`
the unit sits in a lettered cube on a 45-degree wedge instead: the
bench profile gets a [fixture] section, `station record` plans the fixture poses from it
(`station plan`) and the twin's fixture sets the same poses. With `--two-axis` the table is a
two-axis one (register map table_two_axis: a position axis with a rate mode) and there is no
fixture: `station record` sets each orientation itself, `--positions` angles of the position axis
spread over a turn with the rate axis spinning, then one spin of the position axis itself
(docs/protocols.md "Two-axis sessions"); the truth printed with --json then gives the unit-frame
`axes` of those positions. `--two-axis --plan` writes a [plan] section (the unit's nominal layout
and noise density) into the profile: `station record` then sets the angles and spins it plans (at
most `--positions` positions; `station plan` prints them), and the truth's `axes` are theirs.
With `--units N` the table carries a plate of N units (serial links),
each with its own truth, its fixed mounting on the plate and its own pty; the profile lists them as
`[[imu]]` tables (docs/protocols.md "Several units on one table") and the truth gives each unit's
(with --two-axis the plate sits on the position axis and each unit's `axes` are in its frame).

`--protocol iron` and `--protocol static` start the virtual hand bench instead
(`station.twin.hand_bench`): an accelerometer unit on a serial pty, no table, and a technician who
turns it on a 20 s metronome through the protocol's sequence (static: the guided poses; iron: a
re-mounting, then the six faces, per mounting), starting when the station opens the port (in
lockstep time: at clock 0, time standing still until `station record` takes part). The technician
does not hear the station; with `--speed` `station record` must keep up (it does with the default
5 s hold), and it records the turns in order.

It prints the devices' addresses and writes a bench profile pointing at them (`--profile-out`),
then runs until Ctrl-C or `--lifetime` wall seconds. A device can be lost on the real wire and
brought back while the twin runs: SIGUSR1 unplugs the IMU (its pty is closed; the same port comes
back at the next SIGUSR1), SIGUSR2 silences the rotary table (its Modbus server stops answering;
again at the next SIGUSR2; the profile's [table] reply_timeout, `--table-reply`, is how long the
station waits for each reply: in lockstep 30 wall s unless given), e.g. `kill -USR1 <twin pid>`: to
try `station record`'s reconnection, pause and `station resume`. Every bench runs in lockstep time
by default: the twin serves its stepped clock on a Unix socket named in the profile ([bench]
lockstep), and `station record` takes part in it, so the session is the same on any host and runs
as fast as the host allows (`drivers.clock_link`). `--speed` gives a real-time clock instead, that
many times faster than the wall (the profile tells `station record` the same speed): what the lag,
silence and reconnect guards need. With --json, the truth (sensitivity matrix, biases, mountings)
is printed as JSON when the twin stops. A virtual device that stops on an error of its own (its
simulation, not a signal) ends the twin at once: its error line names the device and the error,
e.g. `station twin: the serial IMU twin stopped: ValueError: ...` (exit code 1;
`drivers.twins.failure`).

`--link mavlink` (with `--protocol static`) serves the hand bench's triad as a flight controller
speaking MAVLink (`drivers.twins.mavlink.MavlinkTwin`: HEARTBEAT at 1 Hz, SCALED_IMU with the
accelerometers and a gyro triad at the rate asked by the station's SET_MESSAGE_INTERVAL) on a
pty, or with `--udp` over UDP: it sends to 127.0.0.1:PORT, the profile's
`port = "udpin:127.0.0.1:PORT"` where `station record` listens. The technician's first turn is
timed from the station's stream request.

The CAN twin (a python-can virtual channel) is visible only inside one process:
`station.twin.served.BenchTwin("can")` serves in-process tests and the demo, not a separate
`station record`.
"""

import contextlib
import json
import signal
from pathlib import Path

from station.acquire import interrupts
from station.protocols import KINDS, kinds_with


def register(p) -> None:
    """The options, description and examples of this subcommand, on its parser `p`."""
    p.description = __doc__
    p.epilog = (
        "examples:\n  station twin --profile-out bench.toml\n"
        "  station twin --speed 40 --positions 12 --profile-out bench.toml --json\n"
        "  station twin --protocol static --speed 20 --profile-out hand.toml\n"
        "  station twin --protocol static --link mavlink --udp --profile-out fc.toml\n"
        "  station twin --cube --speed 40 --profile-out cube.toml   # fixture poses, planned\n"
        "  station twin --two-axis --speed 40 --positions 8 --profile-out two_axis.toml\n"
        "  station twin --two-axis --plan --speed 40 --profile-out planned.toml   # [plan]\n"
        "  station twin --units 3 --speed 40 --positions 8 --profile-out plate.toml   # 3 units"
    )
    p.add_argument("--profile-out", type=Path, default=Path("twin_bench.toml"),
                   help="bench profile to write (default twin_bench.toml; overwritten)")
    p.add_argument("--protocol", choices=kinds_with("twin"), default="rotary",
                   help="the bench: rotary table (12 gyros, default), right-angle iron (4 "
                        "accelerometers) or free static poses by hand (accelerometer triad)")
    p.add_argument("--positions", type=int, default=20,
                   help="positions of the protocol the fixture follows: rotary positions or "
                        "static poses (default 20)")
    p.add_argument("--cube", action="store_true",
                   help="rotary or static: the unit sits in a lettered cube, set on the table "
                        "or a 45-degree wedge; the profile gets a [fixture] section and the "
                        "fixture (or technician) follows the plan `station record` makes from it "
                        "(rotary: at most --positions positions)")
    p.add_argument("--two-axis", action="store_true",
                   help="rotary: a two-axis table (position axis with a rate mode, profile "
                        "table_two_axis) that sets every orientation itself; no fixture")
    p.add_argument("--plan", action="store_true",
                   help="--two-axis: the profile gets a [plan] section; `station record` sets "
                        "the angles and spins it plans (at most --positions positions)")
    p.add_argument("--units", type=int, default=1,
                   help="rotary: units on one plate on the table (default 1), each with its own "
                        "truth (seed [SEED, 3, k]), mounting on the plate and pty; the profile "
                        "lists them as [[imu]] tables (SIGUSR1 unplugs the first)")
    p.add_argument("--chamber", action="store_true",
                   help="rotary: the unit streams its temperature (imu12_serial_temp) from inside "
                        "a thermal chamber twin (Modbus TCP on 127.0.0.1) that sets its biases "
                        "and scale factors; the profile gets a [chamber] section, so `station "
                        "record` records a thermal campaign (SIGHUP silences the chamber)")
    p.add_argument("--link", choices=("serial", "mavlink"), default="serial",
                   help="static: how the unit streams: binary serial frames (default) or MAVLink "
                        "SCALED_IMU, as a flight controller")
    p.add_argument("--udp", action="store_true",
                   help="--link mavlink: over UDP on 127.0.0.1 instead of a pty")
    p.add_argument("--mountings", type=int, default=2,
                   help="iron: mountings, each followed by the six faces (default 2)")
    p.add_argument("--speed", type=float, default=None,
                   help="a real-time clock this many times faster than the wall (simulated s per "
                        "wall s); default: lockstep time with `station record`, the same session "
                        "on any host")
    p.add_argument("--spikes", metavar="POSITIONS|CHANCE",
                   help="rotary (and --chamber): a fault knob, spiky windows in the first attempt "
                        "at these positions (1-based over the twin's life, e.g. 2,9: a campaign "
                        "of 6 positions a soak, position 3 of soak 2 is 9) or, with a decimal "
                        "point, at each position with this chance (e.g. 0.1); `station record` "
                        "records them again (docs/simulator.md, docs/protocols.md \"Redo, do not "
                        "warn\")")
    p.add_argument("--seed", type=int, default=1, help="seed of the simulated unit (default 1)")
    p.add_argument("--rate-hz", type=float, default=200.0, help="IMU sample rate (default 200)")
    p.add_argument("--lifetime", type=float, default=3600.0,
                   help="wall seconds after which the twin stops by itself (default 3600)")
    p.add_argument("--table-log", type=Path,
                   help="rotary: append each write the table accepts to this file, one line "
                        "'<CLOCK_MONOTONIC s> <address> <values>' (to time a station's commands)")
    p.add_argument("--table-reply", type=float, metavar="SECONDS",
                   help="rotary: the profile's [table] reply_timeout, the wall seconds `station "
                        "record` waits for each reply of the table (default: the driver's, 30 s "
                        "in lockstep, 0.5 s with --speed); a few seconds find a silent table "
                        "(SIGUSR2) quickly in lockstep")
    p.add_argument("--json", action="store_true",
                   help="machine-readable addresses, and the truth when stopping")
    p.set_defaults(run=run)


def _spikes(text: str | None):
    """--spikes: None, a list of positions ("2,9") or, with a decimal point, a chance ("0.1");
    InputError naming the option otherwise (`station.sim.spikes.check_spikes`)."""
    from station.errors import InputError
    from station.sim.spikes import check_spikes

    if text is None:
        return None
    try:
        spikes = float(text) if "." in text else [int(p) for p in text.split(",")]
        check_spikes(spikes)
    except (ValueError, InputError):
        raise InputError(f"--spikes {text!r}: give positions from 1 (e.g. 2,9) or a chance "
                         "from 0 to 1 with a decimal point (e.g. 0.1)") from None
    return spikes


def run(args) -> int:
    from station.commands import given_values
    from station.errors import InputError
    from station.limits import positive

    if args.positions < 1 or args.mountings < 1 or not args.lifetime > 0 or args.units < 1 \
            or not (args.speed is None or 0 < args.speed < float("inf")):
        raise InputError("--positions, --mountings, --units, --speed and --lifetime must be "
                         "positive")
    if args.units > 1 and (args.protocol != "rotary" or args.chamber):
        raise InputError("--units: several units share the rotary table (--protocol rotary, "
                         "no --chamber)")
    tabled = [name for name, given in (("--table-log", args.table_log),
                                       ("--two-axis", args.two_axis),
                                       ("--table-reply", args.table_reply is not None)) if given]
    if tabled and not KINDS[args.protocol].table:
        raise InputError(f"{', '.join(tabled)}: a {args.protocol} bench has no rotary table")
    if args.table_reply is not None:
        positive(args.table_reply, "--table-reply (the wait for each reply, s)", 600)
    if args.plan and not args.two_axis:
        raise InputError("--plan plans the positions of a two-axis table: give --two-axis "
                         "(--cube plans a fixture's poses)")
    if args.chamber and (args.protocol != "rotary" or args.cube or args.two_axis
                         or args.link != "serial"):
        raise InputError("--chamber serves the rotary bench with its serial IMU (no --cube, no "
                         "--two-axis)")
    args.spikes = _spikes(args.spikes)
    if args.spikes is not None and (args.protocol != "rotary" or args.units > 1):
        raise InputError("--spikes spoils the windows of one unit on the rotary table "
                         "(--protocol rotary, --units 1)")
    with given_values():
        if args.chamber:
            from station.twin.thermal import thermal_twin

            twin = thermal_twin(args)
        else:
            twin = KINDS[args.protocol].entry("twin")(args)
    if args.table_log:
        twin.bench.table_twin.write_log = args.table_log
    twin.bench.table_reply = args.table_reply
    stop = interrupts.Wake()
    devices = {signal.SIGUSR1: "imu", signal.SIGUSR2: "table"}
    if not KINDS[args.protocol].table:
        del devices[signal.SIGUSR2]
    if args.chamber:
        devices[signal.SIGHUP] = "chamber"
    previous = {number: signal.getsignal(number) for number in (signal.SIGTERM, *devices)}
    signal.signal(signal.SIGTERM, stop.set)
    twin.failures.on_failure = lambda words: stop.set()  # a twin stopped: end with its error
    try:
        with twin:
            for number, device in devices.items():
                signal.signal(number, lambda *_, device=device: twin.toggle(device))
            args.profile_out.write_text(twin.profile_text(f"SIM-{args.seed}"))
            info = {**twin.addresses(), "profile": str(args.profile_out.resolve())}
            # Ctrl-C is the way to stop the twin from the moment its addresses are out
            with contextlib.suppress(KeyboardInterrupt):
                if args.json:
                    print(json.dumps(info), flush=True)
                else:
                    table = info.get("table")
                    imus = info.get("units", [info["imu"]])
                    print("".join(f"{imu['link']} IMU twin on {imu['port']} "
                                  f"({imu['rate_hz']:g} Hz)\n" for imu in imus)
                          + (f"Modbus table twin on 127.0.0.1:{table['port']}\n" if table else "")
                          + (f"Modbus thermal chamber twin on 127.0.0.1:{info['chamber']['port']}\n"
                             if args.chamber else "")
                          + f"bench profile: {info['profile']}\n"
                          f"  station record --profile {args.profile_out}\n"
                          "Ctrl-C stops the twin.", flush=True)
                stop.wait(args.lifetime)
            interrupts.handled()  # the Ctrl-C that ends the twin: a next one breaks its shutdown
            truth = twin.truth()
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        stop.close()  # the twin stopped, the handler put back: nothing calls stop.set() now
    if args.json:
        print(json.dumps({"truth": truth}), flush=True)
    return 0
