"""The MIMU4444BT array's raw packet dumps (../shared/data/real/mimu4444-array/exp_*.bin) through
`station import binary` (the drivers' frame parser, profile drivers/profiles/mimu4444.toml).

Prints, per file: packets decoded, bad packet candidates, resyncs, missing packet numbers, unused
bytes, duration and sample rate from the 64 MHz stamps, and over the still poses found by
station.reduce.stillness: the mean |acc| of each IMU (about 9.8 m/s^2 if the decode is right) and
the mean gyro reading (biases, near 0).

    .venv/bin/python bench/mimu4444.py [--json] [--data DIR]
"""

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from station.files.importers import import_binary
from station.files.session import Session
from station.reduce.stillness import detect_still

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "mimu4444-array"
if not DATA.exists():  # a worktree outside /work
    DATA = Path("/work/shared/data/real/mimu4444-array")
IMUS = 8


def figures(dump: Path, tmp: Path) -> dict:
    """The figures of one dump (see the module docstring)."""
    out = import_binary(tmp / f"{dump.stem}.h5", dump, "mimu4444")
    with Session.open(out) as s:
        link = s.metadata["import"]["link"]
        data = s.stream("imu")
    x = data.to_si()
    still = detect_still(x, data.spec.rate_hz)
    rest = np.zeros(len(x), bool)
    for start, stop in still.intervals:
        rest[start:stop] = True
    per_imu = x[rest].reshape(-1, IMUS, 6)
    acc_norm = np.linalg.norm(per_imu[:, :, :3], axis=2)
    return {
        "packets": link["frames"], "bad_packets": link["bad_frames"],
        "resyncs": link["resyncs"], "missing_packet_numbers": link["dropped"],
        "unused_bytes": link["unused_bytes"], "duration_s": round(link["duration_s"], 3),
        "rate_hz_from_stamps": round(link["rate_hz"], 4),
        "still_poses": len(still.intervals), "still_s": round(rest.sum() / data.spec.rate_hz, 1),
        "acc_norm_mean_m_s2": np.round(acc_norm.mean(axis=0), 3).tolist(),
        "acc_norm_sd_over_poses_m_s2": np.round(acc_norm.std(axis=0), 3).tolist(),
        "gyro_mean_deg_s": np.round(np.degrees(per_imu[:, :, 3:].mean(axis=0)), 2).tolist(),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="one JSON object")
    parser.add_argument("--data", type=Path, default=DATA, help="the mimu4444-array folder")
    args = parser.parse_args(argv)
    dumps = sorted(args.data.glob("exp_*.bin"))
    if not dumps:
        print(f"no exp_*.bin in {args.data}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        result = {d.name: figures(d, Path(tmp)) for d in dumps}
    if args.json:
        print(json.dumps(result))
    else:
        for name, f in result.items():
            print(name)
            for key, value in f.items():
                print(f"  {key}: {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
