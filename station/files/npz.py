"""Writing a simulation to disk: the data as `.npz` (array format of `station import`), the truth
beside it as `.truth.json` (non-finite values as null, station.files.jsonable), so that nothing
in the data file reveals the answer."""

import json
import zipfile
from pathlib import Path

import numpy as np

from station.errors import InputError
from station.files.jsonable import jsonable


def truth_path(path) -> Path:
    """`x.npz` -> `x.truth.json`."""
    p = Path(path)
    return p.with_name(p.name[: -len(".npz")] + ".truth.json")


def write(path, simulation) -> tuple[Path, Path]:
    """Write `simulation.arrays` to `path` (.npz, compressed, as numpy.savez_compressed writes
    it; arrays given in blocks are written block by block) and `simulation.truth` to the truth
    file."""
    p = Path(path)
    if p.suffix != ".npz":
        raise InputError(
            f"output file {str(p)!r} must end with .npz (the truth goes to .truth.json)"
        )
    with zipfile.ZipFile(p, "w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as archive:
        for name, value in simulation.arrays.items():
            with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                _write_array(member, value)
    t = truth_path(p)
    t.write_text(json.dumps(jsonable(simulation.truth), indent=1) + "\n")
    return p, t


def _write_array(member, value) -> None:
    """One array in .npy format, as numpy.savez_compressed writes it; an array given in blocks
    (anything with `shape`, `dtype` and an iterator of C-ordered blocks along its first axis,
    e.g. `station.sim.rotary.Blocks`) is written block by block, never held whole."""
    if isinstance(value, np.ndarray | np.generic | int | float):
        np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
        return
    np.lib.format.write_array_header_1_0(member, {
        "descr": np.lib.format.dtype_to_descr(np.dtype(value.dtype)), "fortran_order": False,
        "shape": tuple(value.shape)})
    for block in value:
        member.write(np.ascontiguousarray(block, value.dtype).tobytes())


def read(path) -> dict:
    """The arrays of a data file (never unpickles); InputError for anything else."""
    try:
        with np.load(path, allow_pickle=False) as f:
            return {k: f[k] for k in f.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError, IndexError,
            MemoryError) as exc:
        raise InputError(f"{path} is not a readable .npz data file ({type(exc).__name__}: "
                         f"{' '.join(str(exc).split())[:200]}); give a file written by `station "
                         "simulate` or numpy.savez (numeric arrays, no pickled objects)") from None


def read_truth(path) -> dict:
    """The truth written beside the data file `path` (.npz)."""
    return json.loads(truth_path(path).read_text())
