"""Reading a lab's text table: a header of column names with units, then rows of numbers.

The one reader of the text files that :mod:`.records` (force records) and
:mod:`.stick_slip_table` (stick-slip tables) accept; plain Python and NumPy on the host, a
file only ever read as text, never executed.

**Format.** A CSV (comma-separated; quoted cells allowed) or whitespace-separated text file in
UTF-8. Lines starting with ``#`` are comments and blank lines are skipped; the first other line
is the header naming the columns, each name optionally followed by its unit in brackets
(``t [s]``, ``F[N]``; a different unit is refused, not converted). Every row has as many cells
as the header names columns. Cells are read as float64 (:func:`column_numbers`): an empty cell
or ``-`` is missing where the caller allows it; NaN, ``inf`` and text are refused.

Every refusal of a file is a :class:`DataFileError` (a ``ValueError``) whose message names the
file, the line (1-based, counting comments and blank lines) and the column, or for ``.npz`` the
field.
"""

from __future__ import annotations

import csv
import dataclasses
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

__all__ = ["MISSING", "DataFileError", "TextTable", "column_numbers", "read_text_table"]

MISSING = ("", "-")  # the cells that mean "not measured" (where a column allows it)


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
    """A parsed text table: column name → strings, and each row's line number."""

    path: str
    header_line: int
    names: list[str]
    cells: dict[str, list[str]]
    lines: np.ndarray  # (n,) 1-based line numbers of the data rows

    def fail(self, reason: str, *, row: int | None = None, column: str | None = None) -> DataFileError:
        line = self.header_line if row is None else int(self.lines[row])
        return DataFileError(self.path, reason, line=line, column=column)


_HEADER_CELL = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\s*(?:\[\s*([^\]]*?)\s*\])?$")


def read_text_table(path, units: Mapping[str, str], required: Sequence[str], what: str) -> TextTable:
    """Header and cells of a comma- or whitespace-separated text file (the module docstring).

    ``units``: the valid column names and their units; ``required``: the names the header must
    give; ``what``: the kind of file, for the messages ("force record", "stick-slip table").
    """
    path = str(path)
    try:
        raw = Path(path).read_bytes()
    except FileNotFoundError:
        raise DataFileError(path, "no such file") from None
    except OSError as error:
        raise DataFileError(path, f"cannot be read ({error.strerror or type(error).__name__})") from None
    if raw.startswith(b"PK\x03\x04"):
        raise DataFileError(path, f"a zip (.npz) archive, not a text {what}: give .npz files the suffix .npz")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise DataFileError(
            path, f"not a UTF-8 text file (byte {error.start}); a {what} is CSV or whitespace-separated text"
        ) from None
    header_line, comma, names = None, False, []
    rows: list[list[str]] = []
    lines: list[int] = []
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if header_line is None:
            header_line, comma = number, "," in stripped
            cells = _split(stripped, comma, path, number)
            names = _header(path, number, cells, units, required, comma)
            continue
        rows.append(_split(stripped, comma, path, number))
        lines.append(number)
    if header_line is None:
        example = ",".join(required)
        raise DataFileError(
            path, f"empty: no header line (a {what} starts with a header naming its columns, e.g. {example!r})"
        )
    if not rows:
        raise DataFileError(path, "header only: no data rows", line=header_line)
    separator = "commas" if comma else "whitespace"
    for row, number in zip(rows, lines):
        if len(row) != len(names):
            raise DataFileError(
                path,
                f"{len(row)} cells separated by {separator}, but the header (line {header_line}) names "
                f"{len(names)} columns ({', '.join(names)})",
                line=number,
            )
    cells = {name: [row[k] for row in rows] for k, name in enumerate(names)}
    return TextTable(path, header_line, names, cells, np.asarray(lines))


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
    """The column as float64; empty cells or ``-`` are NaN where ``missing_ok``, every other
    cell must be a finite number (the first offending cell is named)."""
    strings = text.cells[name]
    missing = np.fromiter((s in MISSING for s in strings), bool, len(strings))
    values = np.full(len(strings), np.nan)
    present = np.flatnonzero(~missing)
    if missing.any() and not missing_ok:
        row = int(np.flatnonzero(missing)[0])
        raise text.fail(f"empty cell {strings[row]!r}: every row needs a number", row=row, column=name)
    try:
        values[present] = np.array([strings[i] for i in present], dtype=float)
    except ValueError:
        for i in present:
            try:
                float(strings[i])
            except ValueError:
                raise text.fail(f"not a number: {strings[i]!r}", row=int(i), column=name) from None
        raise  # pragma: no cover (numpy and float() agree on what parses)
    bad = present[~np.isfinite(values[present])]
    if bad.size:
        row = int(bad[0])
        if np.isnan(values[row]):
            note = (
                "write an empty cell or '-' for not measured" if missing_ok else "a force record has no missing values"
            )
            raise text.fail(f"NaN ({strings[row]!r}): {note}", row=row, column=name)
        raise text.fail(f"infinite value {strings[row]!r}", row=row, column=name)
    return values

