"""Numeric tables from text, CSV or MATLAB files, read as untrusted input (no pickle, no objects).

- `read_matrix`: a table without a header: whitespace-separated text (or `delimiter`), a MATLAB
  v5/v7 file (scipy.io) or a MATLAB v7.3 file (HDF5 inside, read with h5py) holding one numeric
  array. Either orientation: the time axis is the long one (or the one that gives `columns`).
- `read_csv`: named columns of a delimited text file with a header line; the delimiter is
  sniffed (`csv.Sniffer`) unless given, and lines before the header (a metadata preamble such as
  `Fs,100`) are skipped: the header is the first line holding every wanted column name, or the
  line after `skip_rows` lines; one line of units right under it is skipped too.

Both return a `Table`: the numbers and notes saying how the file was read (the import's summary).
"""

import csv
import zlib
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import scipy.io
from scipy.io.matlab import MatReadError

from station.errors import CalibrationInputError
from station.files.hdf5 import stored_plainly

MAT5_MAGIC = b"MATLAB 5.0 MAT-file"
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
MAT73_USERBLOCK = 512
"""MATLAB v7.3 files: a 512-byte header text ("MATLAB 7.3 MAT-file, ...") then HDF5."""

MAX_BYTES = 1 << 31
"""Largest array (uncompressed) an imported file may hold."""

HEAD_BYTES = 1 << 16
"""Bytes of a CSV file searched for its header line and sniffed for its delimiter."""

DELIMITERS = ",;\t| "
"""Delimiters the sniffer chooses from (" ": any run of blanks)."""


@dataclass(frozen=True)
class Table:
    """(K, c) numbers, row = sample, and how the file was read (notes for the summary)."""

    values: np.ndarray
    notes: tuple


def read_table(path, columns: int) -> np.ndarray:
    """(K, columns) finite numbers of a text or MATLAB file (`read_matrix`)."""
    return read_matrix(path, columns).values


def read_matrix(path, columns: int | None = None, *, delimiter: str | None = None,
                skip_rows: int = 0) -> Table:
    """The finite numeric table of a text file (whitespace-separated, or `delimiter`, after
    `skip_rows` lines) or a MATLAB file with one numeric 2-D array, samples along the rows.

    A (c, K) array is transposed when c = `columns` (given) or when K > c (the time axis is the
    long one); the notes say which orientation was taken.
    """
    path = Path(path)
    with path.open("rb") as f:
        head = f.read(MAT73_USERBLOCK + len(HDF5_MAGIC))
    notes = []
    if head.startswith(MAT5_MAGIC):
        table = _mat5_array(path)
    elif HDF5_MAGIC in (head[:8], head[MAT73_USERBLOCK:]):
        table, name = _mat73_array(path)
        notes.append(f"{path.name}: MATLAB v7.3 file (HDF5 inside; scipy.io does not read "
                     f"those), variable {name!r} read with h5py")
    elif head.startswith(b"MATLAB"):
        raise CalibrationInputError(
            f"{path} is a MAT-file whose header says {head[:32].decode('ascii', 'replace')!r} "
            "but is neither a MATLAB 5.0 file (v5/v7, read by scipy.io) nor HDF5 at byte 512 "
            "(v7.3, read by h5py): another version, or damaged.",
            "Save it again in MATLAB with save -v7 or save -v7.3.")
    else:
        table = _text_array(path, delimiter, skip_rows)
    if table.ndim != 2 or 0 in table.shape or not np.all(np.isfinite(table)):
        raise CalibrationInputError(
            f"{path} holds a {table.shape} array (finite: {bool(np.all(np.isfinite(table)))}).",
            "Give a 2-D table of finite numbers, one row (or column) per sample.")
    table, note = _oriented(table, columns, path.name)
    if columns is not None and table.shape[1] != columns:
        raise CalibrationInputError(
            f"{path} holds a {table.shape[0]} x {table.shape[1]} table; expected {columns} "
            "columns (in either orientation).",
            "Check which columns the file holds (time first, then one per axis).")
    return Table(table, (*notes, note))


def read_csv(path, columns: list, *, delimiter: str | None = None,
             skip_rows: int | None = None, progress=None) -> Table:
    """(K, len(columns)) numbers of the named columns of a delimited text file with a header.

    delimiter : None: sniffed from the data lines (csv.Sniffer over ", ; tab | space")
    skip_rows : lines before the header; None: the header is the first line holding every name
    progress  : optional callable(characters read, bytes in the file) while the rows are read
    """
    path = Path(path)
    lines = _head_lines(path)
    notes = []
    if delimiter is None:
        delimiter = _sniff(path, lines)
        notes.append(f"{path.name}: delimiter {delimiter!r} (sniffed)")
    where = f"line {1 if skip_rows is None else skip_rows + 1}"
    if skip_rows is None:
        skip_rows = _header_row(lines, columns, delimiter)
        where = (f"line {skip_rows + 1}" if skip_rows is not None else
                 f"no line of the first {len(lines)} holds them all; line 1")
        skip_rows = skip_rows or 0
    elif not 0 <= skip_rows < len(lines):
        raise CalibrationInputError(f"{path}: --skip-rows {skip_rows} skips past the first "
                                    f"{len(lines)} lines.", "Give the number of lines before "
                                    "the header line.")
    if skip_rows:
        notes.append(f"{path.name}: {skip_rows} line(s) before the header skipped")
    header = _fields(lines[skip_rows], delimiter)
    missing = [c for c in columns if c not in header]
    if missing or len(set(columns)) != len(columns):
        raise CalibrationInputError(
            f"{path}: columns {missing or columns} missing or named twice ({where}, split at "
            f"{delimiter!r}: {header[:20]}).",
            "Name each column once as spelled in the header; if the header is elsewhere give "
            "--skip-rows N (lines before it), if the split is wrong give --delimiter.")
    usecols = [header.index(c) for c in columns]
    first = skip_rows + 1
    if first + 1 < len(lines) and not _numbers(_fields(lines[first], delimiter), usecols) \
            and _numbers(_fields(lines[first + 1], delimiter), usecols):
        notes.append(f"{path.name}: line {first + 1} under the header is not numbers (units?), "
                     "skipped")
        first += 1
    try:
        with path.open(encoding="utf-8-sig") as f:
            table = np.loadtxt(_counted(f, path.stat().st_size, progress),
                               delimiter=None if delimiter == " " else delimiter,
                               skiprows=first, ndmin=2, quotechar='"', usecols=usecols)
    except (ValueError, UnicodeDecodeError) as exc:
        raise CalibrationInputError(
            f"{path}: the chosen columns are not all numbers ({exc}).",
            "Pick numeric columns (text columns are not imported); check --delimiter and "
            "--skip-rows (lines before the header).") from None
    if not np.all(np.isfinite(table)):
        raise CalibrationInputError(f"{path}: the chosen columns hold NaN or infinite values.",
                                    "Remove or interpolate the invalid rows first.")
    return Table(table, tuple(notes))


# ----------------------------------------------------------------------------------- internals


def _counted(lines, size: int, progress, every: int = 50_000):
    """The `lines`, telling `progress(characters so far, size)` every `every` lines and at the
    end, when given."""
    done = 0
    for i, line in enumerate(lines):
        done += len(line)
        if progress is not None and i % every == 0:
            progress(done, size)
        yield line
    if progress is not None:
        progress(size, size)


def _oriented(table: np.ndarray, columns, name: str) -> tuple:
    """The table with samples along the rows, and a note saying which orientation was taken."""
    rows, cols = table.shape
    flip = (cols != columns and rows == columns) if columns is not None else rows < cols
    if flip:
        return table.T, (f"{name}: a {rows} x {cols} array with time along its columns, "
                         f"transposed to {cols} samples of {rows} columns")
    return table, f"{name}: {rows} samples of {cols} columns (time along the rows)"


def _text_array(path: Path, delimiter, skip_rows: int) -> np.ndarray:
    try:
        return np.loadtxt(path, dtype=float, ndmin=2, skiprows=skip_rows,
                          delimiter=None if delimiter in (None, " ") else delimiter)
    except ValueError as exc:
        raise CalibrationInputError(
            f"{path} is neither a MATLAB file nor a table of numbers ({exc}).",
            "Give a numeric table (--delimiter if not blank-separated, --skip-rows N for lines "
            "before the numbers) or a .mat file with one numeric array.",
        ) from None


def _mat5_array(path: Path) -> np.ndarray:
    """The one numeric array of a MATLAB v5/v7 file, refusing structs, cells and several
    variables."""
    try:
        variables = {k: v for k, v in scipy.io.loadmat(path).items() if not k.startswith("__")}
    except (ValueError, TypeError, OSError, EOFError, NotImplementedError, MatReadError,
            zlib.error) as exc:
        raise CalibrationInputError(
            f"scipy.io cannot read {path} (a MATLAB 5.0 MAT-file by its header, not v7.3/HDF5, "
            f"which is read with h5py): {exc}.",
            "Save it again in MATLAB (save -v7 or save -v7.3).") from None
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


def _mat73_array(path: Path) -> tuple:
    """(array as MATLAB shows it, variable name) of a MATLAB v7.3 file: one numeric matrix, a
    plain dataset of this file (no external links or storage, known filters), transposed back
    (MATLAB writes column-major arrays, so HDF5 holds the transpose)."""
    try:
        with h5py.File(path, "r") as f:
            names = [n for n in f if not n.startswith("#")]  # "#refs#": cells' and structs' data
            if len(names) != 1:
                raise CalibrationInputError(f"{path} holds variables {sorted(names)}.",
                                            "Save exactly one numeric matrix.")
            return _mat73_dataset(path, f, names[0]).T, names[0]
    except (OSError, KeyError, RuntimeError, ValueError) as exc:
        if isinstance(exc, CalibrationInputError):
            raise
        raise CalibrationInputError(
            f"{path}: a MATLAB v7.3 (HDF5) file that h5py cannot read ({exc}).",
            "Save it again in MATLAB (save -v7.3, or -v7 for scipy.io).") from None


def _mat73_dataset(path: Path, f, name: str) -> np.ndarray:
    link = f.get(name, getlink=True)
    obj = f.get(name) if isinstance(link, h5py.HardLink) else None
    kind = obj.attrs.get("MATLAB_class", b"") if obj is not None else b""
    kind = kind.decode("ascii", "replace") if isinstance(kind, bytes) else str(kind)
    if not isinstance(obj, h5py.Dataset) or kind in ("cell", "struct", "char") or \
            "MATLAB_empty" in obj.attrs:
        raise CalibrationInputError(f"{path}: variable {name!r} is not a numeric matrix "
                                    f"(MATLAB class {kind or 'unknown'}).",
                                    "Save a plain numeric matrix (no cells, structs or text).")
    if not stored_plainly(obj):
        raise CalibrationInputError(f"{path}: variable {name!r} uses external storage or "
                                    "unknown filters; refusing to read it.",
                                    "Save it again in MATLAB (save -v7.3).")
    if obj.dtype.kind not in "iuf" or obj.ndim != 2 or obj.nbytes > MAX_BYTES:
        raise CalibrationInputError(f"{path}: variable {name!r} is a {obj.shape} {obj.dtype} "
                                    f"array (a numeric matrix of at most {MAX_BYTES} bytes "
                                    "expected).", "Save a plain real numeric matrix.")
    return obj[()].astype(float)


def _head_lines(path: Path) -> list:
    """The complete lines among the first HEAD_BYTES of a text file (a BOM dropped)."""
    try:
        with path.open("rb") as f:
            head = f.read(HEAD_BYTES + 1)
        text = head[:HEAD_BYTES].decode("utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationInputError(f"cannot read {path} as UTF-8 CSV ({exc}).",
                                    "Give a CSV file with a header line.") from None
    lines = [line.rstrip("\r") for line in text.split("\n")]
    if len(head) > HEAD_BYTES and len(lines) > 1:
        lines.pop()  # cut in the middle
    if not any(lines):
        raise CalibrationInputError(f"{path} is empty.", "Give a CSV file with a header line.")
    return lines


def _sniff(path: Path, lines: list) -> str:
    """The delimiter of the data lines: the last 20 non-empty lines of the head (a preamble sits
    at the top), sniffed by csv.Sniffer."""
    sample = "\n".join([line for line in lines if line.strip()][-20:])
    try:
        return csv.Sniffer().sniff(sample, delimiters=DELIMITERS).delimiter
    except csv.Error:
        raise CalibrationInputError(f"{path}: cannot tell the delimiter of its lines.",
                                    "Give it: --delimiter ',' (or ';', tab, ' ').") from None


def _header_row(lines: list, columns: list, delimiter: str) -> int | None:
    """Index of the first line holding every name of `columns` as a field (None: none)."""
    for i, line in enumerate(lines):
        if set(columns) <= set(_fields(line, delimiter)):
            return i
    return None


def _numbers(fields: list, usecols: list) -> bool:
    """Whether the fields at `usecols` are all numbers (a data line, not a line of units)."""
    try:
        for i in usecols:
            float(fields[i].strip('"'))
    except (ValueError, IndexError):
        return False
    return True


def _fields(line: str, delimiter: str) -> list:
    """The stripped fields of one line (" ": any run of blanks)."""
    if delimiter == " ":
        return line.split()
    return [f.strip() for f in next(csv.reader([line], delimiter=delimiter), [])]
