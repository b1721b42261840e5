"""Writing a simulation to disk: the data as `.npz` (array format of `station import`), the truth
beside it as `.truth.json`, so that nothing in the data file reveals the answer."""

import json
from pathlib import Path

import numpy as np

from station.errors import InputError


def truth_path(path) -> Path:
    """`x.npz` -> `x.truth.json`."""
    p = Path(path)
    return p.with_name(p.name[: -len(".npz")] + ".truth.json")


def _plain(obj):
    """JSON-ready copy: arrays to nested lists, numpy scalars to Python numbers."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None if np.isnan(obj) else ("inf" if obj > 0 else "-inf")
    return obj


def write(path, simulation) -> tuple[Path, Path]:
    """Write `simulation.arrays` to `path` (.npz) and `simulation.truth` to the truth file."""
    p = Path(path)
    if p.suffix != ".npz":
        raise InputError(
            f"output file {str(p)!r} must end with .npz (the truth goes to .truth.json)"
        )
    np.savez_compressed(p, **simulation.arrays)
    t = truth_path(p)
    t.write_text(json.dumps(_plain(simulation.truth), indent=1) + "\n")
    return p, t


def read(path) -> dict:
    """The arrays of a data file (never unpickles)."""
    with np.load(path, allow_pickle=False) as f:
        return {k: f[k] for k in f.files}


def read_truth(path) -> dict:
    """The truth written beside the data file `path` (.npz)."""
    return json.loads(truth_path(path).read_text())
