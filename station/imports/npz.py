"""Writing a simulation to disk: the data as `.npz` (array format of `station import`), the truth
beside it as `.truth.json` (non-finite values as null, station.files.jsonable), so that nothing
in the data file reveals the answer."""

import json
import math
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


MAX_RATIO = 100
"""Largest inflated / compressed size of an array over RATIO_FLOOR bytes: recorded counts carry
noise and deflate 1.5-10x; an array that deflates further is a bomb (zeros), not a recording."""
RATIO_FLOOR = 16 << 20
"""Arrays inflating to less than this are not held to MAX_RATIO (constant settings compress
well, and cost nothing)."""


def headers(path, max_bytes: int | None = None) -> dict:
    """{name: (shape, dtype)} of the arrays of an .npz, from the zip's and the .npy headers
    alone, before anything is inflated: every member an .npy of numbers or fixed-width strings
    (never objects), at most `max_bytes` of data, its inflated size (`ZipInfo.file_size`) what
    its header's shape needs, and deflated at most MAX_RATIO times (a deflate bomb is refused
    from the sizes, not after inflating it); max_bytes: default `station.imports.tables.MAX_BYTES`.
    InputError names the array and the limit."""
    if max_bytes is None:
        from station.imports.tables import MAX_BYTES as max_bytes
    out = {}
    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                out[info.filename[:-4]] = _header(zf, info, path, max_bytes)
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{path} is not a readable .npz file ({type(exc).__name__}: "
                         f"{' '.join(str(exc).split())[:160]})") from None
    return out


def _header(zf, info, path, max_bytes: int) -> tuple:
    """(shape, dtype) of one member of an .npz, checked (`headers`)."""
    name = info.filename
    if not name.endswith(".npy"):
        raise InputError(f"{path} holds {name!r}, not an array; give an .npz written by "
                         "numpy.savez")
    with zf.open(info) as f:
        major, _ = np.lib.format.read_magic(f)
        read = (np.lib.format.read_array_header_1_0 if major == 1
                else np.lib.format.read_array_header_2_0)
        shape, _, dtype = read(f)
        header = f.tell()
    if dtype.hasobject or dtype.kind not in "iufbUS":
        raise InputError(f"{path}: {name} is of type {dtype} (Python objects are never "
                         "unpickled); save numbers or fixed-width strings (e.g. np.array('v2'), "
                         "dtype <U2), not object arrays")
    size = math.prod(shape) * dtype.itemsize
    if size > max_bytes:
        raise InputError(f"{path}: {name} {shape} exceeds {max_bytes} bytes; split the recording")
    if info.file_size != header + size:
        raise InputError(f"{path}: {name} inflates to {info.file_size} bytes, its header's "
                         f"shape {shape} needs {header + size}: the file is damaged")
    if size > RATIO_FLOOR and size > MAX_RATIO * info.compress_size:
        raise InputError(f"{path}: {name} inflates {size // max(info.compress_size, 1)} times "
                         f"({size} bytes from {info.compress_size}); a recording deflates at "
                         f"most {MAX_RATIO} times: refused before inflating (a deflate bomb)")
    return shape, dtype


def read(path, max_bytes: int | None = None) -> dict:
    """The arrays of a data file (never unpickles), their sizes checked first (`headers`);
    InputError for anything else."""
    headers(path, max_bytes)
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
