"""The devices' watchdogs, the hard way (issue 30's acceptance): a station that dies, loses its link
or hangs, and how long the table and the chamber take to stop and go safe by themselves.

For each bench kind (rotary, thermal, plate of 3 units, two-axis) `station twin --speed 1` runs in
its own process (a real-time clock: the watchdog's period is wall seconds) and `station record`
records against it. At a random moment while the table turns (thermal: while the unit soaks at
the campaign's first setpoint, the table at rest) the bench does one of:

- kill: SIGKILL of `station record`;
- link: the station's Modbus cables pulled: its table and chamber connections go through a TCP
  relay of this bench, which stops passing bytes (and lets no new connection through), as a cut
  cable does; the twin's own SIGUSR2 / SIGHUP silence every client, this bench's reader too;
- stop: SIGSTOP of `station record` (a hung host; SIGKILL after the measurement).

It then reads the twin's registers directly (a plain pymodbus client, not through the relay) every
10 ms and prints the wall seconds from the act until the table reads at rest (rate 0 on every
axis) and until the chamber's setpoint reads the watchdog's safe setpoint. Targets: the table
within 2 s, the chamber within 5 s, every time. The twin is reused across trials of its kind.

    .venv/bin/python -P bench/watchdog_kills.py [--kills 20] [--kinds rotary,thermal,...]
        [--modes kill,link,stop] [--json] [--seed 1]
"""

import argparse
import contextlib
import json
import random
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from pymodbus.client import ModbusTcpClient

from drivers.rotary_table import TableRegisterMap
from drivers.thermal_chamber import ZERO_CELSIUS, ChamberRegisterMap

STATION = [sys.executable, "-m", "station"]
KINDS = {"rotary": [], "thermal": ["--chamber", "--positions", "3", "--rate-hz", "100"],
         "plate": ["--units", "3"], "two-axis": ["--two-axis"]}
MODES = ("kill", "link", "stop")
TARGETS = {"table": 2.0, "chamber": 5.0}
START_S = 180.0  # wall seconds a session may take to turn the table (or start the soak)
WATCH_S = 15.0  # wall seconds the bench waits for the devices to act


class Relay:
    """A TCP relay 127.0.0.1:port -> target, whose `cut()` stops passing bytes both ways and lets
    no new connection through (a pulled cable); `mend()` drops the cut connections and serves
    again."""

    def __init__(self, target: int):
        self.target, self.cut_off = target, threading.Event()
        self._server = socket.create_server(("127.0.0.1", 0))
        self.port = self._server.getsockname()[1]
        self._pairs = []
        threading.Thread(target=self._accept, daemon=True).start()

    def cut(self) -> None:
        self.cut_off.set()

    def mend(self) -> None:
        for pair in self._pairs:
            for s in pair:
                with contextlib.suppress(OSError):
                    s.close()
        self._pairs.clear()
        self.cut_off.clear()

    def _accept(self) -> None:
        while True:
            client, _ = self._server.accept()
            if self.cut_off.is_set():
                self._pairs.append((client,))  # held open, never answered
                continue
            upstream = socket.create_connection(("127.0.0.1", self.target))
            self._pairs.append((client, upstream))
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pass, args=(a, b), daemon=True).start()

    def _pass(self, source, sink) -> None:
        with contextlib.suppress(OSError):
            while data := source.recv(4096):
                if not self.cut_off.is_set():
                    sink.sendall(data)


class Twin:
    """`station twin --speed 1` of one kind in its own process, a relay for each Modbus device and
    the bench profile pointing `station record` at the relays."""

    def __init__(self, kind: str, directory: Path):
        self.kind, self.profile = kind, directory / f"{kind}.toml"
        self.log = directory / f"{kind}-twin.log"  # its warnings: the watchdog's actions
        with self.log.open("w") as log:
            self.process = subprocess.Popen(
                [*STATION, "twin", "--speed", "1", "--json", "--lifetime", "7200",
                 "--profile-out", str(self.profile), *KINDS[kind]], stdout=subprocess.PIPE,
                stderr=log, text=True)
        info = json.loads(self.process.stdout.readline())
        self.table_map = TableRegisterMap.load(info["table"]["profile"])
        self.table = ModbusTcpClient("127.0.0.1", port=info["table"]["port"])
        self.relays = {"table": Relay(info["table"]["port"])}
        text = self.profile.read_text().replace(f"port = {info['table']['port']}\n",
                                                f"port = {self.relays['table'].port}\n")
        self.chamber = self.chamber_map = None
        if "chamber" in info:
            self.chamber_map = ChamberRegisterMap.load("chamber_modbus")
            self.chamber = ModbusTcpClient("127.0.0.1", port=info["chamber"]["port"])
            self.relays["chamber"] = Relay(info["chamber"]["port"])
            text = text.replace(f"port = {info['chamber']['port']}\n",
                                f"port = {self.relays['chamber'].port}\n")
        if "static =" not in text:  # a short static window: the table turns sooner
            text = text.replace("[protocol]\n", "[protocol]\nstatic = 2.0\n")
        self.profile.write_text(text)
        for client in (self.table, self.chamber):
            if client is not None and not client.connect():
                raise RuntimeError(f"cannot read the {kind} twin's registers")

    def rates(self) -> tuple:
        """The table's rate (rad/s) and, on a two-axis table, its position axis' rate."""
        m = self.table_map
        first, count = m.span
        regs = self.table.read_holding_registers(first, count=count, device_id=1).registers

        def value(name):
            return m.decode([regs[a - first] for a in m.addresses(name)], m.rate_scale)
        return (value("rate"), value("position_rate") if m.rate_mode else 0.0)

    def setpoint(self) -> float:
        """The chamber's setpoint, K."""
        m = self.chamber_map
        first, count = m.span
        regs = self.chamber.read_holding_registers(first, count=count, device_id=1).registers
        return m.decode("setpoint", [regs[a - first] for a in m.addresses("setpoint")]) \
            + ZERO_CELSIUS

    def close(self) -> None:
        self.process.send_signal(signal.SIGTERM)
        try:
            self.process.wait(30)
        except subprocess.TimeoutExpired:
            self.process.kill()


def under_way(twin: Twin, log: Path) -> bool:
    """Is the session where the trial strikes: the table turning (thermal: the soak started, as
    the station said and the chamber's setpoint shows)?"""
    if twin.chamber is not None:
        return "soak 1 of" in log.read_text() and abs(twin.setpoint() - 263.15) < 0.05
    return abs(twin.rates()[0]) > 0.5


def trial(twin: Twin, mode: str, out: Path, rng: random.Random) -> dict:
    """One record, struck by `mode` at a random moment under way; the seconds until the devices
    acted (None: not within WATCH_S)."""
    log = out.with_suffix(".log").open("w")
    record = subprocess.Popen([*STATION, "record", "--profile", str(twin.profile), "--out",
                               str(out)], stdin=subprocess.DEVNULL, stdout=log, stderr=log)
    try:
        deadline = time.monotonic() + START_S
        while not under_way(twin, out.with_suffix(".log")):
            if time.monotonic() > deadline or record.poll() is not None:
                return {"kind": twin.kind, "mode": mode, "error": "never under way"}
            time.sleep(0.05)
        time.sleep(rng.uniform(0.0, 3.0))
        rate = twin.rates()
        struck = time.monotonic()
        if mode == "kill":
            record.send_signal(signal.SIGKILL)
        elif mode == "stop":
            record.send_signal(signal.SIGSTOP)
        else:
            for relay in twin.relays.values():
                relay.cut()
        table = chamber = None
        safe = twin.chamber_map.watchdog.safe_setpoint if twin.chamber is not None else None
        while time.monotonic() < struck + WATCH_S and (table is None or (
                safe is not None and chamber is None)):
            now = time.monotonic() - struck
            if table is None and twin.rates() == (0.0, 0.0):
                table = now
            if safe is not None and chamber is None and abs(twin.setpoint() - safe) < 0.05:
                chamber = now
            time.sleep(0.01)
        row = {"kind": twin.kind, "mode": mode, "rate_at_strike": rate[0], "table_s": table,
               "chamber_s": chamber}
        if table is None or (safe is not None and chamber is None):  # what went on, for a look
            row["record_log"] = out.with_suffix(".log").read_text()[-600:]
            row["twin_log"] = twin.log.read_text()[-600:]
        return row
    finally:
        if record.poll() is None:
            record.send_signal(signal.SIGCONT)
            record.kill()
        record.wait(30)
        log.close()
        for relay in twin.relays.values():
            relay.mend()


def figures(rows: list) -> dict:
    """Per mode and device: count, median, max seconds and whether every one met the target."""
    out = {}
    for mode in MODES:
        for device in ("table", "chamber"):
            times = [r[f"{device}_s"] for r in rows if r["mode"] == mode and "error" not in r
                     and (device == "table" or r["kind"] == "thermal")]
            if not times:
                continue
            done = [t for t in times if t is not None]
            out[f"{mode} {device}"] = {
                "trials": len(times), "acted": len(done),
                "median_s": statistics.median(done) if done else None,
                "max_s": max(done) if done else None,
                "within_target": sum(t <= TARGETS[device] for t in done) == len(times)}
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--kills", type=int, default=20, help="trials per mode (default 20)")
    p.add_argument("--kinds", default=",".join(KINDS), help="bench kinds, in turn")
    p.add_argument("--modes", default=",".join(MODES), help="kill, link, stop")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    kinds, modes = args.kinds.split(","), args.modes.split(",")
    rng = random.Random(args.seed)
    rows = []
    with tempfile.TemporaryDirectory(prefix="watchdog-kills-") as tmp:
        twins = {}
        try:
            for mode in modes:
                for k in range(args.kills):
                    kind = kinds[k % len(kinds)]
                    if kind not in twins:
                        twins[kind] = Twin(kind, Path(tmp))
                    row = trial(twins[kind], mode, Path(tmp) / f"{mode}{k}", rng)
                    rows.append(row)
                    if not args.json:
                        print(json.dumps(row), flush=True)
        finally:
            for twin in twins.values():
                twin.close()
    result = {"targets_s": TARGETS, "figures": figures(rows), "trials": rows}
    print(json.dumps(result if args.json else result["figures"], indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
