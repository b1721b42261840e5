"""Numeric tables from text or MATLAB v5 files, read as untrusted input (no pickle, no objects)."""

from pathlib import Path

import numpy as np
import scipy.io

from station.errors import CalibrationInputError

MAT5_MAGIC = b"MATLAB 5.0 MAT-file"


def read_table(path, columns: int) -> np.ndarray:
    """(K, columns) numbers from a whitespace-separated text file or a MATLAB v5 .mat file.

    A .mat file must hold exactly one numeric 2-D array; it is read without pickle or object arrays.
    """
    path = Path(path)
    with path.open("rb") as f:
        head = f.read(len(MAT5_MAGIC))
    if head == MAT5_MAGIC:
        table = _single_mat_array(path)
    else:
        try:
            table = np.loadtxt(path, dtype=float, ndmin=2)
        except ValueError as exc:
            raise CalibrationInputError(
                f"{path} is neither a MATLAB v5 file nor a table of numbers ({exc}).",
                "Give a whitespace-separated numeric table or a .mat file with one numeric array.",
            ) from None
    if table.ndim != 2 or table.shape[1] != columns or not np.all(np.isfinite(table)):
        raise CalibrationInputError(
            f"{path} holds a {table.shape} table (finite: {bool(np.all(np.isfinite(table)))}); "
            f"expected {columns} finite columns.",
            "Check the file's format description (PROVENANCE.md) and the column count.",
        )
    return table


def _single_mat_array(path: Path) -> np.ndarray:
    """The one numeric array of a MATLAB v5 file, refusing structs, cells and several variables."""
    variables = {k: v for k, v in scipy.io.loadmat(path).items() if not k.startswith("__")}
    if len(variables) != 1:
        raise CalibrationInputError(
            f"{path} holds variables {sorted(variables)}.", "Save exactly one numeric matrix."
        )
    (table,) = variables.values()
    if table.dtype.kind not in "iuf":
        raise CalibrationInputError(
            f"{path} holds a {table.dtype} array.",
            "Save a plain numeric matrix (no cells/structs).",
        )
    return table.astype(float)
