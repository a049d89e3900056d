"""The data a peel-test lab hands in: force records, stick-slip tables, and their statistics.

Everything here is plain NumPy on the host, in float64; a data file is only ever read as
numbers (``np.load(..., allow_pickle=False)`` for ``.npz``), never executed.

**Force records** (:func:`read_force_record`, :func:`read_observations`): one run at one
pull velocity V, as a CSV (comma-separated) or whitespace-separated text file. Lines starting
with ``#`` are comments and blank lines are skipped; the first other line is the header naming
the columns, each name optionally followed by its unit in brackets (``t [s]``, ``F[N]``; a
different unit is refused, not converted):

======== ======= =========================================================================
column   unit    what
======== ======= =========================================================================
``t``    s       time, ≥ 0 and strictly increasing (required)
``F``    N       the tape tension (k/l)·u, what a load cell on the tape measures (required)
``v``    m/s     peeling velocity (optional)
``alpha``rad     peel-front angle (optional)
``V``    m/s     pull velocity (optional; constant over the file)
======== ======= =========================================================================

Every cell must be a finite number: NaN, ``inf``, text and empty cells are refused. The pull
velocity comes from, in this order of agreement, a ``V`` column, the file name, or the ``V``
argument (``--V`` on the command line); where several are given they must agree (to 1e-9
relative), and a file with none of them is refused. **The file-name pattern**
(:data:`FILE_NAME_V`): the name without its suffix contains ``V`` as a word of its own (at the
start or after ``_``, ``-`` or a space), then an optional ``=`` or ``_``, then a number
(digits with an optional decimal point), then the end of the name or ``_``, ``-``, a space:
``peel_V=1.1.csv``, ``run_V1.10.txt``, ``V_2.csv`` and ``2024-05-01_V0.8_take3.csv`` give
V = 1.1, 1.1, 2 and 0.8 m/s; ``TV2.csv`` and ``run_v2.csv`` (lower case: that is the peeling
velocity, or a version) give none.

``.npz`` files keep the layouts of ``peeljax fit --data`` (scalar ``V`` and 1-D ``t``, ``v``,
optional ``F``, ``alpha`` with optional own times ``t_F``, ``t_alpha``; or ``V_0, t_0, v_0``,
``V_1``, … for several V in one file). NaN in a *quantity* marks a missing value there (a
``peeljax simulate --out`` file after a stop); times must be finite and ≥ 0, and an optional
``tau`` must be a finite number ≥ 0.

**Stick-slip tables** (:func:`read_stick_slip_table`, :class:`StickSlipTable`): one row per
pull velocity; ``V`` [m/s] and any of ``F_mean``, ``F_slip`` (the force at which the tape
slips), ``F_stick`` (at which it re-sticks) [N], ``period`` (the time between consecutive
slips), ``slip_duration`` [s], each optionally with a standard deviation column
``<name>_std`` (same unit). An empty cell (CSV) or ``-`` (either format) means not measured
at that V; a literal ``nan`` is refused, as are ``inf``, text, V ≤ 0, a V given twice,
``period``/``slip_duration``/standard deviations ≤ 0, ``F_slip`` ≤ ``F_stick`` in a row, a
standard deviation without its value and a row without any value.

**Statistics of a measured force record** (:func:`record_statistics`,
:meth:`StickSlipTable.from_force_records`): the sawtooth's slips detected as force drops with
hysteresis; see :func:`record_statistics` for the definitions and the default threshold.

Every refusal of a file is a :class:`DataFileError` (a ``ValueError``) whose message names the
file, the line (1-based, counting comments and blank lines) and the column, or for ``.npz``
the field.
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from .trajectory import Observation

__all__ = [
    "FILE_NAME_V",
    "FORCE_COLUMNS",
    "TABLE_UNITS",
    "DataFileError",
    "StickSlipTable",
    "read_force_record",
    "read_npz",
    "read_observations",
    "read_stick_slip_table",
    "record_statistics",
]

# Columns of a force record and their units (the header may repeat the unit in brackets).
FORCE_COLUMNS: dict[str, str] = {"t": "s", "F": "N", "v": "m/s", "alpha": "rad", "V": "m/s"}
_FORCE_REQUIRED = ("t", "F")

STATISTICS = ("F_mean", "F_slip", "F_stick", "period", "slip_duration")
_STAT_UNITS = {"F_mean": "N", "F_slip": "N", "F_stick": "N", "period": "s", "slip_duration": "s"}
# Columns of a stick-slip table and their units.
TABLE_UNITS: dict[str, str] = {"V": "m/s", **_STAT_UNITS, **{f"{k}_std": u for k, u in _STAT_UNITS.items()}}
_POSITIVE = ("period", "slip_duration")  # durations: > 0 where measured

# The pull velocity in a file name: see the module docstring.
FILE_NAME_V = re.compile(r"(?:^|(?<=[_\-\s]))V[=_]?(\d+(?:\.\d*)?)(?=$|[_\-\s])")
_SUFFIX = re.compile(r"\.[A-Za-z][A-Za-z0-9]*$")
_MISSING = ("", "-")  # a table's "not measured" cells
_V_RTOL = 1e-9  # V from two sources must agree to this
_ROUNDOFF = 1e-9  # from_force_records: a relative spread below this is no standard deviation


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


# ---------------------------------------------------------------------------- text tables
@dataclasses.dataclass
class _Text:
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


def _read_text(path, units: Mapping[str, str], required: Sequence[str], what: str) -> _Text:
    """Header and cells of a comma- or whitespace-separated text file (see the module docstring)."""
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
            cells = _split(stripped, comma)
            names = _header(path, number, cells, units, required, comma)
            continue
        rows.append(_split(stripped, comma))
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
    return _Text(path, header_line, names, cells, np.asarray(lines))


def _split(line: str, comma: bool) -> list[str]:
    if not comma:
        return line.split()
    if '"' in line or "'" in line:
        return [cell.strip() for cell in next(csv.reader([line], skipinitialspace=True))]
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


def _numbers(text: _Text, name: str, *, missing_ok: bool) -> np.ndarray:
    """The column as float64; empty cells or ``-`` are NaN where ``missing_ok``, every other
    cell must be a finite number (the first offending cell is named)."""
    strings = text.cells[name]
    missing = np.fromiter((s in _MISSING for s in strings), bool, len(strings))
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


# ---------------------------------------------------------------------------- force records
def _V_from_name(path) -> float | None:
    """The pull velocity in the file's name (:data:`FILE_NAME_V`), or None."""
    name = _SUFFIX.sub("", Path(str(path)).name)
    found = {float(m.group(1)) for m in FILE_NAME_V.finditer(name)}
    if len(found) > 1:
        raise DataFileError(path, f"the file name gives V twice, differently: {sorted(found)} m/s")
    return found.pop() if found else None


def _resolve_V(path, sources: dict[str, float]) -> float:
    if not sources:
        raise DataFileError(
            path,
            "no pull velocity V: give the file a constant 'V' column [m/s], put V in its name "
            "(e.g. peel_V=1.1.csv, run_V1.10.txt, V_2.csv), or pass it (V= in Python, --V on the command line)",
        )
    for source, value in sources.items():
        if not (math.isfinite(value) and value > 0):
            raise DataFileError(path, f"V from the {source} must be > 0 (allowed range: (0, inf)), got {value:g}")
    (first, V), *others = sources.items()
    for source, value in others:
        if abs(value - V) > _V_RTOL * max(abs(value), abs(V)):
            raise DataFileError(path, f"V conflicts: {V:g} m/s from the {first}, {value:g} m/s from the {source}")
    return float(V)


def _check_V_argument(V) -> float | None:
    if V is None:
        return None
    try:
        V = float(V)
    except (TypeError, ValueError):
        raise ValueError(f"V must be a number [m/s], got {V!r}") from None
    if not (math.isfinite(V) and V > 0):
        raise ValueError(f"V must be > 0 (allowed range: (0, inf)), got {V!r}")
    return V


def read_force_record(path, *, V: float | None = None) -> Observation:
    """One measured run at one pull velocity, from a CSV or whitespace-separated text file.

    The format, units and refusals are in the module docstring: columns ``t`` [s] and ``F``
    [N] (the tension) required, ``v`` [m/s], ``alpha`` [rad] and a constant ``V`` [m/s]
    optional; V from the ``V`` column, the file name (``peel_V=1.1.csv``) or ``V`` here,
    which must agree where several are given.

    Returns:
        an :class:`~peeljax.fit.Observation` with ``t`` and ``F``, and ``v``/``alpha`` where
        the file has them (``v`` is None otherwise), all float64 on the times ``t``.

    Raises:
        DataFileError: a malformed file, named with the line and column at fault.
        ValueError: a ``V`` argument that is not a number > 0.
    """
    V = _check_V_argument(V)
    text = _read_text(path, FORCE_COLUMNS, _FORCE_REQUIRED, "force record")
    if len(text.lines) < 2:
        raise text.fail("one data row: a force record needs at least 2", row=0)
    columns = {name: _numbers(text, name, missing_ok=False) for name in text.names}
    t = columns["t"]
    if np.any(t < 0):
        row = int(np.flatnonzero(t < 0)[0])
        raise text.fail(f"negative time {t[row]:g} s (times are >= 0)", row=row, column="t")
    if np.any(np.diff(t) <= 0):
        row = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise text.fail(
            f"t must increase strictly: {t[row]:g} s after {t[row - 1]:g} s (line {text.lines[row - 1]})",
            row=row, column="t",
        )  # fmt: skip
    sources = {}
    if "V" in columns:
        column = columns["V"]
        if np.any(column != column[0]):
            row = int(np.flatnonzero(column != column[0])[0])
            raise text.fail(
                f"V must be constant over the file: {column[row]:g} here, {column[0]:g} on line {text.lines[0]}",
                row=row, column="V",
            )  # fmt: skip
        sources["'V' column"] = float(column[0])
    from_name = _V_from_name(path)
    if from_name is not None:
        sources["file name"] = from_name
    if V is not None:
        sources["V argument"] = V
    V = _resolve_V(path, sources)
    return Observation(V=V, t=t, v=columns.get("v"), F=columns["F"], alpha=columns.get("alpha"))


def read_observations(path, *, V: float | None = None) -> list[Observation]:
    """The observations in one data file: a ``.npz`` (either layout; every pull velocity in it)
    or, for any other suffix, a text force record (:func:`read_force_record`, one observation).

    ``V`` is the pull velocity for a text file without a ``V`` column or V in its name; for a
    ``.npz`` (which carries its own) it must agree with every V in the file.
    """
    if Path(str(path)).suffix.lower() == ".npz":
        return read_npz(path, V=V)[0]
    return [read_force_record(path, V=V)]


# ---------------------------------------------------------------------------- .npz files
def read_npz(path, *, V: float | None = None) -> tuple[list[Observation], dict[str, float]]:
    """The observations of an ``.npz`` data file and its settings: ``{"tau": …, "dt": …}``
    where the file has a usable one (``tau`` ≥ 0; ``dt`` finite and > 0 — a ``simulate --out``
    file under error control stores NaN there, which is skipped)."""
    V = _check_V_argument(V)
    path = str(path)
    if not Path(path).is_file():
        raise DataFileError(path, "no such file")
    try:
        data = np.load(path, allow_pickle=False)
    except Exception as error:  # noqa: BLE001  (any failure to parse the file is bad input)
        raise DataFileError(path, f"not a readable .npz without pickles ({type(error).__name__})") from None
    if not hasattr(data, "files"):
        raise DataFileError(path, "expected an .npz archive of named arrays")
    with data:
        try:
            return _read_npz_file(data, path, V)
        except ValueError as error:
            if not isinstance(error, DataFileError) and "allow_pickle" in str(error):
                raise DataFileError(path, "not a readable .npz without pickles (object arrays)") from None
            raise


def _npz_error(path, key, reason) -> DataFileError:
    return DataFileError(path, reason, column=key, field=True)


def _scalar(data, key: str, path: str) -> float:
    value = np.asarray(data[key])
    if value.size != 1 or not np.issubdtype(value.dtype, np.number) or np.issubdtype(value.dtype, np.complexfloating):
        raise _npz_error(path, key, f"{key!r} must be a number")
    return float(value.reshape(()))


def _array(data, key: str, path: str) -> np.ndarray:
    value = np.asarray(data[key])
    if value.ndim != 1 or not np.issubdtype(value.dtype, np.number) or value.size < 2:
        raise _npz_error(path, key, f"{key!r} must be a 1-D numeric array of at least 2 entries")
    return value.astype(np.float64)


def _check_series(path: str, key: str, time_key: str, times: np.ndarray, values: np.ndarray) -> None:
    """NaN in a quantity marks a missing entry (ignored); an infinite value, or times that are
    not finite, are negative or do not increase, mean a broken file."""
    if np.any(np.isinf(values)):
        raise _npz_error(path, key, f"{key!r} has infinite entries (NaN marks a missing value; inf is not one)")
    if not np.all(np.isfinite(times)):
        kind = "NaN" if np.any(np.isnan(times)) else "infinite"
        i = int(np.flatnonzero(~np.isfinite(times))[0])
        raise _npz_error(
            path, time_key, f"{time_key!r} has {kind} entries (first at index {i}): every time must be given"
        )
    if np.any(times < 0):
        i = int(np.flatnonzero(times < 0)[0])
        raise _npz_error(
            path, time_key, f"{time_key!r} has negative times ({times[i]:g} s at index {i}); times are >= 0"
        )
    if np.any(np.diff(times) <= 0):
        i = int(np.flatnonzero(np.diff(times) <= 0)[0])
        raise _npz_error(
            path, time_key, f"the times {time_key!r} must increase strictly, got {times[i]:g} then {times[i + 1]:g}"
        )


def _npz_observation(data, path: str, suffix: str, V_argument: float | None) -> Observation:
    keys = set(data.files)
    for key in ("V", "t", "v"):
        if key + suffix not in keys:
            raise _npz_error(
                path, key + suffix,
                f"missing {key + suffix!r} (keys: t, v, V and optional F, alpha; or V_0, t_0, v_0, ...)",
            )  # fmt: skip
    V = _scalar(data, "V" + suffix, path)
    if not (math.isfinite(V) and V > 0):
        raise _npz_error(path, "V" + suffix, f"V{suffix} must be > 0 (allowed range: (0, inf)), got {V}")
    if V_argument is not None and abs(V - V_argument) > _V_RTOL * max(V, V_argument):
        raise _npz_error(path, "V" + suffix, f"V conflicts: {V:g} m/s in the file, {V_argument:g} m/s given")
    t = _array(data, "t" + suffix, path)
    fields = {"v": _array(data, "v" + suffix, path)}
    if fields["v"].shape != t.shape:
        raise _npz_error(path, "v" + suffix, f"'t{suffix}' and 'v{suffix}' must have one length")
    _check_series(path, "v" + suffix, "t" + suffix, t, fields["v"])
    for q in ("F", "alpha"):
        if q + suffix in keys:
            values = _array(data, q + suffix, path)
            time_key = f"t_{q}{suffix}" if f"t_{q}{suffix}" in keys else "t" + suffix
            times = _array(data, time_key, path)
            if times.shape != values.shape:
                raise _npz_error(path, q + suffix, f"{q}{suffix} and its times {time_key!r} must have one length")
            _check_series(path, q + suffix, time_key, times, values)
            fields[q], fields[f"t_{q}"] = values, times
    observation = Observation(V=V, t=t, **fields)
    if len(observation.series("v")[0]) < 2:
        raise _npz_error(path, "v" + suffix, f"fewer than 2 finite v{suffix} values")
    return observation


def _read_npz_file(data, path, V_argument) -> tuple[list[Observation], dict[str, float]]:
    observations = []
    if "V_0" in data.files:
        i = 0
        while f"V_{i}" in data.files:
            observations.append(_npz_observation(data, path, f"_{i}", V_argument))
            i += 1
    else:
        observations.append(_npz_observation(data, path, "", V_argument))
    settings = {}
    if "tau" in data.files:
        tau = _scalar(data, "tau", path)
        if not math.isfinite(tau) or tau < 0:
            raise _npz_error(path, "tau", f"tau must be a finite number >= 0 (allowed range: [0, inf)), got {tau}")
        settings["tau"] = tau
    if "dt" in data.files:
        try:
            dt = _scalar(data, "dt", path)
        except ValueError:
            dt = math.nan
        if math.isfinite(dt) and dt > 0:  # NaN: the run had error control, no uniform step
            settings["dt"] = dt
    return observations, settings


# ---------------------------------------------------------------------------- stick-slip tables
def _table_checks(V: np.ndarray, values: dict, std: dict, fail) -> None:
    """The rules of a stick-slip table (module docstring); ``fail(row, column, reason)`` makes
    the exception for the row (index into the unsorted input) and column at fault."""
    if V.size == 0:
        raise fail(None, "V", "no rows")
    for i in range(V.size):
        if not np.isfinite(V[i]):
            raise fail(i, "V", "V is required in every row (a finite number)")
        if V[i] <= 0:
            raise fail(i, "V", f"V must be > 0 (allowed range: (0, inf)), got {V[i]:g}")
    order = np.argsort(V, kind="stable")
    repeat = np.flatnonzero(np.diff(V[order]) == 0)
    if repeat.size:
        first, second = sorted((int(order[repeat[0]]), int(order[repeat[0] + 1])))
        raise fail(second, "V", f"V = {V[second]:g} m/s is given twice ({fail.where(first)} too)")
    if not values:
        raise fail(None, None, f"no statistic: give at least one of {', '.join(STATISTICS)}")
    for name, column in values.items():
        if np.any(np.isinf(column)):
            raise fail(int(np.flatnonzero(np.isinf(column))[0]), name, "infinite value")
        if name in _POSITIVE and np.any(column <= 0):
            i = int(np.flatnonzero(column <= 0)[0])
            raise fail(i, name, f"{name} must be > 0 s, got {column[i]:g}")
    for name, column in std.items():
        if name not in values:
            raise fail(None, f"{name}_std", f"a standard deviation without its value: no column {name!r}")
        bad = ~np.isnan(column) & ~(np.isfinite(column) & (column > 0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise fail(i, f"{name}_std", f"a standard deviation must be finite and > 0, got {column[i]:g}")
        orphan = ~np.isnan(column) & np.isnan(values[name])
        if orphan.any():
            raise fail(int(np.flatnonzero(orphan)[0]), f"{name}_std", f"a standard deviation without its value {name}")
    if "F_slip" in values and "F_stick" in values:
        wrong = values["F_slip"] <= values["F_stick"]  # False where either is NaN
        if wrong.any():
            i = int(np.flatnonzero(wrong)[0])
            raise fail(
                i, "F_slip",
                f"F_slip = {values['F_slip'][i]:g} N must exceed F_stick = {values['F_stick'][i]:g} N "
                "(the tape slips at the sawtooth's maximum and re-sticks at its minimum)",
            )  # fmt: skip
    empty = np.all(np.stack([np.isnan(c) for c in values.values()]), axis=0)
    if empty.any():
        raise fail(int(np.flatnonzero(empty)[0]), None, "a row without any value")


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


@dataclasses.dataclass(frozen=True, eq=False)
class StickSlipTable:
    """Stick-slip statistics against the pull velocity: one row per V, increasing.

    Attributes:
        V: (n,) pull velocities [m/s], > 0, increasing, unique.
        values: statistic name → (n,) values, NaN where not measured; only the statistics
            given, in the order of :attr:`STATISTICS`: ``F_mean``, ``F_slip``, ``F_stick`` [N],
            ``period``, ``slip_duration`` [s].
        std: statistic name → (n,) standard deviations (> 0), NaN where not given; only for
            the statistics that came with a ``<name>_std`` column.

    Build one with :func:`read_stick_slip_table`, :meth:`from_dict` or
    :meth:`from_force_records`; arrays are read-only.
    """

    V: np.ndarray
    values: dict[str, np.ndarray]
    std: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)

    STATISTICS = STATISTICS

    def __post_init__(self):
        V = _frozen(self.V)
        values = {k: _frozen(self.values[k]) for k in STATISTICS if k in self.values}
        std = {k: _frozen(self.std[k]) for k in STATISTICS if k in self.std}
        unknown = sorted(set(self.values) - set(STATISTICS)) + sorted(
            f"{k}_std" for k in set(self.std) - set(STATISTICS)
        )
        if unknown:
            raise ValueError(f"unknown statistic(s) {unknown}; valid: {', '.join(STATISTICS)}")
        for name, column in [("V", V), *values.items(), *((f"{k}_std", c) for k, c in std.items())]:
            if column.shape != V.shape or column.ndim != 1:
                raise ValueError(f"{name} must be a 1-D array of the length of V ({V.size}), got shape {column.shape}")
        _table_checks(V, values, std, _index_fail)
        order = np.argsort(V, kind="stable")
        object.__setattr__(self, "V", _frozen(V[order]))
        object.__setattr__(self, "values", {k: _frozen(c[order]) for k, c in values.items()})
        object.__setattr__(self, "std", {k: _frozen(c[order]) for k, c in std.items()})

    @classmethod
    def from_dict(cls, mapping: Mapping | None = None, /, **columns) -> StickSlipTable:
        """A table from columns: ``from_dict(V=[...], F_mean=[...], F_mean_std=[...], ...)`` (or one
        mapping of the same names, e.g. a DataFrame's ``to_dict("list")``). NaN (or None) marks
        not measured; the rules of a table file apply, errors name the column and index."""
        columns = {**(dict(mapping) if mapping is not None else {}), **columns}
        unknown = [k for k in columns if k not in TABLE_UNITS]
        if unknown:
            raise ValueError(f"unknown column(s) {unknown}; valid names: {', '.join(TABLE_UNITS)}")
        if "V" not in columns:
            raise ValueError("missing the column 'V' (pull velocities [m/s])")

        def array(name):
            try:
                a = np.asarray(columns[name], dtype=np.float64)
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be numbers (NaN or None: not measured), got {columns[name]!r}") from None
            return a.reshape(1) if a.ndim == 0 else a

        values = {k: array(k) for k in STATISTICS if k in columns}
        std = {k: array(f"{k}_std") for k in STATISTICS if f"{k}_std" in columns}
        orphans = [f"{k}_std" for k in std if k not in values]
        if orphans:
            raise ValueError(f"{orphans[0]}: a standard deviation without its value: no column {orphans[0][:-4]!r}")
        return cls(V=array("V"), values=values, std=std)

    @classmethod
    def from_force_records(
        cls, observations: Iterable[Observation], *, transient: float = 0.0, min_drop: float | None = None
    ) -> StickSlipTable:
        """The table of measured force records (each an :class:`Observation` with ``F``), one row
        per pull velocity: :func:`record_statistics` of each record after ``transient`` [s].

        Records at the same V are pooled: their cycles together give the per-cycle statistics
        and their spread, F_mean is the time-weighted mean of their time averages. A standard
        deviation is NaN where fewer than 2 values were found, or where the spread is at
        round-off level, below 1e-9 of the value (a noise-free periodic record: a table's
        standard deviations are > 0).
        """
        groups: dict[float, list[dict]] = {}
        for k, observation in enumerate(observations):
            series = observation.series("F")
            if series is None:
                raise ValueError(f"observation {k} (V = {observation.V:g}): no force F to take statistics of")
            groups.setdefault(float(observation.V), []).append(
                _record_cycles(series[0], series[1], transient=transient, min_drop=min_drop)
            )
        if not groups:
            raise ValueError("no force records")
        V = np.asarray(sorted(groups))
        values = {k: np.full(V.size, np.nan) for k in STATISTICS}
        std = {k: np.full(V.size, np.nan) for k in STATISTICS}
        for i, Vi in enumerate(V):
            records = groups[float(Vi)]
            durations = np.asarray([r["duration"] for r in records])
            values["F_mean"][i] = float(np.sum([r["F_mean"] * r["duration"] for r in records]) / durations.sum())
            pooled = {k: np.concatenate([r["cycles"][k] for r in records]) for k in records[0]["cycles"]}
            std["F_mean"][i] = _std(pooled["F_mean"])
            for k in ("F_slip", "F_stick", "period", "slip_duration"):
                if pooled[k].size:
                    values[k][i], std[k][i] = float(np.mean(pooled[k])), _std(pooled[k])
        for k in STATISTICS:  # a spread at round-off level: a noise-free periodic record, no std
            std[k][~(std[k] > _ROUNDOFF * np.abs(values[k]))] = np.nan
        values = {k: c for k, c in values.items() if not np.all(np.isnan(c))}
        std = {k: c for k, c in std.items() if k in values and not np.all(np.isnan(c))}
        return cls(V=V, values=values, std=std)

    @property
    def statistics(self) -> tuple[str, ...]:
        """The statistics present (columns of :attr:`values`), in the order of :attr:`STATISTICS`."""
        return tuple(self.values)

    def __len__(self) -> int:
        return int(self.V.size)

    def __eq__(self, other) -> bool:
        if not isinstance(other, StickSlipTable):
            return NotImplemented

        def same(a, b):
            return a.keys() == b.keys() and all(np.array_equal(a[k], b[k], equal_nan=True) for k in a)

        return np.array_equal(self.V, other.V) and same(self.values, other.values) and same(self.std, other.std)

    __hash__ = None

    def columns(self) -> list[str]:
        """The file's column names: V, then each statistic followed by its ``_std`` where given."""
        names = ["V"]
        for k in self.values:
            names += [k, f"{k}_std"] if k in self.std else [k]
        return names

    def _column(self, name: str) -> np.ndarray:
        if name == "V":
            return self.V
        return self.std[name[:-4]] if name.endswith("_std") else self.values[name]

    def to_csv(self, path) -> None:
        """Write the table as CSV (:func:`read_stick_slip_table` reads it back unchanged): a
        comment with the units, the header, one row per V, an empty cell where not measured."""
        names = self.columns()
        lines = [
            "# peeljax stick-slip table: one row per pull velocity V",
            (
                "# units: V [m/s]; F_mean, F_slip, F_stick [N]; period, slip_duration [s]; <name>_std: the standard "
                "deviation of <name>, same unit"
            ),
            "# an empty cell: not measured at that V",
            ",".join(names),
        ]
        cells = [[("" if math.isnan(x) else repr(float(x))) for x in self._column(n)] for n in names]
        lines += [",".join(row) for row in zip(*cells)]
        Path(path).write_text("\n".join(lines) + "\n")

    def _rows(self, limit: int | None = None) -> list[str]:
        heads = ["V [m/s]"] + [f"{k} [{_STAT_UNITS[k]}]" for k in self.values]
        rows = []
        for i in range(len(self)):
            row = [f"{self.V[i]:.6g}"]
            for k, c in self.values.items():
                s = self.std[k][i] if k in self.std else math.nan
                row.append("-" if math.isnan(c[i]) else f"{c[i]:.5g}" + ("" if math.isnan(s) else f" ± {s:.2g}"))
            rows.append(row)
        shown = rows if limit is None or len(rows) <= limit else rows[: limit - 2] + [["…"] * len(heads)] + rows[-1:]
        widths = [max(len(r[j]) for r in [heads, *shown]) for j in range(len(heads))]
        return ["  ".join(cell.rjust(w) for cell, w in zip(r, widths)) for r in [heads, *shown]]

    def __str__(self) -> str:
        return "\n".join(self._rows())

    def __repr__(self) -> str:
        head = f"StickSlipTable({len(self)} V in [{self.V[0]:g}, {self.V[-1]:g}] m/s: {', '.join(self.statistics)})"
        return "\n".join([head, *self._rows(limit=12)])


class _IndexFail:
    """Errors of :meth:`StickSlipTable.from_dict`: name the column and the row's index."""

    @staticmethod
    def where(row: int) -> str:
        return f"index {row}"

    def __call__(self, row, column, reason):
        at = "" if row is None else f"[{row}]"
        return ValueError(f"{column or 'table'}{at}: {reason}")


_index_fail = _IndexFail()


class _LineFail:
    """Errors of :func:`read_stick_slip_table`: a :class:`DataFileError` naming line and column."""

    def __init__(self, text: _Text):
        self.text = text

    def where(self, row: int) -> str:
        return f"line {self.text.lines[row]}"

    def __call__(self, row, column, reason):
        return self.text.fail(reason, row=row, column=column)


def read_stick_slip_table(path) -> StickSlipTable:
    """A stick-slip table from a CSV or whitespace-separated text file (the format and the
    refusals are in the module docstring); rows are sorted by V.

    Raises:
        DataFileError: naming the file, the line and the column at fault.
    """
    text = _read_text(path, TABLE_UNITS, ("V",), "stick-slip table")
    if not any(name in STATISTICS for name in text.names):
        raise text.fail(f"no statistic column: give at least one of {', '.join(STATISTICS)}", column=None)
    for name in text.names:
        if name.endswith("_std") and name[:-4] not in text.names:
            raise text.fail(f"a standard deviation without its value: no column {name[:-4]!r}", column=name)
    V = _numbers(text, "V", missing_ok=True)
    values = {k: _numbers(text, k, missing_ok=True) for k in STATISTICS if k in text.names}
    std = {k: _numbers(text, f"{k}_std", missing_ok=True) for k in STATISTICS if f"{k}_std" in text.names}
    _table_checks(V, values, std, _LineFail(text))
    return StickSlipTable(V=V, values=values, std=std)


# ---------------------------------------------------------------------------- statistics of a record
MIN_DROP_NOISE = 10.0  # default min_drop: this many times the estimated noise …
MIN_DROP_RANGE = 0.01  # … and at least this fraction of the record's peak-to-peak range


def _noise(F: np.ndarray) -> float:
    """The white noise's standard deviation, estimated from second differences (robust: the
    median absolute deviation, which the few samples of each slip do not move)."""
    if F.size < 3:
        return 0.0
    d2 = np.diff(F, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


def _extrema(F: np.ndarray, drop: float) -> tuple[np.ndarray, np.ndarray]:
    """Hysteresis extrema: indices of the maxima (each followed by a fall of more than ``drop``
    below it) and of the minima (each followed by a rise of more than ``drop``), alternating.
    The first extremum found is left out: the window may have cut its rise or fall."""
    peaks, troughs = [], []
    i_max = i_min = 0
    mode = 0  # 0: neither found yet; +1: after a minimum, seeking a maximum; -1: after a maximum
    for i in range(1, F.size):
        x = F[i]
        if mode >= 0:
            if x > F[i_max]:
                i_max = i
            if F[i_max] - x > drop:
                peaks.append(i_max)
                mode, i_min = -1, i
                continue
        if mode <= 0:
            if x < F[i_min]:
                i_min = i
            if x - F[i_min] > drop:
                troughs.append(i_min)
                mode, i_max = 1, i
    found = sorted([(p, 1) for p in peaks] + [(q, -1) for q in troughs])[1:]
    return np.asarray([i for i, kind in found if kind == 1], int), np.asarray(
        [i for i, kind in found if kind == -1], int
    )


def _integral(F: np.ndarray, t: np.ndarray) -> float:
    """∫ F dt by the trapezoid rule."""
    return float(np.sum(0.5 * (F[1:] + F[:-1]) * np.diff(t)))


def _std(x: np.ndarray) -> float:
    return float(np.std(x, ddof=1)) if x.size >= 2 else math.nan


def _record_cycles(t, F, *, transient: float = 0.0, min_drop: float | None = None) -> dict:
    t = np.asarray(t, dtype=np.float64)
    F = np.asarray(F, dtype=np.float64)
    if t.ndim != 1 or t.shape != F.shape:
        raise ValueError(f"t and F must be 1-D arrays of one length, got shapes {t.shape} and {F.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(F))):
        raise ValueError("t and F must be finite")
    if np.any(np.diff(t) <= 0):
        raise ValueError("t must increase strictly")
    transient = float(transient)
    if not (math.isfinite(transient) and transient >= 0):
        raise ValueError(f"transient must be a finite number >= 0, got {transient!r}")
    window = t >= transient
    if window.sum() < 2:
        raise ValueError(f"fewer than 2 samples after the transient {transient:g} s (the record ends at {t[-1]:g} s)")
    t, F = t[window], F[window]
    noise = _noise(F)
    if min_drop is None:
        drop = max(MIN_DROP_NOISE * noise, MIN_DROP_RANGE * float(np.ptp(F)))
    else:
        drop = float(min_drop)
        if not (math.isfinite(drop) and drop > 0):
            raise ValueError(f"min_drop must be > 0 [N], got {min_drop!r}")
    peaks, troughs = _extrema(F, drop) if drop > 0 else (np.zeros(0, int), np.zeros(0, int))
    # a slip: a maximum and the minimum that follows it (they alternate: before the next maximum)
    nxt = np.searchsorted(troughs, peaks)
    has = nxt < troughs.size
    slip_duration = t[troughs[nxt[has]]] - t[peaks[has]]
    cycle_means = np.asarray(
        [_integral(F[a : b + 1], t[a : b + 1]) / (t[b] - t[a]) for a, b in itertools.pairwise(peaks)]
    )
    duration = float(t[-1] - t[0])
    return {
        "F_mean": float(_integral(F, t) / duration),
        "duration": duration,
        "cycles": {
            "F_mean": cycle_means,
            "F_slip": F[peaks],
            "F_stick": F[troughs],
            "period": np.diff(t[peaks]),
            "slip_duration": slip_duration,
        },
        "t_slip": t[peaks],
        "t_stick": t[troughs],
        "min_drop": drop,
        "noise": noise,
        "window": (float(t[0]), float(t[-1])),
    }


def record_statistics(t, F, *, transient: float = 0.0, min_drop: float | None = None) -> dict:
    """The stick-slip statistics of a measured force record F(t) (a sawtooth), after ``transient``.

    **Slips.** A slip is a fall of F by more than ``min_drop`` [N] below its running maximum;
    the next one counts only after F has risen by more than ``min_drop`` above its running
    minimum (hysteresis: noise smaller than ``min_drop`` neither makes nor splits a slip). The
    first extremum found in the window is left out (the window may cut it). Default
    ``min_drop``: the larger of 10 times the record's white-noise level (estimated from the
    median absolute deviation of its second differences, which assumes samples dense enough
    that F changes smoothly between slips) and 1 % of its peak-to-peak range. Not a fixed
    fraction of the range: the model's slips come in bursts of unequal size (V = 1.1 m/s:
    drops of 17–28 N and re-stick rises of 6–20 N within a range of 118 N; V = 3 m/s: drops
    down to 2.3 N, rises to 0.4 N in 220 N), so a quarter of the range would see none of them.
    Slips smaller than ``min_drop`` — or whose re-stick rise is — are merged with their
    neighbours: check ``slips`` against the record, and pass ``min_drop`` where it misjudges.

    **Per slip**: ``F_slip``, the maximum of F before the fall (the stick → slip instant: in
    the model F is continuous and largest there); ``F_stick``, the minimum after it (slip →
    stick); ``slip_duration``, from that maximum to that minimum; ``period``, between
    consecutive maxima. ``F_mean`` is the time average of F over the window (trapezoid rule),
    its ``F_mean_std`` the spread of the time averages over the cycles (maximum to maximum).
    Each statistic is given as its mean over the slips in the window and ``<name>_std``, their
    sample standard deviation (NaN for fewer than 2 values). The times are those of the
    samples: within a sample spacing of the true instants.

    Returns:
        a dict with ``F_mean``, ``F_mean_std`` and, where at least one value was found,
        ``F_slip``, ``F_stick``, ``period``, ``slip_duration`` with their ``_std``; and
        ``slips`` (the number of maxima found), ``t_slip``/``t_stick`` (the times of the
        maxima/minima), ``min_drop`` (the threshold used), ``noise`` (the estimated noise
        level) and ``window`` (first and last time used). A record without slips (steady
        peeling) has only ``F_mean`` of the statistics.
    """
    r = _record_cycles(t, F, transient=transient, min_drop=min_drop)
    out = {"F_mean": r["F_mean"], "F_mean_std": _std(r["cycles"]["F_mean"])}
    for name in ("F_slip", "F_stick", "period", "slip_duration"):
        values = r["cycles"][name]
        if values.size:
            out[name], out[f"{name}_std"] = float(np.mean(values)), _std(values)
    out.update(
        slips=int(r["t_slip"].size), t_slip=r["t_slip"], t_stick=r["t_stick"], min_drop=r["min_drop"],
        noise=r["noise"], window=r["window"],
    )  # fmt: skip
    return out
