"""`station twin`: the virtual bench's devices, for `station record` to talk to.

Starts the digital twin of a bench (`station.virtual_bench.VirtualBench`): a 12-gyro unit streaming
binary frames through a pseudo-terminal, and a Modbus TCP rotary table on 127.0.0.1 whose registers
follow the simulated table's physics. The unit sits in a motorised fixture that turns it to the
next position of the rotary protocol (`station.protocols.rotary.suggested_axes`) each time the
table is commanded to stop, so a technician has nothing to turn: pressing Enter at each prompt of
`station record` runs the whole session. Restart the twin for each new session (the fixture counts
the stops).

It prints the devices' addresses and writes a bench profile pointing at them (`--profile-out`),
then runs until Ctrl-C or `--lifetime` wall seconds. `--speed` makes the twin's clock run faster
than the wall; the profile tells `station record` to use the same speed. With --json, the truth
(sensitivity matrix, biases, mountings) is printed as JSON when the twin stops.

The CAN twin (a python-can virtual channel) is visible only inside one process: `BenchTwin("can")`
serves in-process tests and the demo, not a separate `station record`.
"""

import argparse
import json
import os
import signal
import sys
import termios
import threading
import time
from pathlib import Path
from typing import Self

import numpy as np

from station.protocols.rotary import instruction, suggested_axes


def register(sub) -> None:
    p = sub.add_parser(
        "twin", help="run the virtual bench's devices (serial IMU + Modbus table) for `record`",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n  station twin --profile-out bench.toml\n"
               "  station twin --speed 40 --positions 12 --profile-out bench.toml --json")
    p.add_argument("--profile-out", type=Path, default=Path("twin_bench.toml"),
                   help="bench profile to write (default twin_bench.toml; overwritten)")
    p.add_argument("--positions", type=int, default=20,
                   help="positions of the protocol the fixture follows (default 20)")
    p.add_argument("--speed", type=float, default=1.0,
                   help="clock speed, simulated seconds per wall second (default 1)")
    p.add_argument("--seed", type=int, default=1, help="seed of the simulated unit (default 1)")
    p.add_argument("--rate-hz", type=float, default=200.0, help="IMU sample rate (default 200)")
    p.add_argument("--lifetime", type=float, default=3600.0,
                   help="wall seconds after which the twin stops by itself (default 3600)")
    p.add_argument("--json", action="store_true",
                   help="machine-readable addresses, and the truth when stopping")
    p.set_defaults(run=run)


class BenchTwin:
    """A `VirtualBench` whose unit is re-mounted by a fixture at every table stop.

    positions : the fixture follows `suggested_axes(positions)`, as the rotary protocol does
    """

    def __init__(self, imu: str = "serial", seed: int = 1, speed: float = 1.0,
                 positions: int = 20, rate_hz: float = 200.0, lifetime: float = 3600.0):
        from station.virtual_bench import VirtualBench

        self.bench = VirtualBench(imu, seed=seed, speed=speed, rate_hz=rate_hz, remount_time=0.0,
                                  lifetime=lifetime)
        self.seed = seed
        self.axes = suggested_axes(positions)
        self.mounted = 0
        self.error = None
        self._port_fd = None  # the pty watched for the station's open, until it happens
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._fixture, name="fixture", daemon=True)

    def start(self) -> Self:
        """Serve the table; the serial IMU streams from the moment the station opens its port
        (a twin streaming to nobody would hand the station a stale backlog, computed late)."""
        from drivers.twin_serial import SerialTwin

        self._mount()
        b = self.bench
        if b.kind == "serial":
            b.table_twin.start()
            b.imu_twin = SerialTwin(b.profile, b.mounted, b.clock, max_lag=np.inf)
            self._port_fd = os.open(b.imu_twin.port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            self._idle_attrs = termios.tcgetattr(self._port_fd)
        else:
            b.start()
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        if self._port_fd is not None:
            os.close(self._port_fd)
            self._port_fd = None
        self.bench.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def addresses(self) -> dict:
        """Where the station finds the devices."""
        b = self.bench
        imu = {"link": "serial", "port": b.imu_twin.port} if b.kind == "serial" else \
            {"link": "can", "interface": "virtual", "channel": b.can_channel}
        return {"imu": {**imu, "profile": b.profile.source, "rate_hz": b.profile.imu.rate_hz},
                "table": {"host": "127.0.0.1", "port": b.table_twin.port,
                          "profile": "table_modbus"},
                "clock_speed": b.clock.speed}

    def profile_text(self, unit_serial: str | None = None) -> str:
        """A bench profile (`station record --profile`) pointing at these devices."""
        a = self.addresses()
        serial = unit_serial or f"SIM-{self.seed}"
        imu = "\n".join(f"{k} = {_toml(v)}" for k, v in a["imu"].items())
        table = "\n".join(f"{k} = {_toml(v)}" for k, v in a["table"].items())
        return (f"# Bench profile of the virtual bench (station twin), written {time.ctime()}.\n"
                f"[bench]\nunit_serial = {_toml(serial)}\nclock_speed = {a['clock_speed']!r}\n\n"
                f"[imu]\n{imu}\n\n[table]\n{table}\n\n"
                f"[protocol]\npositions = {len(self.axes)}\n")

    def truth(self) -> dict:
        """The simulated unit and the mountings made (JSON-ready)."""
        t = self.bench.truth()
        return {"a": t.a.tolist(), "bias": t.bias.tolist(), "a_nominal": t.a_nominal.tolist(),
                "orientations": t.orientations.tolist(), "mounted": self.mounted}

    def _mount(self) -> None:
        j = self.mounted % len(self.axes)
        self.bench.technician.wait(instruction(j, len(self.axes), self.axes[j]))
        self.mounted += 1

    def _port_opened(self) -> bool:
        """True (once) when a program configured the pty's terminal, as pyserial does on open."""
        if termios.tcgetattr(self._port_fd) == self._idle_attrs:
            return False
        os.close(self._port_fd)
        self._port_fd = None
        return True

    def _fixture(self) -> None:
        """Start the serial stream when the station opens the port; re-mount the unit at each
        running -> stopped transition of the table's run command."""
        try:
            running = False
            while not self._stop.wait(0.002):
                if self._port_fd is not None and self._port_opened():
                    self.bench.imu_twin.start()
                now = self.bench.table.state().running
                if running and not now:
                    self._mount()
                running = now
        except Exception as exc:  # noqa: BLE001 - reported by the command
            self.error = exc


def run(args) -> int:
    if args.positions < 1 or not args.speed > 0 or not args.lifetime > 0:
        print("station twin: --positions, --speed and --lifetime must be positive",
              file=sys.stderr)
        return 2
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    twin = BenchTwin("serial", args.seed, args.speed, args.positions, args.rate_hz,
                     args.lifetime)
    try:
        with twin:
            args.profile_out.write_text(twin.profile_text(f"SIM-{args.seed}"))
            info = {**twin.addresses(), "profile": str(args.profile_out.resolve())}
            if args.json:
                print(json.dumps(info), flush=True)
            else:
                print(f"serial IMU twin on {info['imu']['port']} ({info['imu']['rate_hz']:g} Hz)\n"
                      f"Modbus table twin on 127.0.0.1:{info['table']['port']}\n"
                      f"bench profile: {info['profile']}\n"
                      f"  station record --profile {args.profile_out}\n"
                      "Ctrl-C stops the twin.", flush=True)
            try:
                stop.wait(args.lifetime)
            except KeyboardInterrupt:
                pass
            truth = twin.truth()
    finally:
        signal.signal(signal.SIGTERM, previous)
    if twin.error is not None:
        print(f"station twin: the fixture failed: {twin.error}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps({"truth": truth}), flush=True)
    return 0


def _toml(value) -> str:
    """A TOML scalar (strings JSON-quoted: a valid TOML basic string)."""
    if isinstance(value, str):
        return json.dumps(value)
    return repr(float(value)) if isinstance(value, float) else repr(int(value))
