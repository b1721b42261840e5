"""CPU cost of starting the `station` command, against a bare Python in the same run.

Runs each command `--repeat` times as a child process and reads the children's user + system CPU
from `resource.getrusage(RUSAGE_CHILDREN)`; prints the median per command. Target (issue 13):
`station --help` costs <= 0.3 s of CPU. `station solve --help` also imports its command module.
Prints a table, or one JSON object with --json.
"""

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys

TARGET_S = 0.3


def cpu_seconds(cmd) -> float:
    """User + system CPU seconds of one run of `cmd` (stdout discarded; must exit 0)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def commands() -> dict:
    """The commands measured: the console script when installed, and `python -m station`."""
    python = sys.executable
    script = shutil.which("station", path=os.path.dirname(python)) or shutil.which("station")
    cases = {"python -c pass": [python, "-c", "pass"],
             "python -m station --help": [python, "-m", "station", "--help"],
             "python -m station solve --help": [python, "-m", "station", "solve", "--help"]}
    if script:
        cases["station --help"] = [script, "--help"]
    return cases


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=9, help="runs per command (median)")
    parser.add_argument("--json", action="store_true", help="one JSON object")
    args = parser.parse_args()
    figures = {name: statistics.median(cpu_seconds(cmd) for _ in range(args.repeat))
               for name, cmd in commands().items()}
    help_cpu = figures.get("station --help", figures["python -m station --help"])
    out = {"cpu_s": figures, "target_s": TARGET_S, "meets_target": help_cpu <= TARGET_S,
           "over_bare_python_s": help_cpu - figures["python -c pass"]}
    if args.json:
        print(json.dumps(out, indent=1))
        return
    for name, s in figures.items():
        print(f"{name:34s} {s * 1e3:7.1f} ms CPU")
    print(f"station --help over bare Python: {out['over_bare_python_s'] * 1e3:.1f} ms "
          f"(target <= {TARGET_S * 1e3:.0f} ms in all: "
          f"{'met' if out['meets_target'] else 'MISSED'})")


if __name__ == "__main__":
    main()
