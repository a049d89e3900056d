"""Reading a lab's text table: a header of column names with units, then rows of numbers.

The one reader of the text files that :mod:`.records` (force records) and
:mod:`.stick_slip_table` (stick-slip tables) accept; NumPy on the host, a file only ever read
as text, never executed.

**Format.** A CSV (comma-separated; quoted cells allowed) or whitespace-separated text file in
UTF-8. ``#`` starts a comment (a whole line, or the rest of a line) and blank lines are
skipped; the first other line is the header naming the columns, each name optionally followed
by its unit in brackets (``t [s]``, ``F[N]``; a different unit is refused, not converted; a row
of units under the header is refused with that advice). Every row has as many cells as the
header names columns. Cells are read as float64: an empty cell or ``-`` is missing where the
caller allows it (NaN); NaN, ``inf`` and text are refused.

**Speed and memory.** The rows are parsed by NumPy's C reader (``numpy.loadtxt``), about as
much memory as the numbers take (8 bytes a cell); only when it fails — a fault to explain, a
table with missing cells, or a CSV with a line of blanks only, which it reads as one empty
cell — does a line-by-line scan run, to find the line and column at fault and word the
refusal (it keeps the numbers compactly too, but parses at Python's speed). Before anything is parsed, the memory the numbers will take is estimated from the
file's size and the length of its first rows (:func:`estimated_bytes`), and a file that would
not fit the memory limit (:func:`peeljax._memory.memory_limit`, half the RAM) is refused
naming the estimate.

Every refusal of a file is a :class:`DataFileError` (a ``ValueError``) whose message names the
file, the line (1-based, counting comments and blank lines) and the column, or for ``.npz`` the
field.
"""

from __future__ import annotations

import array
import csv
import dataclasses
import os
import re
import warnings
from collections.abc import Mapping, Sequence

import numpy as np

from .._memory import memory_limit as default_memory_limit

__all__ = ["MISSING", "DataFileError", "TextTable", "column_numbers", "estimated_bytes", "read_text_table"]

MISSING = ("", "-")  # the cells that mean "not measured" (where a column allows it)
_HEAD_BYTES = 1 << 16  # the start of a file read to find its header and measure its rows
_PARSE_OVERHEAD = 1.25  # NumPy's reader grows its result in blocks: a margin over 8 bytes a cell


class DataFileError(ValueError):
    """A data file refused: the message names the file, the line (1-based) and the column
    (for ``.npz``: the field). The parts are also attributes: ``path``, ``line`` (None when no
    single line is at fault), ``column`` (None when no single column is), ``reason``."""

    def __init__(self, path, reason: str, *, line: int | None = None, column: str | None = None, field: bool = False):
        self.path, self.reason, self.line, self.column = str(path), reason, line, column
        where = [self.path]
        if line is not None:
            where.append(f"line {line}")
        if column is not None:
            where.append(f"{'field' if field else 'column'} {column!r}")
        super().__init__(", ".join(where) + ": " + reason)


@dataclasses.dataclass
class TextTable:
    """A parsed text table: column name → float64 numbers (NaN: a missing cell, where allowed).

    ``lines`` (the 1-based line number of each data row) is found only when a message needs it:
    the fast reader does not keep it.
    """

    path: str
    header_line: int
    names: list[str]
    columns: dict[str, np.ndarray]
    _lines: np.ndarray | None = None

    @property
    def n_rows(self) -> int:
        return int(next(iter(self.columns.values())).size)

    @property
    def lines(self) -> np.ndarray:
        """(n,) the 1-based line numbers of the data rows (a scan of the file, the first time)."""
        if self._lines is None:
            self._lines = _data_lines(self.path, self.header_line)
        return self._lines

    def fail(self, reason: str, *, row: int | None = None, column: str | None = None) -> DataFileError:
        line = self.header_line if row is None else int(self.lines[row])
        return DataFileError(self.path, reason, line=line, column=column)


_HEADER_CELL = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\s*(?:\[\s*([^\]]*?)\s*\])?$")


def _strip_comment(line: str) -> str:
    return line.split("#", 1)[0].strip() if "#" in line else line.strip()


def _read_head(path: str, what: str) -> tuple[str, int]:
    """The file's first bytes as text (whole lines) and its size; the refusals of a file that
    cannot be read, is a zip archive or is not UTF-8."""
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as stream:
            raw = stream.read(_HEAD_BYTES)
    except FileNotFoundError:
        raise DataFileError(path, "no such file") from None
    except OSError as error:
        raise DataFileError(path, f"cannot be read ({error.strerror or type(error).__name__})") from None
    if raw.startswith(b"PK\x03\x04"):
        raise DataFileError(path, f"a zip (.npz) archive, not a text {what}: give .npz files the suffix .npz")
    if len(raw) == _HEAD_BYTES and b"\n" in raw:
        raw = raw[: raw.rindex(b"\n") + 1]  # whole lines only (a UTF-8 character is not cut)
    try:
        return raw.decode("utf-8-sig"), size
    except UnicodeDecodeError as error:
        raise DataFileError(
            path, f"not a UTF-8 text file (byte {error.start}); a {what} is CSV or whitespace-separated text"
        ) from None


def estimated_bytes(size: int, head: str, header_line: int, n_columns: int) -> tuple[float, float]:
    """(bytes, rows): the memory the numbers of a file of ``size`` bytes take once parsed,
    estimated from the mean length of the data rows in its first bytes ``head`` (8 bytes a cell,
    with NumPy's margin), and the rows that implies."""
    rows = head.splitlines()[header_line:]
    data = [line for line in rows if _strip_comment(line)]
    header_bytes = len("\n".join(head.splitlines()[:header_line]).encode()) + 1
    per_row = max(1.0, sum(len(line.encode()) + 1 for line in data) / len(data)) if data else 1.0
    n_rows = max(0.0, size - header_bytes) / per_row
    return n_rows * n_columns * 8 * _PARSE_OVERHEAD, n_rows


def read_text_table(
    path, units: Mapping[str, str], required: Sequence[str], what: str, *, missing_ok: bool = False,
    memory_limit: float | None = None,
) -> TextTable:  # fmt: skip
    """Header and numbers of a comma- or whitespace-separated text file (the module docstring).

    ``units``: the valid column names and their units; ``required``: the names the header must
    give; ``what``: the kind of file, for the messages ("force record", "stick-slip table");
    ``missing_ok``: empty cells and ``-`` are NaN (else refused); ``memory_limit``: bytes the
    parsed numbers may take (default: half the RAM).
    """
    path = str(path)
    head, size = _read_head(path, what)
    header_line, comma, names = None, False, []
    for number, line in enumerate(head.splitlines(), start=1):
        stripped = _strip_comment(line)
        if stripped:
            header_line, comma = number, "," in stripped
            names = _header(path, number, _split(stripped, comma, path, number), units, required, comma)
            break
    if header_line is None:
        if size > len(head.encode()) + 3:  # more than the head: a header beyond 64 KiB of comments
            return _scan(path, units, required, what, missing_ok)
        example = ",".join(required)
        raise DataFileError(
            path, f"empty: no header line (a {what} starts with a header naming its columns, e.g. {example!r})"
        )
    limit = default_memory_limit() if memory_limit is None else float(memory_limit)
    need, rows = estimated_bytes(size, head, header_line, len(names))
    if need > limit:
        raise DataFileError(
            path,
            f"too large to read: its {size / 1e6:.4g} MB hold about {rows:,.0f} rows of {len(names)} numbers, "
            f"about {need / 1e9:.3g} GB once read, more than the memory limit of {limit / 1e9:.3g} GB: "
            "keep every N-th row (or a time window) in a smaller file",
        )
    try:  # NumPy's C reader; any failure: the scan below finds it and says where
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "input contained no data": the scan says it
            values = np.loadtxt(
                path, delimiter="," if comma else None, comments="#", skiprows=header_line, quotechar='"',
                ndmin=2, encoding="utf-8-sig", dtype=np.float64,
            )  # fmt: skip
    except (ValueError, OSError, UnicodeDecodeError):
        values = None
    if values is not None and values.shape[0] > 0 and values.shape[1] == len(names) and np.isfinite(values).all():
        columns = {name: values[:, k] for k, name in enumerate(names)}  # views: no copy of the numbers
        return TextTable(path, header_line, names, columns)
    return _scan(path, units, required, what, missing_ok)


def _scan(path: str, units, required, what: str, missing_ok: bool) -> TextTable:
    """The line-by-line reader: every row checked in file order, the first fault refused naming
    its line and column; the numbers kept compactly (8 bytes a cell)."""
    header_line, comma, names = None, False, []
    columns: list[array.array] = []
    lines = array.array("q")
    separator = ""
    with open(path, encoding="utf-8-sig") as stream:
        for number, line in enumerate(stream, start=1):
            stripped = _strip_comment(line)
            if not stripped:
                continue
            if header_line is None:
                header_line, comma = number, "," in stripped
                names = _header(path, number, _split(stripped, comma, path, number), units, required, comma)
                columns = [array.array("d") for _ in names]
                separator = "commas" if comma else "whitespace"
                continue
            cells = _split(stripped, comma, path, number)
            if len(cells) != len(names):
                raise DataFileError(
                    path,
                    f"{len(cells)} cells separated by {separator}, but the header (line {header_line}) names "
                    f"{len(names)} columns ({', '.join(names)})",
                    line=number,
                )
            for k, cell in enumerate(cells):
                columns[k].append(_number(path, number, names[k], cell, missing_ok, units, first=not lines))
            lines.append(number)
    if header_line is None:
        example = ",".join(required)
        raise DataFileError(
            path, f"empty: no header line (a {what} starts with a header naming its columns, e.g. {example!r})"
        )
    if not lines:
        raise DataFileError(path, "header only: no data rows", line=header_line)
    numbers = {name: np.frombuffer(column, dtype=np.float64) for name, column in zip(names, columns)}
    return TextTable(path, header_line, names, numbers, np.frombuffer(lines, dtype=np.int64))


def _number(path: str, line: int, name: str, cell: str, missing_ok: bool, units, first: bool) -> float:
    """One cell as a finite float (NaN for a missing cell where allowed), or the refusal."""
    if cell in MISSING:
        if missing_ok:
            return float("nan")
        raise DataFileError(path, f"empty cell {cell!r}: every row needs a number", line=line, column=name)
    try:
        value = float(cell)
    except ValueError:
        hint = ""
        if first and cell.strip("[]() ") in set(units.values()):
            hint = f" (a row of units under the header? give each unit in the header instead, e.g. '{name} [{units[name]}]')"
        raise DataFileError(path, f"not a number: {cell!r}{hint}", line=line, column=name) from None
    if value != value:
        note = "write an empty cell or '-' for not measured" if missing_ok else "a force record has no missing values"
        raise DataFileError(path, f"NaN ({cell!r}): {note}", line=line, column=name)
    if value in (float("inf"), float("-inf")):
        raise DataFileError(path, f"infinite value {cell!r}", line=line, column=name)
    return value


def _data_lines(path: str, header_line: int) -> np.ndarray:
    """The 1-based line numbers of the data rows after the header (for messages)."""
    lines = array.array("q")
    with open(path, encoding="utf-8-sig") as stream:
        for number, line in enumerate(stream, start=1):
            if number > header_line and _strip_comment(line):
                lines.append(number)
    return np.frombuffer(lines, dtype=np.int64)


def _split(line: str, comma: bool, path, number: int) -> list[str]:
    if not comma:
        return line.split()
    if '"' in line or "'" in line:
        try:
            return [cell.strip() for cell in next(csv.reader([line], skipinitialspace=True))]
        except csv.Error as error:  # e.g. a quoted cell longer than csv's field limit (131072)
            raise DataFileError(path, f"not a CSV line ({error})", line=number) from None
    return [cell.strip() for cell in line.split(",")]


def _header(path, number, cells, units, required, comma) -> list[str]:
    names = []
    valid = ", ".join(units)
    for k, cell in enumerate(cells, start=1):
        match = _HEADER_CELL.match(cell)
        if match is None or match.group(1) not in units:
            hint = ""
            if not comma and ";" in cell:
                hint = " (semicolons do not separate columns: use commas or whitespace, and '.' as the decimal point)"
            elif cell == "":
                hint = " (an empty column name: a trailing comma?)"
            elif cell.startswith("[") and not comma:
                hint = " (a unit in a whitespace-separated header is written without spaces: t[s])"
            raise DataFileError(
                path,
                f"unknown column {cell!r} (column {k} of the header); valid names: {valid}{hint}",
                line=number,
                column=cell,
            )
        name, unit = match.group(1), match.group(2)
        if unit is not None and unit != units[name]:
            raise DataFileError(
                path,
                f"{name} is read in {units[name]}, the header says [{unit}]: convert the column",
                line=number,
                column=name,
            )
        if name in names:
            raise DataFileError(
                path, f"duplicate column {name!r} (columns {names.index(name) + 1} and {k})", line=number, column=name
            )
        names.append(name)
    for name in required:
        if name not in names:
            raise DataFileError(
                path, f"missing required column {name!r} (the header names {', '.join(names)}; valid names: {valid})",
                line=number, column=name,
            )  # fmt: skip
    return names


def column_numbers(text: TextTable, name: str, *, missing_ok: bool) -> np.ndarray:
    """The column as float64 (NaN: a missing cell, which :func:`read_text_table` allows only
    with ``missing_ok``); where not ``missing_ok``, a missing cell is refused naming it."""
    values = text.columns[name]
    if not missing_ok and np.isnan(values).any():
        row = int(np.flatnonzero(np.isnan(values))[0])
        raise text.fail("empty cell: every row needs a number", row=row, column=name)
    return values
