"""The columns of a record file: a CSV file's named columns or a MAT file's variables, as float arrays of one
length, every value finite and within ±MAX_MAGNITUDE (what servofmu's readers accept).

A CSV file is scanned once as text before numpy's C reader parses its numbers: that scan finds its encoding
(UTF-8, a byte-order mark dropped; an 8-bit file such as a Latin-1 "µ" read as Latin-1), its header, its delimiter
and any row whose count of values differs from the header's (numpy's reader, told which columns to take, would
drop an extra value silently).  A MAT variable must be one vector of real numbers: a matrix is not flattened, a
complex variable is not cast to real.
"""
from __future__ import annotations

import csv
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import MAX_MAGNITUDE, UserError
from ..fileio import read_hdf5_image, read_image

__all__ = ["read_columns", "columns_from_arrays", "MIN_SAMPLES"]

MIN_SAMPLES = 10
_SNIFF = 1 << 16  # bytes looked at for NUL bytes: a binary file has them early
_CHUNK = 1 << 22  # characters of text the scan takes at a time


def read_columns(path: str | Path, names: list[str], options: Sequence[str | None] | None = None
                 ) -> dict[str, np.ndarray]:
    """The named columns of a CSV (header row) or MAT file (variables), as float arrays of equal length.

    ``options``: the command-line option that named each column (``--input``...), for the messages."""
    path = Path(path)
    label = _labeller(names, options)
    if not path.is_file():
        raise UserError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".mat":
        return _read_mat(path, names, label)
    if suffix in (".csv", ".txt", ".tsv"):
        return _read_csv(path, names, label)
    raise UserError(f"{path}: unknown record format {path.suffix!r} (use .csv or .mat)")


def _labeller(names, options):
    """name -> "'name'" or "'name' (--option)"."""
    given = dict(zip(names, options or ()))
    return lambda name: f"{name!r}" + (f" ({given[name]})" if given.get(name) else "")


def _named_by(label, name: str) -> str:
    """", named by --option" for a column an option named, else nothing."""
    text = label(name)
    return f", named by {text[text.index('(') + 1:-1]}" if text.endswith(")") else ""


# ---------------------------------------------------------------------------
# CSV
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class _Layout:
    """What the scan of a CSV file's text found."""

    encoding: str
    header_line: int  # counted from 1
    header: list[str]
    delimiter: str | None  # None: white space
    rows: int  # lines of values


def _read_csv(path: Path, names: list[str], label) -> dict[str, np.ndarray]:
    """The columns ``names`` of a CSV file: a header row, then numbers; blank lines and lines starting with # are
    skipped.  numpy's C reader parses it (millions of rows in seconds); where it fails, a scan of the text finds the
    first bad value and names its line and column."""
    layout = _layout(path, names, label)
    cols = [layout.header.index(n) for n in names]
    try:
        with warnings.catch_warnings():  # (the scan has refused a file without values: numpy's warning says no more)
            warnings.simplefilter("ignore")
            data = np.loadtxt(path, delimiter=layout.delimiter, comments="#", skiprows=layout.header_line,
                              usecols=cols, ndmin=2, quotechar='"', encoding=layout.encoding)
    except (ValueError, IndexError) as exc:  # a value that is not a number
        _raise_first_bad_value(path, layout, names, cols, label)
        raise UserError(f"{path}: not a readable CSV file ({(str(exc).splitlines() or ['damaged'])[0]})") from exc
    finite = np.isfinite(data)
    bad = ~finite | (np.abs(np.where(finite, data, 0.0)) > MAX_MAGNITUDE)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        why = "NaN or Inf" if not finite[r, c] else f"beyond ±{MAX_MAGNITUDE:g}, which servofmu does not read"
        raise UserError(f"{path}: line {_line_of_row(path, layout, int(r))}: column {names[c]!r} is "
                        f"{float(data[r, c])!r} ({why})")
    out = {n: data[:, c].copy() for c, n in enumerate(names)}
    _check_time(path, out[names[0]], names[0], lambda i: f"line {_line_of_row(path, layout, i)}")
    return out


def _layout(path: Path, names: list[str], label) -> _Layout:
    """The file's encoding, header and delimiter, every row checked to hold as many values as the header names."""
    with path.open("rb") as fh:
        if b"\0" in fh.read(_SNIFF):
            raise UserError(f"{path}: not a text (CSV) file (it holds NUL bytes)")
    try:
        layout = _scan(path, "utf-8-sig", label)
    except UnicodeDecodeError:  # 8-bit text: every byte is a Latin-1 character
        layout = _scan(path, "latin-1", label)
    header, line = layout.header, layout.header_line
    missing = [n for n in names if n not in header]
    if missing:
        raise UserError(f"{path}: no column {missing[0]!r} (the header has {', '.join(header)})"
                        + _named_by(label, missing[0]))
    for name in names:
        where = [i + 1 for i, h in enumerate(header) if h == name]
        if len(where) > 1:
            raise UserError(f"{path}: line {line}: column {label(name)} is named {len(where)} times in the header "
                            f"(columns {', '.join(map(str, where))}): rename all but one")
    if not layout.rows:
        raise UserError(f"{path}: no values after the header (line {line})")
    return layout


def _scan(path: Path, encoding: str, label) -> _Layout:
    """Read the text once: the header (first line neither blank nor a comment), its delimiter, and every line of
    values counted; a line whose count of values is not the header's is refused."""
    with path.open(encoding=encoding) as fh:
        lines = enumerate(fh, start=1)
        for lineno, line in lines:
            if line.strip() and not line.startswith("#"):
                break
        else:
            raise UserError(f"{path}: empty file")
        delimiter = _delimiter(line)
        header = _fields(line.rstrip("\r\n"), delimiter, strip=True)
        width, rows, n, tail = _width(header), 0, lineno, ""
        while True:  # blocks of whole lines (the last may lack its newline)
            chunk = fh.read(_CHUNK)
            text = tail + chunk
            cut = text.rfind("\n") + 1 if chunk else len(text)
            block, tail = text[:cut], text[cut:]
            if not block:
                if chunk:
                    continue  # a line longer than a chunk
                break
            if delimiter != " " and _plain(block, delimiter, width):  # the quick path: every line plain and full
                count = block.count("\n") + (not block.endswith("\n"))
                rows, n = rows + count, n + count
                continue
            for text in block.removesuffix("\n").split("\n"):
                n += 1
                text = text.split("#", 1)[0]
                if text.strip():
                    rows += 1
                    _check_width(path, n, text, delimiter, header, width, lineno, label)
    return _Layout(encoding, lineno, header, None if delimiter == " " else delimiter, rows)


def _plain(text: str, delimiter: str, width: int) -> bool:
    """Whether every line of ``text`` holds ``width`` values and nothing that needs a closer look (a comment, a
    quote, a blank line, a trailing delimiter): delimiters counted per line by numpy, not by a loop."""
    if "#" in text or '"' in text:
        return False
    raw = np.frombuffer((text if text.endswith("\n") else text + "\n").encode("utf-8"), dtype=np.uint8)
    ends = np.flatnonzero(raw == 10)
    per_line = np.diff(np.searchsorted(np.flatnonzero(raw == ord(delimiter)), np.r_[-1, ends]))
    return bool(np.all(per_line == width - 1) and not np.any(raw[ends - 1] == ord(delimiter)))


def _check_width(path: Path, n: int, text: str, delimiter: str, header: list[str], width: int, lineno: int,
                 label) -> None:
    """Refuse line ``n`` when its count of values is not the header's (line ``lineno``)."""
    count = _width(_fields(text.rstrip("\r\n"), delimiter)) if '"' in text else _count(text, delimiter)
    if count > width:
        raise UserError(f"{path}: line {n}: {count} values where the header (line {lineno}) names {width} "
                        "columns: a value too many (a stray delimiter?)")
    if count < width:
        raise UserError(f"{path}: line {n}: has no value for column {label(header[count])} ({count} values "
                        f"where the header (line {lineno}) names {width} columns)")


def _delimiter(line: str) -> str:
    try:
        return csv.Sniffer().sniff(line, delimiters=",;\t ").delimiter
    except csv.Error:
        return ","


def _fields(text: str, delimiter: str, strip: bool = False) -> list[str]:
    row = next(csv.reader([text], delimiter=delimiter, skipinitialspace=True), [])
    if delimiter == " ":
        row = [v for v in row if v != ""]
    return [v.strip() for v in row] if strip else row


def _width(fields: list[str]) -> int:
    """The count of values, empty ones at the end (a trailing delimiter) not counted."""
    n = len(fields)
    while n and not fields[n - 1].strip():
        n -= 1
    return n


def _count(text: str, delimiter: str) -> int:
    """The count of values of a line without quotes (the quick path of the scan)."""
    if delimiter == " ":
        return len(text.split())
    return text.rstrip().rstrip(delimiter).rstrip().count(delimiter) + 1 if text.strip() else 0


def _data_lines(path: Path, layout: _Layout):
    """(line number, text) of the lines after the header that hold values: not blank, not a comment."""
    with path.open(encoding=layout.encoding, errors="replace") as fh:
        for lineno, line in enumerate(fh, start=1):
            if lineno > layout.header_line and line.split("#", 1)[0].strip():
                yield lineno, line.rstrip("\r\n")


def _line_of_row(path: Path, layout: _Layout, row: int) -> int:
    """The line number of data row ``row`` (counted from 0 after the header)."""
    for k, (lineno, _) in enumerate(_data_lines(path, layout)):
        if k == row:
            return lineno
    return -1


def _raise_first_bad_value(path: Path, layout: _Layout, names: list[str], cols: list[int], label) -> None:
    """Find the first value numpy's reader refused, by a scan of the text, and name its line and column."""
    for lineno, line in _data_lines(path, layout):
        row = _fields(line.split("#", 1)[0], layout.delimiter or " ")
        for name, col in zip(names, cols):
            if col >= len(row):
                raise UserError(f"{path}: line {lineno}: has no value for column {label(name)}")
            try:
                float(row[col])
            except ValueError:
                raise UserError(f"{path}: line {lineno}: column {name!r} is not a number: {row[col]!r}") from None


# ---------------------------------------------------------------------------
# MAT
# ---------------------------------------------------------------------------
def _read_mat(path: Path, names: list[str], label) -> dict[str, np.ndarray]:
    from scipy.io import loadmat

    try:
        content = {k: v for k, v in loadmat(str(path), squeeze_me=True).items() if not k.startswith("__")}
    except NotImplementedError:  # MATLAB v7.3 files are HDF5
        content = _read_mat73(path)
    except Exception as exc:  # scipy raises many types for damaged files (MatReadError, IndexError, ...)
        raise UserError(f"{path}: not a readable MAT file ({(str(exc).splitlines() or ['damaged'])[0]})") from exc
    return _checked(path, content, names, label, "variable")


def columns_from_arrays(where: str, arrays: dict[str, object]) -> dict[str, np.ndarray]:
    """Arrays given in memory (``{name: values}``, the time first), checked as a MAT file's variables are: each
    one real vector of finite numbers within ±MAX_MAGNITUDE, all of one length, the time strictly increasing.
    ``where`` names them in the messages (a record's name)."""
    names = list(arrays)
    return _checked(where, arrays, names, _labeller(names, None), "argument")


def _checked(path, content: dict, names: list[str], label, what: str) -> dict[str, np.ndarray]:
    out = {}
    for n in names:
        if n not in content:
            raise UserError(f"{path}: no variable {n!r} (the file has {', '.join(sorted(content)) or 'none'})"
                            + _named_by(label, n))
        out[n] = _vector(path, n, content[n], label, what)
    lengths = {n: len(v) for n, v in out.items()}
    if len(set(lengths.values())) > 1:
        raise UserError(f"{path}: {what}s have different lengths ({', '.join(f'{k}: {v}' for k, v in lengths.items())})")
    _check_time(path, out[names[0]], names[0], lambda i: f"sample {i + 1}")
    return out


def _vector(path: Path, name: str, value, label, what: str = "variable") -> np.ndarray:
    """A MAT variable as one real vector: an N×1 or 1×N matrix; a larger matrix or a complex one is refused."""
    shape = np.shape(value)
    if sum(d != 1 for d in shape) > 1:
        raise UserError(f"{path}: {what} {label(name)} is a {'×'.join(map(str, shape))} array; a record's "
                        f"{what} is one vector (N×1 or 1×N)")
    if np.iscomplexobj(value):
        raise UserError(f"{path}: {what} {label(name)} is complex; a record's samples are real numbers")
    try:
        values = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError) as exc:
        raise UserError(f"{path}: {what} {label(name)} is not numeric") from exc
    bad = np.nonzero(~(np.abs(values) <= MAX_MAGNITUDE))[0]
    if len(bad):
        why = "NaN or Inf" if not np.isfinite(values[bad[0]]) else f"beyond ±{MAX_MAGNITUDE:g}"
        raise UserError(f"{path}: {what} {name!r}: sample {bad[0] + 1} is {why}")
    return values


def _read_mat73(path: Path) -> dict:
    """The datasets of a MATLAB 7.3 file (HDF5), read as servofmu reads its own files: once, in a first pass that
    cannot hang on a damaged file (fileio.read_hdf5_image)."""
    import h5py

    return read_hdf5_image(read_image(path, "MAT file"), path, "MAT file",
                           lambda f: {k: np.asarray(v[()]) for k, v in f.items() if isinstance(v, h5py.Dataset)})


def _check_time(path: Path, t: np.ndarray, name: str, where) -> None:
    if len(t) < MIN_SAMPLES:
        raise UserError(f"{path}: needs at least {MIN_SAMPLES} samples, has {len(t)}")
    steps = np.diff(t)
    if np.any(steps <= 0):
        i = int(np.argmax(steps <= 0)) + 1
        raise UserError(f"{path}: {where(i)}: {name} is not strictly increasing: sample {i + 1} at "
                        f"{float(t[i])!r} s after {float(t[i - 1])!r} s")
