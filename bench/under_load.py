"""The station on a busy host: `station demo` and the test suite beside CPU hogs.

Starts `--hogs` processes that spin a core each (default 2: a load of 2x this 2-core machine with
the work itself), then runs `station demo --json` and the test suite (`pytest`, quiet by the
pyproject's addopts: a second -q drops the closing counts line; or the files given with
--tests), and prints the demo's exit code and eps ratio and the suite's pass, fail and
error counts; the hogs are stopped whatever happens. One JSON object with --json.

    .venv/bin/python -P bench/under_load.py [--hogs 2] [--tests tests/test_demo.py ...] [--json]
"""

import argparse
import contextlib
import json
import multiprocessing
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def spin(stop) -> None:
    """Keep one core busy until `stop` is set."""
    while not stop.is_set():
        sum(range(10000))


@contextlib.contextmanager
def hogging(n: int):
    """`n` processes spinning a core each while the block runs; stopped whatever happens."""
    stop = multiprocessing.Event()
    hogs = [multiprocessing.Process(target=spin, args=(stop,), daemon=True) for _ in range(n)]
    for hog in hogs:
        hog.start()
    try:
        yield hogs
    finally:
        stop.set()
        for hog in hogs:
            hog.join(5)


def pytest_counts(output: str) -> dict:
    """{"passed": n, "failed": n, "errors": n, "skipped": n} from pytest's closing line (the last
    line that counts tests; warnings may follow it)."""
    found = {k: 0 for k in ("passed", "failed", "errors", "skipped")}
    closing = [line for line in output.splitlines()
               if re.search(r"\d+ (passed|failed)", line) and " in " in line]
    for number, word in re.findall(r"(\d+) (passed|failed|errors?|skipped)",
                                   closing[-1] if closing else ""):
        found["errors" if word.startswith("error") else word] = int(number)
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hogs", type=int, default=2, help="CPU-bound processes beside the work")
    parser.add_argument("--tests", nargs="*", default=[], help="test files (default: all)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    stop = multiprocessing.Event()
    hogs = [multiprocessing.Process(target=spin, args=(stop,), daemon=True)
            for _ in range(args.hogs)]
    for hog in hogs:
        hog.start()
    try:
        start = time.perf_counter()
        demo = subprocess.run([sys.executable, "-m", "station", "demo", "--json"], cwd=ROOT,
                              capture_output=True, text=True, timeout=1800)
        demo_s = time.perf_counter() - start
        summary = json.loads(demo.stdout) if demo.stdout.strip().startswith("{") else {}
        start = time.perf_counter()
        suite = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider",
                                *args.tests], cwd=ROOT, capture_output=True, text=True,
                               timeout=7200)
        suite_s = time.perf_counter() - start
    finally:
        stop.set()
        for hog in hogs:
            hog.join(5)
    out = {"hogs": args.hogs,
           "demo": {"exit": demo.returncode, "seconds": demo_s,
                    "eps_over_sqrt_crlb": summary.get("eps_over_sqrt_crlb"),
                    "verdict": (summary.get("verdict") or {}).get("overall"),
                    "stderr_tail": demo.stderr.strip()[-300:]},
           "suite": {"exit": suite.returncode, "seconds": suite_s,
                     **pytest_counts(suite.stdout),
                     "failures": re.findall(r"^(?:FAILED|ERROR) .*", suite.stdout, re.M),
                     "error_lines": re.findall(r"^E .*", suite.stdout, re.M)[:60],
                     "closing": suite.stdout.strip().splitlines()[-1:]}}
    if args.json:
        print(json.dumps(out, indent=1))
        return
    d, s = out["demo"], out["suite"]
    print(f"{args.hogs} CPU hogs beside the work")
    print(f"demo: exit {d['exit']} in {d['seconds']:.0f} s, eps / sqrt(trace CRLB) "
          f"{d['eps_over_sqrt_crlb']}, verdict {d['verdict']}")
    print(f"suite: {s['passed']} passed, {s['failed']} failed, {s['errors']} errors, "
          f"{s['skipped']} skipped in {s['seconds']:.0f} s")
    for failure in s["failures"]:
        print(f"  {failure}")


if __name__ == "__main__":
    main()
