"""The damaged inputs of issue 30 for `bench/file_faults.py`: every input where it enters.

`case(kind, i, sources, rng)` writes damaged input i of a class (`KINDS`) into the scratch folder
and says which command reads it (the class's commands in turn) and how an acceptance counts:
"compare" (a calibration written from an undamaged part of the file: compared with the
undamaged file's), "unverified" (accepted by a command that writes no calibration; the damage was
in a part it did not read) or "changed" (the input is damaged where the command must read it:
any acceptance is a changed result).
"""

import hashlib
import json
import random
import shutil
import zipfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCH = (ROOT / "drivers/profiles/bench_serial.toml").read_text().replace(
    "192.168.0.50", "127.0.0.1").replace("port = 502", "port = 9").replace(
    "/dev/ttyUSB0", "/dev/null")
"""A bench profile whose devices fail at once if it is ever accepted (nothing listens)."""
NUMBERS = ("1e999", "-1e999", "NaN", "1" + "0" * 400)
"""What a number of a JSON document is set to: beyond float range, not a number, 10**400."""
BOMB_MB = (24, 96, 384, 1400)
"""Inflated sizes of the deflate bombs, MB."""


@dataclass
class Sources:
    """The undamaged inputs: a scratch folder, a session file and its calibration file."""

    scratch: Path
    session: Path
    cal: Path


def nested(depth: int) -> str:
    """JSON or TOML arrays nested `depth` deep."""
    return "[" * depth + "]" * depth


def deep_json(text: str, depth: int) -> str:
    """A JSON object's text with a key of its own holding arrays nested `depth` deep."""
    return text.rstrip()[:-1] + ', "deep": ' + nested(depth) + "}"


def number_json(doc: dict, rng: random.Random) -> str:
    """`doc`'s JSON text with one of its numbers (chosen at random) written as one of NUMBERS."""
    leaves, stack = [], [doc]
    while stack:
        node = stack.pop()
        items = node.items() if isinstance(node, dict) else enumerate(node)
        for key, value in items:
            if isinstance(value, dict | list):
                stack.append(value)
            elif type(value) in (int, float):
                leaves.append((node, key))
    node, key = rng.choice(leaves)
    node[key] = "@@number@@"
    return json.dumps(doc).replace('"@@number@@"', rng.choice(NUMBERS))


def session_metadata(path: Path, text: str) -> None:
    """Write `text` as the session's metadata, its checksum written again (crafted)."""
    import h5py
    import numpy as np

    with h5py.File(path, "r+") as f:
        del f["metadata"]
        ds = f.create_dataset("metadata", data=text, dtype=h5py.string_dtype())
        ds.attrs["sha256"] = np.bytes_(hashlib.sha256(text.encode()).hexdigest())


def metadata_of(path: Path) -> str:
    """A session's metadata text."""
    import h5py

    with h5py.File(path, "r") as f:
        raw = f["metadata"][()]
    return raw.decode() if isinstance(raw, bytes) else raw


def session_commands(i: int, path: Path, src: Sources) -> tuple:
    """(argv, files it writes) of the session readers replay, solve, diagnose, apply, in turn."""
    out = src.scratch / f"out-{i}"
    return [(["replay", path], []),
            (["solve", path, "--out", out.with_suffix(".cal.json"), "--force"],
             [out.with_suffix(".cal.json")]),
            (["diagnose", path], []),
            (["apply", src.cal, path, "--out", out.with_suffix(".csv"), "--force"],
             [out.with_suffix(".csv")])][i % 4]


def metadata_deep(i, src, rng) -> dict:
    path = src.scratch / f"metadata_deep-{i}.h5"
    shutil.copy(src.session, path)
    session_metadata(path, deep_json(metadata_of(path), rng.choice((65, 1000, 100_000))))
    argv, outs = session_commands(i, path, src)
    return {"argv": argv, "made": [path, *outs], "accept": "changed"}


def metadata_number(i, src, rng) -> dict:
    path = src.scratch / f"metadata_number-{i}.h5"
    shutil.copy(src.session, path)
    session_metadata(path, number_json(json.loads(metadata_of(path)), rng))
    argv, outs = session_commands(i, path, src)
    return {"argv": argv, "made": [path, *outs], "accept": "changed"}


def table_nan(i, src, rng) -> dict:
    """NaN or inf at a random row of the table's time or angle; solve's calibration is compared
    with the undamaged one (a row no window reads may be accepted), the others unverified."""
    import h5py

    path = src.scratch / f"table_nan-{i}.h5"
    shutil.copy(src.session, path)
    with h5py.File(path, "r+") as f:
        ds = f["streams/table"][rng.choice(("time", "angle"))]
        ds[rng.randrange(ds.shape[0])] = rng.choice((float("nan"), float("inf"), -float("inf")))
    out = src.scratch / f"table_nan-{i}.cal.json"
    argv = [["solve", path, "--out", out, "--force"], ["replay", path], ["diagnose", path],
            ["report", path, "--out", out.with_suffix(".html")]][i % 4]
    return {"argv": argv, "made": [path, out, out.with_suffix(".html")], "out": out,
            "accept": "compare" if i % 4 == 0 else "unverified"}


def cal_commands(i: int, cal: Path, src: Sources) -> tuple:
    """(argv, files it writes) of the calibration file readers apply and export, in turn."""
    out = src.scratch / f"cal-out-{i}"
    return [(["apply", cal, src.session, "--out", out.with_suffix(".csv"), "--force"],
             [out.with_suffix(".csv")]),
            (["export", cal, "--to", "c-header", "--out", out.with_suffix(".h")],
             [out.with_suffix(".h")])][i % 2]


def calfile_number(i, src, rng) -> dict:
    cal = src.scratch / f"calfile_number-{i}.cal.json"
    cal.write_text(number_json(json.loads(src.cal.read_text()), rng))
    argv, outs = cal_commands(i, cal, src)
    return {"argv": argv, "made": [cal, *outs], "accept": "changed"}


def calfile_deep(i, src, rng) -> dict:
    """A calibration file whose `fit` (a key it must have) holds arrays nested deep."""
    cal = src.scratch / f"calfile_deep-{i}.cal.json"
    doc = json.loads(src.cal.read_text())
    doc["fit"] = "@@deep@@"
    cal.write_text(json.dumps(doc).replace('"@@deep@@"', nested(rng.choice((65, 1000, 100_000)))))
    argv, outs = cal_commands(i, cal, src)
    return {"argv": argv, "made": [cal, *outs], "accept": "changed"}


def record(profile: Path, i: int, src: Sources) -> list:
    """`station record` with the bench profile `profile` (refused when it is loaded)."""
    return ["record", "--profile", profile, "--out", src.scratch / f"record-{i}.h5"]


def profile_deep(i, src, rng) -> dict:
    """A bench profile whose [protocol] static (a key it reads) holds arrays nested deep."""
    profile = src.scratch / f"profile_deep-{i}.toml"
    deep = nested(rng.choice((17, 1000, 100_000)))
    profile.write_text(BENCH.replace("static = 10.0", f"static = {deep}"))
    return {"argv": record(profile, i, src), "made": [profile, src.scratch / f"record-{i}.h5"],
            "accept": "changed"}


def profile_wide(i, src, rng) -> dict:
    device = src.scratch / f"wide-{i}.toml"
    names = ", ".join(f'"g{k}"' for k in range(rng.choice((1025, 10_000, 100_000))))
    text = (ROOT / "drivers/profiles/imu12_serial.toml").read_text()
    device.write_text("\n".join(f"channels = [{names}]" if line.startswith("channels") else line
                                for line in text.splitlines()) + "\n")
    profile = src.scratch / f"profile_wide-{i}.toml"
    profile.write_text(BENCH.replace('profile = "imu12_serial"', f'profile = "{device.name}"'))
    return {"argv": record(profile, i, src),
            "made": [profile, device, src.scratch / f"record-{i}.h5"], "accept": "changed"}


def zeros(z: zipfile.ZipFile, name: str, shape: tuple, descr: str) -> None:
    """An all-zero array member of `z`, streamed (never held whole)."""
    import numpy as np

    with z.open(f"{name}.npy", "w", force_zip64=True) as f:
        np.lib.format.write_array_header_1_0(
            f, {"descr": descr, "fortran_order": False, "shape": shape})
        left = int(np.prod(shape)) * np.dtype(descr).itemsize
        while left > 0:
            f.write(bytes(min(left, 1 << 22)))
            left -= 1 << 22


def bomb(path: Path, megabytes: int) -> None:
    """A rotary array file (every array `station import npz` requires, shapes consistent) whose
    `y` and `rate_cmd` are all zeros: `megabytes` MB inflated from about a thousandth of it
    (built once per size, then copied)."""
    import numpy as np

    built = path.parent / f"bomb-{megabytes}.npz"
    if not built.exists():
        n, m = 4, 12
        k = megabytes * (1 << 20) // (n * m * 4)
        with zipfile.ZipFile(built, "w", compression=zipfile.ZIP_DEFLATED,
                             allowZip64=True) as z:
            zeros(z, "y", (n, k, m), "<i4")
            zeros(z, "rate_cmd", (k,), "<f8")
            small = {"lsb": np.float64(1e3), "fs": np.float64(100.0), "t0": np.arange(n) * 1e3,
                     "c_cmd": np.float64(1.0), "a_nominal": np.eye(3, m),
                     **{f"seg_{s}": np.array([j * k // 5, (j + 1) * k // 5]) for j, s in
                        enumerate(("static", "spinup", "settle", "rotating", "spindown"))}}
            for name, value in small.items():
                with z.open(f"{name}.npy", "w") as f:
                    np.lib.format.write_array(f, np.asanyarray(value))
    shutil.copy(built, path)


def npz_bomb(i, src, rng) -> dict:
    path = src.scratch / f"npz_bomb-{i}.npz"
    bomb(path, rng.choice(BOMB_MB))
    out = src.scratch / f"npz_bomb-{i}.h5"
    argv = [["import", "npz", out, path], ["diagnose", path]][i % 2]
    return {"argv": argv, "made": [path, out], "accept": "changed"}


KINDS = {"metadata_deep": metadata_deep, "metadata_number": metadata_number,
         "table_nan": table_nan, "calfile_number": calfile_number, "calfile_deep": calfile_deep,
         "profile_deep": profile_deep, "profile_wide": profile_wide, "npz_bomb": npz_bomb}
"""Class name -> its damaged input i (`case`)."""


def case(kind: str, i: int, sources: Sources, rng: random.Random) -> dict:
    """Damaged input i of class `kind`: {"argv": the command, "made": files to remove after,
    "out": the calibration file a compared command writes, "accept": how an acceptance counts}."""
    return {"out": None, **KINDS[kind](i, sources, rng)}
