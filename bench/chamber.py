"""Transaction rate of the thermal chamber driver against its twin, Modbus TCP and RTU.

For each link (TCP on 127.0.0.1, RTU on a null-modem pair of ptys) and each bundled layout (int16
scaled, float32), counts `state()` reads (one read of every register) and `set_setpoint` writes for
`--seconds` wall seconds and prints reads and writes per second and the median read latency. A pty
has no baud rate: the RTU figures are the software cost (pymodbus framing, CRC, the copying thread),
not a real line's, where 19200 baud alone allows ~80 such reads per second. `--quick` measures
0.3 s per case (a check that the bench runs). Prints a table, or one JSON list with --json:

    .venv/bin/python -P bench/chamber.py [--json] [--quick] [--seconds 2]

(-P: do not put bench/ on sys.path, where bench/serial.py would hide pyserial.)
"""

import argparse
import json
import logging
import statistics
import time

from drivers.clock import ScaledClock
from drivers.thermal_chamber import ChamberRegisterMap, ThermalChamber
from drivers.twins.chamber import ChamberTwin
from drivers.twins.thermal import ChamberPhysics

LAYOUTS = ("chamber_modbus", "chamber_float_rtu")


def measure(profile: str, link: str, seconds: float) -> dict:
    """Reads and writes per second and the median read latency of one layout on one link."""
    register_map = ChamberRegisterMap.load(profile)
    clock = ScaledClock(speed=1.0)
    with ChamberTwin(ChamberPhysics(clock), register_map, link=link,
                     lifetime=4 * seconds + 10) as twin:
        where = (dict(host="127.0.0.1", port=twin.port) if link == "tcp"
                 else dict(serial_port=twin.serial_port))
        with ThermalChamber(register_map, clock=clock, **where) as chamber:
            latencies, end = [], time.perf_counter() + seconds
            while time.perf_counter() < end:
                start = time.perf_counter()
                chamber.state()
                latencies.append(time.perf_counter() - start)
            writes, start = 0, time.perf_counter()
            while time.perf_counter() < start + seconds:
                chamber.set_setpoint(300.0 + writes % 10)
                writes += 1
            write_s = time.perf_counter() - start
    return {"profile": profile, "link": link, "reads_per_s": len(latencies) / sum(latencies),
            "read_latency_ms": statistics.median(latencies) * 1e3,
            "writes_per_s": writes / write_s}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="wall seconds per case")
    parser.add_argument("--quick", action="store_true", help="0.3 s per case")
    parser.add_argument("--json", action="store_true", help="one JSON list")
    args = parser.parse_args()
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    seconds = 0.3 if args.quick else args.seconds
    rows = [measure(p, link, seconds) for link in ("tcp", "rtu") for p in LAYOUTS]
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(f"{'link':5s} {'profile':18s} {'reads/s':>9s} {'median ms':>10s} {'writes/s':>9s}")
    for r in rows:
        print(f"{r['link']:5s} {r['profile']:18s} {r['reads_per_s']:9.0f} "
              f"{r['read_latency_ms']:10.3f} {r['writes_per_s']:9.0f}")


if __name__ == "__main__":
    main()
