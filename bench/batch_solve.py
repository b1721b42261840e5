"""CPU time a session of a batch `station solve` (issue 35), beside `station solve` of one file.

Makes `--distinct` small rotary sessions with the simulator (`station simulate --positions 8
--fs 20`, seeds 1, 2, ...; `station import npz`), copies them round-robin into `--sessions` files
(each its own file: checked, read, solved, written and recorded in the folder's station.db like
any other), then alternates: a
`station solve FILE` of one of them and the batch `station solve --from-list LIST` of all (into
a fresh folder each time, so that every calibration file is new); `--repeats` times. Each
command's CPU time (user + system of the command and its children: the structure check's child
process included) comes from `resource.getrusage(RUSAGE_CHILDREN)` around it. Printed: the
median CPU time of one `station solve` and of the batch per session (target <= 0.15 s), and
the batch's exit code and lines (one per session, every calibration file written).

    .venv/bin/python -P bench/batch_solve.py [--sessions 1000] [--distinct 4] [--repeats 1]
                                             [--json]
"""

import argparse
import json
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

STATION = [sys.executable, "-P", "-c",
           "import sys; from station.cli import main; sys.exit(main(sys.argv[1:]))"]
TARGET = 0.15
"""CPU seconds a session in a batch of 1,000 (issue 35)."""


def station(*argv, cwd=None) -> tuple:
    """(CPU seconds, exit code, stdout) of `station ARGV` (its children included)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run([*STATION, *map(str, argv)], capture_output=True, text=True, cwd=cwd)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, done.returncode, done.stdout


def made(distinct: int, work: Path) -> list:
    """`distinct` simulated rotary session files (8 positions at 20 Hz)."""
    files = []
    for seed in range(1, distinct + 1):
        npz, h5 = work / f"sim{seed}.npz", work / f"sim{seed}.h5"
        for argv in (("simulate", "--positions", 8, "--fs", 20, "--seed", seed, "--out", npz),
                     ("import", "npz", h5, npz)):
            _, code, _ = station(*argv)
            if code != 0:
                raise RuntimeError(f"station {' '.join(map(str, argv))} exited {code}")
        files.append(h5)
    return files


def batch_folder(sources: list, n: int, folder: Path) -> Path:
    """A folder of n copies of the sources (round-robin) and LIST naming them; returns LIST."""
    folder.mkdir()
    names = []
    for i in range(n):
        name = f"s{i:05d}.h5"
        shutil.copyfile(sources[i % len(sources)], folder / name)
        names.append(name)
    listed = folder / "sessions.txt"
    listed.write_text("\n".join(names) + "\n")
    return listed


def measure(n: int, distinct: int, repeats: int, work: Path) -> dict:
    sources = made(distinct, work)
    single, batch, codes, lines = [], [], [], []
    for r in range(repeats):
        one = work / f"one{r}"
        one.mkdir()
        shutil.copyfile(sources[r % len(sources)], one / "s.h5")
        cpu, code, _ = station("solve", one / "s.h5")
        if code != 0:
            raise RuntimeError(f"station solve of one session exited {code}")
        single.append(cpu)
        listed = batch_folder(sources, n, work / f"batch{r}")
        cpu, code, out = station("solve", "--from-list", listed)
        batch.append(cpu / n)
        codes.append(code)
        lines.append(len(out.splitlines()))
        written = len(list(listed.parent.glob("*.cal.json")))
        if written != n:
            raise RuntimeError(f"the batch wrote {written} of {n} calibration files")
        shutil.rmtree(listed.parent)
    per = float(np.median(batch))
    return {"sessions": n, "distinct": distinct, "repeats": repeats,
            "single_solve_cpu_s": float(np.median(single)),
            "batch_cpu_s_per_session": per, "target_s_per_session": TARGET,
            "met": per <= TARGET, "batch_exit_codes": codes, "batch_lines": lines}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, default=1000, help="sessions in the batch")
    parser.add_argument("--distinct", type=int, default=4, help="simulated sessions copied")
    parser.add_argument("--repeats", type=int, default=1, help="pairs of runs (medians)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="batch_solve") as work:
        result = measure(args.sessions, args.distinct, args.repeats, Path(work))
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        print(f"station solve of one session: {result['single_solve_cpu_s']:.2f} s CPU; a batch "
              f"of {result['sessions']}: {result['batch_cpu_s_per_session']:.3f} s CPU a session "
              f"(target <= {TARGET}: {'met' if result['met'] else 'missed'}), exit codes "
              f"{result['batch_exit_codes']}, lines {result['batch_lines']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
