"""CPU cost of starting the `station` command, against a bare Python in the same run.

Runs each command `--repeat` times as a child process and reads the children's user + system CPU
from `resource.getrusage(RUSAGE_CHILDREN)`; prints the median per command. Targets: `station
--help` costs <= 0.1 s of CPU (issue 35; 0.3 s in issue 13); `station solve` of the bundled rotary
example (sessions/rotary-12gyro.h5, a calibration file written to a temporary folder) costs <= 3x
`python -c "import numpy, h5py"` (issue 35: a command is mostly its work, not its imports).
`station solve --help` also imports its command module. Prints a table, or one JSON object with
--json.

The commands run as an installed station does, from compiled modules: the bytecode is written once
(to a temporary PYTHONPYCACHEPREFIX, in a first round that is not counted), whatever
PYTHONDONTWRITEBYTECODE says (pip compiles a package's modules when it installs it; a host that
forbids bytecode compiles the station's 70 modules of a solve at every start, about 30 ms more).
"""

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HELP_TARGET_S = 0.1
SOLVE_TARGET = 3.0
"""`station solve` of the example over `import numpy, h5py`."""
EXAMPLE = Path(__file__).resolve().parents[1] / "sessions" / "rotary-12gyro.h5"


def cpu_seconds(cmd, env: dict) -> float:
    """User + system CPU seconds of one run of `cmd` (stdout discarded; must exit 0)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env=env)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def commands(out: Path) -> dict:
    """The commands measured: the console script when installed, and `python -m station`; the
    solve writes its calibration file to `out`."""
    python = sys.executable
    script = shutil.which("station", path=os.path.dirname(python)) or shutil.which("station")
    cases = {"python -c pass": [python, "-c", "pass"],
             "python -c 'import numpy, h5py'": [python, "-c", "import numpy, h5py"],
             "python -m station --help": [python, "-m", "station", "--help"],
             "python -m station solve --help": [python, "-m", "station", "solve", "--help"],
             "python -m station solve EXAMPLE": [python, "-m", "station", "solve", str(EXAMPLE),
                                                 "--out", str(out), "--force"]}
    if script:
        cases["station --help"] = [script, "--help"]
    return cases


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=9, help="runs per command (median)")
    parser.add_argument("--json", action="store_true", help="one JSON object")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cases = commands(Path(tmp) / "example.cal.json")
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env["PYTHONPYCACHEPREFIX"] = str(Path(tmp) / "pycache")
        for cmd in cases.values():  # compiles the modules, as an installation does
            cpu_seconds(cmd, env)
        runs = {name: [] for name in cases}
        for _ in range(args.repeat):  # interleaved: a load change hits every command alike
            for name, cmd in cases.items():
                runs[name].append(cpu_seconds(cmd, env))
    figures = {name: statistics.median(r) for name, r in runs.items()}
    help_cpu = figures.get("station --help", figures["python -m station --help"])
    ratio = figures["python -m station solve EXAMPLE"] / figures["python -c 'import numpy, h5py'"]
    out = {"cpu_s": figures, "help_target_s": HELP_TARGET_S,
           "help_meets": help_cpu <= HELP_TARGET_S,
           "over_bare_python_s": help_cpu - figures["python -c pass"],
           "solve_over_imports": ratio, "solve_target": SOLVE_TARGET,
           "solve_meets": ratio <= SOLVE_TARGET}
    if args.json:
        print(json.dumps(out, indent=1))
        return
    for name, s in figures.items():
        print(f"{name:34s} {s * 1e3:7.1f} ms CPU")
    print(f"station --help: {help_cpu * 1e3:.1f} ms in all, {out['over_bare_python_s'] * 1e3:.1f} "
          f"ms over bare Python (target <= {HELP_TARGET_S * 1e3:.0f} ms in all: "
          f"{'met' if out['help_meets'] else 'MISSED'})")
    print(f"station solve of the example: {ratio:.2f}x `import numpy, h5py` (target <= "
          f"{SOLVE_TARGET:g}x: {'met' if out['solve_meets'] else 'MISSED'})")


if __name__ == "__main__":
    main()
