"""The station on a busy host: `station demo`, thermal campaigns and the test suite beside CPU hogs.

Starts `--hogs` processes that spin a core each (default 2), then runs `station demo --json`
`--demos` times, `--thermal` thermal campaigns on the thermal twin (recorded and solved), and the
test suite (`pytest`, quiet by the pyproject's addopts; or the files given with --tests; skipped
with --no-suite; `--suites 2` runs it twice at once), all at nice 19 with --nice; prints each
demo's exit code, verdict, eps ratio and real-time factor, each campaign's exit code, each
suite run's pass, fail and error counts and the load average after each part; the hogs are
stopped whatever happens. One JSON object with --json.

    .venv/bin/python -P bench/under_load.py [--hogs 6] [--nice] [--demos 5] [--positions 20]
        [--thermal 3] [--no-suite] [--suites 2] [--log DIR] [--tests tests/test_demo.py ...]
        [--timeout 14400] [--json]
"""

import argparse
import concurrent.futures
import contextlib
import json
import multiprocessing
import os
import re
import resource
import subprocess
import sys
import tempfile
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


THERMAL = """
import sys
from pathlib import Path
from station.cli import main
from station.twin.thermal import ThermalTwin
out, seed = Path(sys.argv[1]), int(sys.argv[2])
with ThermalTwin(seed=seed, positions=6) as twin:
    (out.parent / f"thermal{seed}.toml").write_text(twin.profile_text())
    sys.exit(main(["record", "--profile", str(out.parent / f"thermal{seed}.toml"), "--out",
                   str(out), "--solve", "--json"]))
"""
"""A thermal campaign on the in-process thermal twin (lockstep time), recorded and solved."""


def run(cmd: list, nice: bool, timeout: float, log: Path | None = None) -> tuple:
    """(CompletedProcess, wall seconds) of `cmd` in the repository, at nice 19 if asked; past
    `timeout` wall seconds the command is killed and its exit is None (its output so far kept).
    Its standard output goes to a file as it is written: `log` (to watch a long run) or a
    temporary one."""
    start = time.perf_counter()
    with open(log, "w+", errors="replace") if log is not None else \
            tempfile.TemporaryFile("w+", errors="replace") as out:
        with subprocess.Popen(cmd, cwd=ROOT, stdout=out, stderr=subprocess.PIPE, text=True,
                              preexec_fn=(lambda: os.nice(19)) if nice else None) as child:
            try:
                _, err = child.communicate(timeout=timeout)
                code = child.returncode
            except subprocess.TimeoutExpired:
                child.kill()
                _, err = child.communicate()
                code = None
        out.seek(0)
        done = subprocess.CompletedProcess(cmd, code, out.read(), err)
    return done, time.perf_counter() - start


def demos(k: int, nice: bool, positions: int) -> list:
    """`station demo --json` k times: exit, verdict, eps ratio, wall seconds, real-time factor.
    Each records its calibration in a temporary store (not station.db in the repository)."""
    out = []
    for _ in range(k):
        with tempfile.TemporaryDirectory(prefix="under-load-demo-") as tmp:
            done, seconds = run([sys.executable, "-m", "station", "demo", "--json", "--positions",
                                 str(positions), "--db", f"sqlite:///{tmp}/station.db"], nice, 3600)
        summary = json.loads(done.stdout) if done.stdout.strip().startswith("{") else {}
        out.append({"exit": done.returncode, "seconds": seconds,
                    "verdict": (summary.get("verdict") or {}).get("overall"),
                    "eps_over_sqrt_crlb": summary.get("eps_over_sqrt_crlb"),
                    "real_time_factor": summary.get("real_time_factor"),
                    "eps": summary.get("eps"), "scale_factors": summary.get("scale_factors"),
                    "stderr_tail": done.stderr.strip()[-300:]})
        print(f"demo {len(out)}/{k}: exit {done.returncode} in {seconds:.0f} s",
              file=sys.stderr, flush=True)
    return out


def thermals(k: int, nice: bool) -> list:
    """k thermal campaigns (seeds 1..k) recorded and solved (`THERMAL`): exit, wall seconds."""
    out = []
    with tempfile.TemporaryDirectory(prefix="under-load-") as tmp:
        for seed in range(1, k + 1):
            done, seconds = run([sys.executable, "-c", THERMAL, str(Path(tmp) / f"camp{seed}"),
                                 str(seed)], nice, 3600)
            out.append({"exit": done.returncode, "seconds": seconds,
                        "stderr_tail": done.stderr.strip()[-300:]})
            print(f"thermal campaign {seed}/{k}: exit {done.returncode} in {seconds:.0f} s",
                  file=sys.stderr, flush=True)
    return out


OUTCOME = re.compile(r"^(?:\[gw\d+\] \[\s*\d+%\] )?(PASSED|FAILED|ERROR|SKIPPED|XFAIL|XPASS) "
                     r"(\S+)|^(\S+::\S+) (PASSED|FAILED|ERROR|SKIPPED|XFAIL|XPASS)", re.M)
"""A test's outcome line of `pytest --verbosity=1` (with pytest-xdist: "[gw0] [ 12%] PASSED
tests/...")."""


def outcomes(stdout: str) -> dict:
    """test id -> its outcome, from the `--verbosity=1` lines printed as each test ends (so a
    suite killed at its timeout still names the tests that failed by then)."""
    return {m[2] or m[3]: m[1] or m[4] for m in OUTCOME.finditer(stdout)}


def slowdown(nice: bool) -> float:
    """Wall seconds per CPU second of a small CPU-bound child (0.5 s of CPU) beside the hogs, at
    nice 19 if asked: how much of a core the work gets (CFS gives a nice-19 task 15/1039 of a
    core beside a nice-0 hog on it)."""
    spend = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.5: pass"
    _, seconds = run([sys.executable, "-c", spend], nice, 3600)
    return seconds / 0.5


def cpu_seconds() -> float:
    """User + system CPU seconds of the children waited for so far (with theirs). A suite run
    killed at its timeout leaves its workers to the init process, so their CPU is not counted:
    the figure means something for runs that ended by themselves."""
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    return used.ru_utime + used.ru_stime


def suites(k: int, tests: list, nice: bool, timeout: float, logs: Path | None) -> list:
    """k runs of the suite at once (each beside the hogs and the other runs), as `suite`."""
    with concurrent.futures.ThreadPoolExecutor(k) as pool:
        runs = [pool.submit(suite, tests, nice, timeout,
                            logs / f"suite{i + 1}.log" if logs else None) for i in range(k)]
        return [r.result() for r in runs]


def suite(tests: list, nice: bool, timeout: float, log: Path | None = None) -> dict:
    """The test suite (or `tests`), each test's outcome printed as it ends (`--verbosity=1`;
    with a `log`, each failure's report written beside it as it ends: bench/failures_now.py):
    counts, failures, wall seconds, the slowest tests (pytest's --durations lines); killed after
    `timeout` s (exit None; `progress` and `failed_so_far`: the tests ended by then)."""
    report = [] if log is None else ["-p", "bench.failures_now", "--failures-log",
                                     str(log.with_suffix(".failures"))]
    done, seconds = run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider",
                         "--verbosity=1", *report, *tests], nice, timeout, log)
    ended = outcomes(done.stdout)
    counts = list(ended.values())
    return {"exit": done.returncode, "seconds": seconds, **pytest_counts(done.stdout),
            "progress": {k: counts.count(k) for k in sorted(set(counts))},
            "failed_so_far": sorted(t for t, k in ended.items() if k in ("FAILED", "ERROR")),
            "failures": re.findall(r"^(?:FAILED|ERROR) .*", done.stdout, re.M),
            "error_lines": re.findall(r"^E .*", done.stdout, re.M)[:60],
            "slowest": re.findall(r"^\d+\.\d+s (?:call|setup|teardown) .*", done.stdout, re.M),
            "closing": done.stdout.strip().splitlines()[-1:]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hogs", type=int, default=2, help="CPU-bound processes beside the work")
    parser.add_argument("--nice", action="store_true", help="run the work at nice 19")
    parser.add_argument("--demos", type=int, default=1, help="station demo runs (default 1)")
    parser.add_argument("--thermal", type=int, default=0,
                        help="thermal campaigns recorded and solved (default 0)")
    parser.add_argument("--no-suite", action="store_true", help="skip the test suite")
    parser.add_argument("--suites", type=int, default=1,
                        help="runs of the suite at once, each beside the hogs and the others")
    parser.add_argument("--log", type=Path, help="a directory for each suite run's output "
                        "(suiteN.log, written as the run goes)")
    parser.add_argument("--tests", nargs="*", default=[], help="test files (default: all)")
    parser.add_argument("--positions", type=int, default=20, help="each demo's positions")
    parser.add_argument("--timeout", type=float, default=4 * 3600,
                        help="wall seconds the suite may take before it is stopped")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    with hogging(args.hogs):
        load = []
        out = {"hogs": args.hogs, "nice": args.nice,
               "wall_per_cpu_second": slowdown(args.nice), "demo": demos(args.demos, args.nice,
                                                                   args.positions)}
        load.append(os.getloadavg()[0])
        out["thermal"] = thermals(args.thermal, args.nice)
        load.append(os.getloadavg()[0])
        if not args.no_suite:
            if args.log:
                args.log.mkdir(parents=True, exist_ok=True)
            before = cpu_seconds()
            out["suites"] = suites(args.suites, args.tests, args.nice, args.timeout, args.log)
            out["suites_cpu_seconds"] = cpu_seconds() - before
            load.append(os.getloadavg()[0])
        out["load_average_1min"] = load
    if args.json:
        print(json.dumps(out, indent=1))
        return
    print(f"{args.hogs} CPU hogs beside the work{' (at nice 19)' if args.nice else ''}; load "
          f"average after each part {', '.join(f'{x:.1f}' for x in load)}; a CPU-bound child "
          f"took {out['wall_per_cpu_second']:.1f} wall s per CPU s")
    for d in out["demo"]:
        print(f"demo: exit {d['exit']} in {d['seconds']:.0f} s, verdict {d['verdict']}, eps / "
              f"sqrt(trace CRLB) {d['eps_over_sqrt_crlb']}, {d['real_time_factor']} x real time")
    for t in out["thermal"]:
        print(f"thermal campaign: exit {t['exit']} in {t['seconds']:.0f} s")
    for s in out.get("suites", []):
        print(f"suite: {s['passed']} passed, {s['failed']} failed, {s['errors']} errors, "
              f"{s['skipped']} skipped in {s['seconds']:.0f} s"
              + (f" (stopped after the timeout; ended by then: {s['progress']})"
                 if s["exit"] is None else ""))
        for failure in s["failures"] or s["failed_so_far"]:
            print(f"  {failure}")
    if "suites_cpu_seconds" in out:
        print(f"the suite runs used {out['suites_cpu_seconds']:.0f} CPU s")


if __name__ == "__main__":
    main()
