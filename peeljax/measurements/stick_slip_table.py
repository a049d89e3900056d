"""The stick-slip table: stick-slip statistics against the pull velocity, one row per V.

:class:`StickSlipTable` is what :func:`~peeljax.fit.fit_stick_slip` fits to; build one from a
file (:func:`read_stick_slip_table`), from columns (:meth:`StickSlipTable.from_dict`) or from
measured force records (:meth:`StickSlipTable.from_force_records`, by
:func:`~peeljax.measurements.record_statistics`). Plain NumPy on the host, in float64; a file is only
ever read as numbers, never executed.

**The file** (a CSV or whitespace-separated text file, :mod:`.text_tables`): one row per pull
velocity; ``V`` [m/s] and any of ``F_mean``, ``F_slip`` (the force at which the tape slips),
``F_stick`` (at which it re-sticks) [N], ``period`` (the time between consecutive slips),
``slip_duration`` [s], each optionally with a standard deviation column ``<name>_std`` (same
unit). An empty cell (CSV) or ``-`` (either format) means not measured at that V; a literal
``nan`` is refused, as are ``inf``, text, V ≤ 0, a V given twice,
``period``/``slip_duration``/standard deviations ≤ 0, ``F_slip`` ≤ ``F_stick`` in a row, a
standard deviation without its value and a row without any value. A refused file raises a
:class:`~peeljax.measurements.DataFileError` naming the file, the line and the column.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping

import numpy as np

from .._atomic import write_text
from .statistics import STATISTICS, record_cycles, sample_std
from .text_tables import TextTable, column_numbers, read_text_table
from .observations import Observation

__all__ = ["STATISTICS", "TABLE_UNITS", "StickSlipTable", "read_stick_slip_table"]

_STAT_UNITS = {"F_mean": "N", "F_slip": "N", "F_stick": "N", "period": "s", "slip_duration": "s"}
# Columns of a stick-slip table and their units.
TABLE_UNITS: dict[str, str] = {"V": "m/s", **_STAT_UNITS, **{f"{k}_std": u for k, u in _STAT_UNITS.items()}}
_POSITIVE = ("period", "slip_duration")  # durations: > 0 where measured
_ROUNDOFF = 1e-9  # from_force_records: a relative spread below this is no standard deviation


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
        cls, observations: Iterable[Observation], *, transient: float = 0.0, min_drop: float | None = None,
        std: str = "cycle", smooth: float = 0.0, noise_factor: float | None = None,
    ) -> StickSlipTable:  # fmt: skip
        """The table of measured force records (each an :class:`Observation` with ``F``), one row
        per pull velocity: :func:`record_statistics` of each record after ``transient`` [s].

        Records at the same V are pooled: their cycles together give the per-cycle statistics
        and their spread, F_mean is the time-weighted mean of their time averages. ``std``:
        ``"cycle"`` (default) gives each statistic the per-cycle sample standard deviation,
        ``"error"`` the standard error of its mean, that divided by √n (n its cycles; what a fit
        of the attractor's statistics needs). ``smooth``, ``noise_factor``: for noisy records,
        :func:`record_statistics`'s. A standard deviation is NaN where fewer than 2
        values were found, or where the spread is at round-off level, below 1e-9 of the value
        (a noise-free periodic record: a table's standard deviations are > 0).
        """
        if std not in ("cycle", "error"):
            raise ValueError(f"std must be 'cycle' or 'error', got {std!r}")
        per_mean = std == "error"
        groups: dict[float, list[dict]] = {}
        for k, observation in enumerate(observations):
            series = observation.series("F")
            if series is None:
                raise ValueError(f"observation {k} (V = {observation.V:g}): no force F to take statistics of")
            groups.setdefault(float(observation.V), []).append(
                record_cycles(series[0], series[1], transient=transient, min_drop=min_drop, smooth=smooth,
                              **({} if noise_factor is None else {"noise_factor": noise_factor}))  # fmt: skip
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
            per = (lambda x: 1.0 / math.sqrt(max(x.size, 1))) if per_mean else (lambda x: 1.0)
            std["F_mean"][i] = sample_std(pooled["F_mean"]) * per(pooled["F_mean"])
            for k in ("F_slip", "F_stick", "period", "slip_duration"):
                if pooled[k].size:
                    values[k][i], std[k][i] = float(np.mean(pooled[k])), sample_std(pooled[k]) * per(pooled[k])
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
        write_text(path, "\n".join(lines) + "\n")

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

    def __init__(self, text: TextTable):
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
    text = read_text_table(path, TABLE_UNITS, ("V",), "stick-slip table", missing_ok=True)
    if not any(name in STATISTICS for name in text.names):
        raise text.fail(f"no statistic column: give at least one of {', '.join(STATISTICS)}", column=None)
    for name in text.names:
        if name.endswith("_std") and name[:-4] not in text.names:
            raise text.fail(f"a standard deviation without its value: no column {name[:-4]!r}", column=name)
    V = column_numbers(text, "V", missing_ok=True)
    values = {k: column_numbers(text, k, missing_ok=True) for k in STATISTICS if k in text.names}
    std = {k: column_numbers(text, f"{k}_std", missing_ok=True) for k in STATISTICS if f"{k}_std" in text.names}
    _table_checks(V, values, std, _LineFail(text))
    return StickSlipTable(V=V, values=values, std=std)

