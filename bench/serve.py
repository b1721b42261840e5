"""`station serve` under a real-time 200 Hz stream: does the page's live plot keep up, and how fast
does the page load?

A rotary twin on a real-time clock (`--speed`, default 1: the wall's, the bench as it really
runs; 200 Hz, 12 gyros) and `station serve` in this process; headless chromium (Debian's, through
its chromedriver) opens the page, starts a session from it and watches it for `--minutes`. The page
counts every update it draws and, for each, its lag: the wall time it drew the update minus the
wall time the newest sample it shows reached the station (`window.stationStats`, station.js).
Printed per minute: updates per second and the lag's median and 95th percentile; then the first
minute against the last (a growing lag would show there). The first load: the page opened afresh
`--loads` times (navigation timing: request to the load event, and to the first live update).

    python bench/serve.py                   # 10 minutes
    python bench/serve.py --minutes 2 --json
"""

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[0:1] = [str(ROOT), str(ROOT / "tests")]  # not bench/: its serial.py would shadow pyserial

from servedstation import ServedStation, chromium  # noqa: E402

from station.twin.served import BenchTwin  # noqa: E402

STATS = "return [window.stationStats.updates, window.stationStats.lags.splice(0)]"


def first_loads(browser, url: str, loads: int) -> dict:
    """Seconds from the request to the load event, and to the first live update drawn, of
    `loads` fresh page loads (the browser's cache emptied by a new profile each run is not
    needed: the assets are no-store or revalidated on the loopback)."""
    onload, live = [], []
    for _ in range(loads):
        browser.get("about:blank")
        browser.get(url)
        deadline = time.monotonic() + 30
        while browser.execute_script("return window.stationStats.first") is None:
            if time.monotonic() > deadline:
                raise RuntimeError("the page drew no live update within 30 s")
            time.sleep(0.01)
        timing = browser.execute_script(
            "const t = performance.getEntriesByType('navigation')[0];"
            "return [t.loadEventEnd, window.stationStats.first];")
        onload.append(timing[0] / 1000)
        live.append(timing[1] / 1000)
    return {"load_event_s": _spread(onload), "first_update_s": _spread(live)}


def _spread(values: list) -> dict:
    return {"median": statistics.median(values), "max": max(values), "n": len(values)}


def watch(browser, minutes: float) -> list:
    """Per minute of the session: updates per second, lag median and 95th percentile (s)."""
    rows = []
    browser.execute_script(STATS)  # start afresh
    for minute in range(int(round(minutes))):
        start, count0 = time.monotonic(), browser.execute_script(STATS)[0]
        lags = []
        while time.monotonic() - start < 60:
            time.sleep(1)
            lags += browser.execute_script(STATS)[1]
        count = browser.execute_script(STATS)[0] - count0
        lags.sort()
        rows.append({"minute": minute + 1, "updates_per_s": count / (time.monotonic() - start),
                     "lag_median_s": statistics.median(lags) if lags else None,
                     "lag_p95_s": lags[int(0.95 * (len(lags) - 1))] if lags else None,
                     "updates": count})
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="session watched (default 10)")
    parser.add_argument("--speed", type=float, default=1.0,
                        help="the twin's clock against the wall (default 1: real time)")
    parser.add_argument("--loads", type=int, default=10, help="fresh page loads timed")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    positions = 40  # more than the minutes need: the session is aborted at the end
    with tempfile.TemporaryDirectory(prefix="bench-serve-") as tmp, \
            BenchTwin(seed=1, speed=args.speed, positions=positions) as twin:
        profile = Path(tmp) / "twin.toml"
        profile.write_text(twin.profile_text("BENCH-1"))
        browser = chromium()
        try:
            with ServedStation([profile], Path(tmp) / "sessions") as station:
                browser.get(station.url)
                loads = first_loads(browser, station.url, args.loads)
                station.session.start("twin", "BENCH-1")
                browser.get(station.url)
                rows = watch(browser, args.minutes)
                shown = station.session.snapshot()
                if shown["state"] != "running":
                    raise RuntimeError(f"the session ended early: {shown['state']}, "
                                       f"{shown['error']}")
                station.session.abort()
        finally:
            browser.quit()
    first, last = rows[0], rows[-1]
    result = {"minutes": len(rows), "speed": args.speed, "rate_hz": 200, "loads": loads,
              "per_minute": rows,
              "updates_per_s_min": min(r["updates_per_s"] for r in rows),
              "lag_median_first_last_s": [first["lag_median_s"], last["lag_median_s"]]}
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"page first load (loopback, {loads['load_event_s']['n']} loads): load event median "
          f"{loads['load_event_s']['median'] * 1e3:.0f} ms, max "
          f"{loads['load_event_s']['max'] * 1e3:.0f} ms; first live update median "
          f"{loads['first_update_s']['median'] * 1e3:.0f} ms, max "
          f"{loads['first_update_s']['max'] * 1e3:.0f} ms")
    print(f"live plot, 200 Hz stream, {len(rows)} min at {args.speed:g}x real time:")
    for r in rows:
        print(f"  minute {r['minute']:2d}: {r['updates_per_s']:.1f} updates/s, lag median "
              f"{r['lag_median_s'] * 1e3:.0f} ms, p95 {r['lag_p95_s'] * 1e3:.0f} ms")
    print(f"slowest minute {result['updates_per_s_min']:.1f} updates/s; lag median first minute "
          f"{first['lag_median_s'] * 1e3:.0f} ms, last {last['lag_median_s'] * 1e3:.0f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
