"""The bench's devices before a session, for the page's "Check devices": the IMU's link and
port, the rotary table's state read now (rate, flags, a tripped watchdog) and its watchdog, the
chamber's address. Nothing is commanded; the session itself opens the devices."""

import os

from station.acquire.live_view import LiveView


def devices(bench) -> dict:
    """{"devices": [{"device", "state"}, ...]} of the bench profile `bench` (`BenchProfile`)."""
    rows = [{"device": f"IMU ({bench.link} link)", "state": _imu(bench)}]
    if bench.table_map is not None:
        rows.append({"device": f"rotary table {bench.table_host}:{bench.table_port}",
                     "state": _table(bench)})
        watchdog = bench.table_map.watchdog
        rows.append({"device": "table watchdog",
                     "state": watchdog.words() if watchdog else
                     "none in the register map: a killed station would leave the table turning"})
    if bench.chamber is not None:
        rows.append({"device": "thermal chamber", "state": "in the profile (a thermal campaign)"})
    return {"devices": rows}


def _imu(bench) -> str:
    """The IMU's address and rate; a serial port that is not there is said."""
    rate = f"{bench.imu.imu.rate_hz:g} Hz, {len(bench.imu.imu.channels)} channels"
    address = bench.imu_address
    if isinstance(address, dict):
        return f"{address['interface']}:{address['channel']}, {rate}"
    if address.startswith("/dev/") and not os.path.exists(address):
        return f"{address} is not there: check the cable and the port ({rate})"
    return f"{address}, {rate}"


def _table(bench) -> str:
    """The table's state read now, or why it could not be read."""
    from drivers.errors import TableError

    try:
        return LiveView.table_words(table_reading(bench))
    except TableError as exc:
        return f"not answering: {exc}"


def table_reading(bench):
    """The rotary table's state read now over its own connection (`TableReading`); TableError
    when it does not answer."""
    from drivers.rotary_table import RotaryTable

    table = RotaryTable(bench.table_host, bench.table_port, bench.table_map,
                        timeout=bench.table_reply)
    try:
        table.connect()
        return table.state()
    finally:
        table.close()
