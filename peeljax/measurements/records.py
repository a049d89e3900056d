"""Measured runs read from a lab's files: text force records and ``.npz`` observations.

Plain NumPy on the host, in float64; a data file is only ever read as numbers
(``np.load(..., allow_pickle=False)`` for ``.npz``), never executed.

**Force records** (:func:`read_force_record`, :func:`read_observations`): one run at one
pull velocity V, as a CSV (comma-separated) or whitespace-separated text file
(:mod:`.text_tables`: ``#`` comments, a header naming the columns, each name optionally
followed by its unit in brackets, ``t [s]``, ``F[N]``; a different unit is refused, not
converted):

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

``.npz`` files (:func:`read_npz`) keep the layouts of ``peeljax fit --data`` (scalar ``V`` and
1-D ``t``, ``v``, optional ``F``, ``alpha`` with optional own times ``t_F``, ``t_alpha``; or
``V_0, t_0, v_0``, ``V_1``, … for several V in one file). NaN in a *quantity* marks a missing
value there (a ``peeljax simulate --out`` file after a stop); times must be finite and ≥ 0,
and an optional ``tau`` must be a finite number ≥ 0.

Every refusal of a file is a :class:`~peeljax.measurements.DataFileError` (a ``ValueError``) whose
message names the file, the line and the column, or for ``.npz`` the field.
"""

from __future__ import annotations

import dataclasses

import math
import os
import re
import zipfile
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .._files import check_input_file
from .._npz import check_declared_sizes
from .text_tables import DataFileError, column_numbers, read_text_table
from .observations import Observation

__all__ = [
    "FILE_NAME_V", "FIT_BYTES_PER_SAMPLE", "FORCE_COLUMNS", "MAX_FIT_SAMPLES", "check_fit_samples", "decimate",
    "load_observations", "read_force_record", "read_npz", "read_observations",
]  # fmt: skip

# A point-by-point fit (fit_adhesion) compiles a program that holds the model's state at every
# sample time, forward and for the gradient: 44 kB a sample measured (benchmarks/fit_memory.py, retired,
# results/fit_memory.md: the peak memory's slope from 2 000 to 32 000 samples; XLA asked for
# 228 GB, 38 kB a sample, for a 6e6-row record). MAX_FIT_SAMPLES keeps it near 1 GB; a denser
# record is refused before compiling, and may be decimated on request.
FIT_BYTES_PER_SAMPLE = 44e3
MAX_FIT_SAMPLES = 25_000

# Columns of a force record and their units (the header may repeat the unit in brackets).
FORCE_COLUMNS: dict[str, str] = {
    "t": "s", "F": "N", "v": "m/s", "alpha": "rad", "V": "m/s",
    # a run written as text (``peeljax simulate --out run.csv``): ω, u and G are not fitted; the rows
    # after a jump are left out (after_jump 1), as in a run's .npz
    "omega": "rad/s", "u": "m", "G": "N", "after_jump": "1",
}  # fmt: skip
_FORCE_REQUIRED = ("t", "F")

# The pull velocity in a file name: see the module docstring.
FILE_NAME_V = re.compile(r"(?:^|(?<=[_\-\s]))V[=_]?(\d+(?:\.\d*)?)(?=$|[_\-\s])")
_SUFFIX = re.compile(r"\.[A-Za-z][A-Za-z0-9]*$")
_V_RTOL = 1e-9  # V from two sources must agree to this


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


def read_force_record(path, *, V: float | None = None, memory_limit: float | None = None) -> Observation:
    """One measured run at one pull velocity, from a CSV or whitespace-separated text file.

    The format, units and refusals are in the module docstring: columns ``t`` [s] and ``F``
    [N] (the tension) required, ``v`` [m/s], ``alpha`` [rad] and a constant ``V`` [m/s]
    optional; V from the ``V`` column, the file name (``peel_V=1.1.csv``) or ``V`` here,
    which must agree where several are given.

    The rows are parsed by NumPy's C reader, about 8 bytes a number; a file whose numbers would
    take more than ``memory_limit`` bytes (default: half the RAM), estimated from its size
    before it is read, is refused naming the estimate (:mod:`.text_tables`).

    Returns:
        an :class:`~peeljax.measurements.Observation` with ``t`` and ``F``, and ``v``/``alpha`` where
        the file has them (``v`` is None otherwise), all float64 on the times ``t``.

    Raises:
        DataFileError: a malformed file, named with the line and column at fault, or one too
            large for the memory.
        ValueError: a ``V`` argument that is not a number > 0.
    """
    V = _check_V_argument(V)
    text = read_text_table(path, FORCE_COLUMNS, _FORCE_REQUIRED, "force record", memory_limit=memory_limit)
    if text.n_rows < 2:
        raise text.fail("one data row: a force record needs at least 2", row=0)
    columns = {name: column_numbers(text, name, missing_ok=False) for name in text.names}
    if "after_jump" in columns:  # a run's text: its left limits, as from its .npz
        after = columns.pop("after_jump")
        if not np.all((after == 0) | (after == 1)):
            row = int(np.flatnonzero((after != 0) & (after != 1))[0])
            raise text.fail("after_jump must be 0 or 1 (1: the row just after a jump)", row=row, column="after_jump")
        keep = left_limit_rows(columns["t"], after == 1)
        columns = {name: column[keep] for name, column in columns.items()}
        text = dataclasses.replace(text, columns=columns, _lines=np.asarray(text.lines)[keep])
    t = columns["t"]
    if np.any(t < 0):
        row = int(np.flatnonzero(t < 0)[0])
        raise text.fail(f"negative time {t[row]:g} s (times are >= 0)", row=row, column="t")
    if np.any(t[1:] <= t[:-1]):  # a mask, not np.diff: no second copy of a long record's times
        row = int(np.flatnonzero(t[1:] <= t[:-1])[0]) + 1
        raise text.fail(
            f"t must increase strictly: {t[row]:g} s after {t[row - 1]:g} s (line {text.lines[row - 1]})",
            row=row, column="t",
        )  # fmt: skip
    for name in ("F", "v"):  # a tension and a peeling velocity are >= 0
        negative = _first_negative(columns.get(name))
        if negative is not None:
            raise text.fail(
                f"{name} must be >= 0 {_UNITS[name]} ({_MEANING[name]}), got {columns[name][negative]:g} at t = "
                f"{t[negative]:g} s", row=negative, column=name,
            )  # fmt: skip
    outside = _first_outside_angle(columns.get("alpha"))
    if outside is not None:
        raise text.fail(
            f"alpha must lie in (-pi, pi) rad, got {columns['alpha'][outside]:g} at t = {t[outside]:g} s (degrees?)",
            row=outside, column="alpha",
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


def decimate(observation: Observation, every: int) -> Observation:
    """The observation with every ``every``-th sample of each series kept (the first included):
    measured values, not filtered ones. The kept arrays are copies, so the full record can be
    freed and a fit's program is sized to what is kept."""
    _check_every(every)
    if every == 1:
        return observation

    def keep(values):
        return None if values is None else np.ascontiguousarray(np.asarray(values)[::every])

    return Observation(
        V=observation.V, t=keep(observation.t), v=keep(observation.v), F=keep(observation.F),
        alpha=keep(observation.alpha), t_F=keep(observation.t_F), t_alpha=keep(observation.t_alpha),
    )  # fmt: skip


def _check_every(every) -> None:
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ValueError(f"decimate must be an integer >= 1 (allowed range: [1, inf)), got {every!r}")


_thin = decimate  # (load_observations' parameter of that name hides it)


def check_fit_samples(observations: list[Observation], names: list[str], option: str = "decimate") -> None:
    """Refuse (ValueError) a record far denser than a point-by-point fit can hold: more than
    :data:`MAX_FIT_SAMPLES` samples in one series. The message names the record (``names``,
    one per observation), its sample spacing and the ``option`` value that thins it enough."""
    for observation, name in zip(observations, names):
        t = np.asarray(observation.t)
        n = max(np.asarray(getattr(observation, q)).size for q in ("t", "t_F", "t_alpha")
                if getattr(observation, q) is not None)  # fmt: skip
        if n <= MAX_FIT_SAMPLES:
            continue
        spacing = float(np.median(np.diff(t[: min(t.size, 10_001)]))) if t.size > 1 else math.nan
        every = -(-n // MAX_FIT_SAMPLES)
        raise ValueError(
            f"{name} holds {n} samples ({spacing:.3g} s apart, over {float(t[-1] - t[0]):.4g} s): far denser than a "
            f"point-by-point fit can use: its compiled program keeps the model's state at every sample, about "
            f"{FIT_BYTES_PER_SAMPLE / 1e3:.0f} kB each ({n * FIT_BYTES_PER_SAMPLE / 1e9:.3g} GB here), and takes at "
            f"most {MAX_FIT_SAMPLES}: keep every {every}th sample ({option} {every}: {spacing * every:.3g} s apart), "
            "or give a shorter record"
        )


def read_observations(path, *, V: float | None = None) -> list[Observation]:
    """The observations in one data file: a ``.npz`` (either layout; every pull velocity in it)
    or, for any other suffix, a text force record (:func:`read_force_record`, one observation).

    ``V`` is the pull velocity for a text file without a ``V`` column or V in its name; for a
    ``.npz`` (which carries its own) it must agree with every V in the file.
    """
    if Path(str(path)).suffix.lower() == ".npz":
        return read_npz(path, V=V)[0]
    return [read_force_record(path, V=V)]


def load_observations(
    paths: Sequence[str | os.PathLike], V: float | Sequence[float] | None = None, decimate: int | None = None
) -> tuple[list[Observation], dict[str, float]]:
    """The observations of several data files (:func:`read_observations`, file by file) and the settings that
    their ``.npz`` files agree on.

    Args:
        paths: the data files: ``.npz`` (either layout), any other suffix a text force record.
        V: the pull velocity [m/s], > 0, of the text files that carry it neither in a ``V`` column nor in
            their name: one value for every file, or one per file in order.
        decimate: keep every N-th sample of each file (:func:`decimate`), an integer >= 1.

    Returns:
        The observations, and ``{"tau": ..., "dt": ...}``: each setting the ``.npz`` files give one value of.

    Raises:
        ValueError: ``decimate`` or ``V`` out of range, checked before any file is read; a missing file, a
            folder or a file refused (:class:`~peeljax.measurements.DataFileError`), as ``paths: <why, naming the file>``.
    """
    if decimate is not None:
        _check_every(decimate)
    V_files = [V] * len(paths) if V is None or np.ndim(V) == 0 else list(V)
    if len(V_files) == 1:
        V_files = V_files * len(paths)
    if len(V_files) != len(paths):
        raise ValueError(f"V takes one value for all data files or one per file: {len(V_files)} values for {len(paths)} files")
    V_files = [_check_V_argument(value) for value in V_files]
    observations, settings = [], {"tau": set(), "dt": set()}
    for path, V_file in zip(paths, V_files):
        check_input_file("paths", str(path))
        try:
            if Path(str(path)).suffix.lower() == ".npz":
                found, given = read_npz(path, V=V_file)
                for key, value in given.items():
                    settings[key].add(value)
            else:
                found = [read_force_record(path, V=V_file)]
        except DataFileError as error:
            raise ValueError(f"paths: {error}") from None
        observations.extend(found if decimate is None else [_thin(o, decimate) for o in found])
    return observations, {key: next(iter(values)) for key, values in settings.items() if len(values) == 1}


# ---------------------------------------------------------------------------- .npz files
# What zipfile raises for damaged bytes: a bad CRC or directory, a broken deflate stream, a cut
# member, and (flipped flag bits) "compression method not supported" or "encrypted".
_DAMAGED_ZIP = (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError)


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
        if hasattr(data, "files"):  # before numpy allocates what a damaged header declares
            check_declared_sizes(path)
    except Exception as error:  # noqa: BLE001  (any failure to parse the file is bad input)
        if str(error).startswith("too large"):
            raise DataFileError(path, str(error)) from None
        if str(error).startswith("damaged") or isinstance(error, _DAMAGED_ZIP):
            raise DataFileError(path, f"damaged .npz ({str(error).removeprefix('damaged: ')})") from None
        raise DataFileError(path, f"not a readable .npz without pickles ({type(error).__name__})") from None
    if not hasattr(data, "files"):
        raise DataFileError(path, "expected an .npz archive of named arrays")
    with data:
        try:
            return _read_npz_file(data, path, V)
        except (*_DAMAGED_ZIP, OSError) as error:  # a member's bytes corrupt
            raise DataFileError(path, f"damaged .npz: an array cannot be read ({error})") from None
        except ValueError as error:
            if not isinstance(error, DataFileError) and "allow_pickle" in str(error):
                raise DataFileError(path, "not a readable .npz without pickles (object arrays)") from None
            if not isinstance(error, DataFileError):  # numpy's own: a header or data it cannot parse
                raise DataFileError(path, f"damaged .npz: an array cannot be read ({error})") from None
            raise


_UNITS = {"F": "N", "v": "m/s"}
_MEANING = {"F": "the tape's tension", "v": "the peeling velocity"}


def _first_negative(values) -> int | None:
    """The index of the first entry < 0 (NaN is a missing entry, not one), or None."""
    if values is None:
        return None
    negative = np.flatnonzero(values < 0)
    return int(negative[0]) if negative.size else None


def _first_outside_angle(values) -> int | None:
    """The index of the first angle not in (−π, π) rad (NaN is a missing entry), or None."""
    if values is None:
        return None
    outside = np.flatnonzero(np.abs(values) >= np.pi)
    return int(outside[0]) if outside.size else None


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
    """NaN in a quantity marks a missing entry (ignored); an infinite value, a negative tension
    or peeling velocity, or times that are not finite, are negative or do not increase, mean a
    broken file."""
    if np.any(np.isinf(values)):
        raise _npz_error(path, key, f"{key!r} has infinite entries (NaN marks a missing value; inf is not one)")
    name = key.split("_")[0]
    outside = _first_outside_angle(values) if name == "alpha" else None
    if outside is not None:
        raise _npz_error(
            path, key, f"{key!r} must lie in (-pi, pi) rad, got {values[outside]:g} at index {outside} (degrees?)"
        )
    negative = _first_negative(values) if name in _UNITS else None
    if negative is not None:
        raise _npz_error(
            path, key, f"{key!r} must be >= 0 {_UNITS[name]} ({_MEANING[name]}), got {values[negative]:g} at index "
            f"{negative} (t = {times[negative]:g} s)",
        )  # fmt: skip
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


def _left_limits(data, path: str, suffix: str, t: np.ndarray) -> np.ndarray:
    """Which rows of a run file's ``t`` a record keeps: a run keeps both sides of every jump (two
    rows at its time, the second marked in ``after_jump``; ``peeljax simulate --out``), a record
    one value per time, the left limit. The rows after a jump are left out, and so is an output
    time equal to a jump's time (it holds the same state as the row before the jump)."""
    key = "after_jump" + suffix
    if key not in data.files:
        return np.ones(t.shape, bool)
    after = np.asarray(data[key])
    if after.dtype != bool or after.shape != t.shape:
        raise _npz_error(path, key, f"{key!r} must be booleans of the length of 't{suffix}' (a run file's jump rows)")
    return left_limit_rows(t, after)


def left_limit_rows(t: np.ndarray, after_jump: np.ndarray) -> np.ndarray:
    """The rows of a run's output that hold its left limits, one per time: not after a jump,
    and not a second row at one time (an output time equal to a jump's: the state before it)."""
    keep = ~np.asarray(after_jump, bool)
    kept = np.flatnonzero(keep)
    keep[kept[1:][t[kept[1:]] == t[kept[:-1]]]] = False
    return keep


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
    left = _left_limits(data, path, suffix, t)
    t = t[left]
    fields = {"v": _array(data, "v" + suffix, path)}
    if fields["v"].shape != left.shape:
        raise _npz_error(path, "v" + suffix, f"'t{suffix}' and 'v{suffix}' must have one length")
    fields["v"] = fields["v"][left]
    _check_series(path, "v" + suffix, "t" + suffix, t, fields["v"])
    for q in ("F", "alpha"):
        if q + suffix in keys:
            values = _array(data, q + suffix, path)
            time_key = f"t_{q}{suffix}" if f"t_{q}{suffix}" in keys else "t" + suffix
            times = _array(data, time_key, path)
            if times.shape != values.shape:
                raise _npz_error(path, q + suffix, f"{q}{suffix} and its times {time_key!r} must have one length")
            if time_key == "t" + suffix:  # on the run's rows: the left limits, as v
                times, values = times[left], values[left]
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
