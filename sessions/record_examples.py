"""Record the committed example rotary sessions on the virtual bench and store their results.

    .venv/bin/python -P sessions/record_examples.py [--force]

Each session is recorded through the real drivers (serial pty twin, Modbus table twin), then
replayed with the default settings (`station.replay`) into `results/rotary`: a replay of the file
reproduces those numbers exactly (tests/test_replay.py).
"""

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from station.protocols.rotary import RotarySettings, suggested_axes
from station.replay import replay_into
from station.twin.rotary_bench import VirtualBench, record_rotary

HERE = Path(__file__).resolve().parent

# 12 positions of a 12-gyro unit, 25 Hz, one revolution per position: about 1.2 MB (0.65 MB of it
# is the fixed 64 KB chunks of the session format)
EXAMPLES = {
    "rotary-12gyro.h5": {"seed": 7, "positions": 12, "rate_hz": 25.0},
}
SETTINGS = RotarySettings(rate=1.0, revolutions=1, static=4.0, rest=0.5, guard=0.5, steady=0.5)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--force", action="store_true", help="replace existing files")
    args = parser.parse_args()
    for name, how in EXAMPLES.items():
        path = HERE / name
        if path.exists():
            if not args.force:
                print(f"{path} exists (--force replaces it)")
                continue
            path.unlink()
        with VirtualBench(seed=how["seed"], speed=40.0, rate_hz=how["rate_hz"],
                          remount_time=1.0) as bench:
            record_rotary(bench, path, SETTINGS, suggested_axes(how["positions"]))
        reduced, result = replay_into(path, "rotary")
        print(f"{path}: {path.stat().st_size / 1e6:.2f} MB, {reduced.M.shape[1]} positions, "
              f"chi2/dof {result.chi2 / result.dof:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
