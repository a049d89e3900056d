"""The orbits' two file formats: one orbit's (what :meth:`PeriodicOrbit.save` writes and
:func:`peeljax.load` reads back as a :class:`~peeljax.orbits.SavedOrbit`) and a bifurcation
diagram's (what :meth:`OrbitDiagram.save` writes and :func:`peeljax.load` reads back as an
:class:`~peeljax.orbits.OrbitDiagram`). Both are ``.npz`` files of plain arrays (nothing in them
is code) with ``meta_json`` saying their kind, units and the peeljax that wrote them. This
module knows the arrays, not the classes (it imports none): :mod:`.orbit` and :mod:`.diagram`
write and read through it.

**An orbit's file** (kind ``"orbit"``).

The file is an ``.npz`` of plain arrays and scalars (``np.load(path, allow_pickle=False)``
reads it; nothing in it is code), with ``meta_json`` saying its kind (``"orbit"``), the units
of its arrays and the peeljax that wrote it (:mod:`peeljax._files`). It holds every field of a
:class:`~peeljax.orbits.PeriodicOrbit`, so the orbit read back is whole: its trajectory,
statistics and multipliers are there without shooting again, and its section point starts
Newton for a neighbouring orbit.

Arrays (SI units; the orbit's fields of the same names):

* ``V`` [m/s], ``slips`` (k), ``period`` (T) [s], ``force_integral`` [N·s], ``approach`` [N],
  ``crossing`` [N/s], ``section`` = (α, ω) [rad, rad/s] and ``state`` = (α, ω, u, v̂)
  [rad, rad/s, m, m/s] just before the slip at the section;
* ``monodromy`` (2 × 2, on the section's coordinates (α, ω)) and ``multipliers`` (complex, the
  larger modulus first);
* ``status`` and ``status_name`` (:class:`~peeljax.orbits.OrbitStatus`), ``reason``,
  ``run_status`` (the :class:`~peeljax.StopReason` of the period's last run), ``iterations``,
  ``residual``, ``steps``;
* the five statistics of one period: ``F_mean``, ``F_slip``, ``F_stick`` [N],
  ``time_between_slips`` (``statistics["period"]``, T/k) and ``slip_duration`` [s];
* the model: ``R`` [m], ``I`` [kg m2], ``k`` [N], ``l`` [m], ``geometry`` and ``phi_json`` (φ's
  14 coefficients);
* ``settings_json``: how it was found (rtol, atol, …; ``{}`` where not given).

``meta_json``'s ``units`` names the unit of every array of one unit (UDUNITS spelling).

A file that is not such an ``.npz`` (a missing or misshapen array, a status that is no
:class:`~peeljax.orbits.OrbitStatus`, a model outside its domain) is refused with a ValueError
naming the file and what is wrong. Files are written atomically (:mod:`peeljax._atomic`).

**A diagram's file** (kind ``"orbit_diagram"``): an ``.npz`` of plain arrays (``np.load(path, allow_pickle=False)`` reads it; text is stored as
fixed-width unicode arrays), ``meta_json`` saying its kind (``"orbit_diagram"``), the units
and the peeljax that wrote it (:mod:`peeljax._files`):

* every branch point, the branches one after another: ``point_branch`` (its branch's index),
  ``point_parameter`` (the continued parameter's value), ``V`` [m/s], ``slips``, ``period`` [s],
  the five statistics ``F_mean``, ``F_slip``, ``F_stick`` [N], ``time_between_slips``,
  ``slip_duration`` [s], ``multipliers`` (n × 2 complex), ``stable``, ``approach`` [N],
  ``crossing`` [N/s], ``section`` (n × 2: α [rad], ω [rad/s]), the test functions
  ``fold``, ``period_doubling``, ``torus``;
* ``branch_parameter`` (the parameter's name per branch) and ``branch_ends`` (why each ended,
  its lines joined by newlines);
* every bifurcation: ``bif_branch``, ``bif_kind``, ``bif_parameter``, ``bif_V``, ``bif_slips``,
  ``bif_note``;
* every seed run: ``seed_V``, ``seed_start``, ``seed_slips``, ``seed_period``, ``seed_F_slip``,
  ``seed_F_stick``, ``seed_interval``, ``seed_orbit``, ``seed_branch``;
* ``V_range``, ``wall_time``, ``seed_time`` [s]; ``complete`` (False: the diagram was
  interrupted, and holds the seeds and branches finished before; files without it are complete).
"""

from __future__ import annotations

import json
import os

import jax.numpy as jnp
import numpy as np

from .._atomic import write_npz
from .._files import META_KEY, json_safe, meta_array, read_meta
from ..adhesion import AdhesionLaw, in_a_file
from ..cycles import STATISTICS
from ..model import GEOMETRIES, PeelingModel
from ..solution import StopReason
from .shooting import OrbitStatus

__all__ = ["DIAGRAM_KIND", "KIND", "ORBIT_UNITS", "diagram_parts", "orbit_arrays", "orbit_fields", "write_diagram", "write_orbit"]

KIND = "orbit"
# The file's name of each statistic (``period`` is the orbit's T; the statistic is T/k).
_STATISTICS = {"F_mean": "F_mean", "F_slip": "F_slip", "F_stick": "F_stick", "period": "time_between_slips",
               "slip_duration": "slip_duration"}  # fmt: skip
_MODEL = ("R", "I", "k", "l")

ORBIT_UNITS: dict[str, str] = {
    "V": "m/s", "slips": "1", "period": "s", "force_integral": "N s", "approach": "N", "crossing": "N/s",
    "multipliers": "1",
    "residual": "1", "iterations": "1", "steps": "1",
    "F_mean": "N", "F_slip": "N", "F_stick": "N", "time_between_slips": "s", "slip_duration": "s",
    "R": "m", "I": "kg m2", "k": "N", "l": "m",
}  # fmt: skip


# The orbit's fields and their arrays in the file: shape, and the kind of number ("f" float,
# "i" integer, "c" complex). ``model`` and ``statistics`` are written apart; the reader checks
# every array against this table (tests/test_orbit_files.py: it covers every field).
_FIELDS: dict[str, tuple[tuple[int, ...], str]] = {
    "V": ((), "f"), "slips": ((), "i"), "section": ((2,), "f"), "state": ((4,), "f"), "period": ((), "f"),
    "force_integral": ((), "f"), "approach": ((), "f"), "crossing": ((), "f"), "monodromy": ((2, 2), "f"),
    "multipliers": ((2,), "c"),
    "status": ((), "i"), "run_status": ((), "i"), "iterations": ((), "i"), "residual": ((), "f"), "steps": ((), "i"),
}  # fmt: skip
# ±inf: no phase turned back towards a fold (approach), no slip crossed the section (crossing)
_MAY_BE_INFINITE = {"approach", "crossing"}


# ---------------------------------------------------------------------------- writing
def orbit_arrays(orbit, settings: dict | None = None) -> dict[str, np.ndarray]:
    """The arrays of an orbit's ``.npz`` (module docstring); ``settings``: JSON-able notes on
    how it was found (rtol, atol, …), kept in ``settings_json``.

    Raises:
        ValueError: a batch of orbits (save each), or a model whose φ is a callable, which a
            file of data cannot hold.
    """
    missing = [name for name in ("model", *_FIELDS, "statistics") if not hasattr(orbit, name)]
    if missing:
        raise TypeError(f"orbit must be a PeriodicOrbit, got {type(orbit).__name__} (without {', '.join(missing)})")
    if np.ndim(orbit.V) != 0:
        raise ValueError("save: one orbit per file; take one orbit out of the batch and save it")
    model = orbit.model
    if not in_a_file(model.adhesion):
        what = "a subclass of AdhesionLaw" if isinstance(model.adhesion, AdhesionLaw) else "a Python callable"
        raise ValueError(
            f"save: the orbit's adhesion law is {what}, which a file cannot hold (files are data, never code); "
            "use an AdhesionLaw to save it"
        )
    dtypes = {"f": np.float64, "i": np.int64, "c": np.complex128}
    arrays = {name: np.asarray(getattr(orbit, name), dtypes[kind]) for name, (_, kind) in _FIELDS.items()}
    arrays.update({name: np.float64(orbit.statistics[key]) for key, name in _STATISTICS.items()})
    arrays.update({name: np.float64(getattr(model, name)) for name in _MODEL})
    arrays.update(
        status_name=np.asarray(orbit.status_name, dtype=str),
        reason=np.asarray(orbit.reason, dtype=str),
        geometry=np.asarray(model.geometry, dtype=str),
        phi_json=np.asarray(json.dumps(model.adhesion.coefficients()), dtype=str),
        settings_json=np.asarray(
            json.dumps(json_safe({} if settings is None else dict(settings)), allow_nan=False), dtype=str
        ),
    )
    arrays[META_KEY] = meta_array(KIND, {key: unit for key, unit in ORBIT_UNITS.items() if key in arrays})
    return arrays


def write_orbit(path: str | os.PathLike, orbit, settings: dict | None = None) -> None:
    """Write ``orbit`` to ``path`` (:func:`orbit_arrays`; the name kept exactly as given), replaced
    only once complete: a failed write leaves the previous file as it was."""
    write_npz(path, orbit_arrays(orbit, settings))


# ---------------------------------------------------------------------------- reading
def _get(arrays: dict, key: str, name: str, shape: tuple = (), kind: str = "f") -> np.ndarray:
    """``arrays[key]`` of ``shape`` with numbers of ``kind`` (a float may be given as an
    integer, a complex as either), else a ValueError naming the file and the array."""
    if key not in arrays:
        raise ValueError(f"{name!r} is malformed: it has no {key!r}; expected an orbit's .npz (PeriodicOrbit.save)")
    value = np.asarray(arrays[key])
    kinds, what = {"f": ("fiu", "numbers"), "i": ("iu", "integers"), "c": ("cfiu", "numbers"), "U": ("U", "text")}[kind]
    if value.shape != shape or value.dtype.kind not in kinds:
        raise ValueError(
            f"{name!r} is malformed: {key} must be {what} of shape {shape}, got {value.dtype} of shape {value.shape}"
        )
    return value


def _json_object(arrays: dict, key: str, name: str) -> dict:
    text = str(_get(arrays, key, name, kind="U"))
    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"{name!r} is malformed: {key} is not JSON ({error})") from None
    if not isinstance(value, dict):
        raise ValueError(f"{name!r} is malformed: {key} is not a JSON object")
    return value


def _positive(value: float, key: str, name: str) -> float:
    if not (np.isfinite(value) and value > 0):
        raise ValueError(
            f"{name!r} is malformed: {key} must be finite and > 0 (allowed range: (0, inf)), got {value!r}"
        )
    return value


def _model(arrays: dict, name: str) -> PeelingModel:
    geometry = str(_get(arrays, "geometry", name, kind="U"))
    if geometry not in GEOMETRIES:
        raise ValueError(f"{name!r} is malformed: geometry {geometry!r} is none of {', '.join(GEOMETRIES)}")
    parameters = {key: _positive(float(_get(arrays, key, name)), key, name) for key in _MODEL}
    adhesion = AdhesionLaw.from_dict(_json_object(arrays, "phi_json", name), source=f"{name!r} (phi_json)")
    return PeelingModel(**parameters, adhesion=adhesion, geometry=geometry)


def orbit_fields(arrays: dict, name: str) -> dict:
    """The fields of an orbit's ``.npz`` arrays, checked (``name``: the file, for messages):
    the keyword arguments of :class:`~peeljax.orbits.PeriodicOrbit` (the model rebuilt from
    its parameters and φ's coefficients), and ``settings``, ``units``, ``peeljax_version``.

    Raises:
        ValueError: naming the file and the array, for a missing or misshapen array, a value
            outside its range, a status that is none, a model outside its domain.
    """
    meta = read_meta(arrays, name) or {}
    values = {key: _get(arrays, key, name, shape, kind) for key, (shape, kind) in _FIELDS.items()}
    for key, value in values.items():
        bad = np.isnan(value) if key in _MAY_BE_INFINITE else ~np.isfinite(value)
        if np.any(bad):
            what = "a number" if key in _MAY_BE_INFINITE else "finite"
            raise ValueError(f"{name!r} is malformed: {key} must be {what}, got {value.tolist()}")
    _positive(float(values["V"]), "V", name)
    if int(values["slips"]) < 1:
        raise ValueError(f"{name!r} is malformed: slips must be a positive integer, got {int(values['slips'])}")
    if int(values["status"]) not in OrbitStatus._value2member_map_:
        known = ", ".join(f"{s.value} ({s.name.lower()})" for s in OrbitStatus)
        raise ValueError(f"{name!r} is malformed: status {int(values['status'])} is no orbit status ({known})")
    if int(values["run_status"]) not in StopReason._value2member_map_:
        raise ValueError(f"{name!r} is malformed: run_status {int(values['run_status'])} is no StopReason")
    statistics = {}
    for key, file_key in _STATISTICS.items():
        value = _get(arrays, file_key, name)
        if not np.isfinite(value):
            raise ValueError(f"{name!r} is malformed: {file_key} must be finite, got {value.item()!r}")
        statistics[key] = jnp.asarray(value, float)
    settings = _json_object(arrays, "settings_json", name) if "settings_json" in arrays else {}
    dtypes = {"f": float, "i": jnp.int32, "c": complex}
    fields = {key: jnp.asarray(values[key], dtypes[kind]) for key, (_, kind) in _FIELDS.items()}
    return {
        "model": _model(arrays, name), **fields, "statistics": statistics, "settings": settings,
        "units": dict(meta.get("units", {})), "peeljax_version": str(meta.get("peeljax_version", "")),
    }  # fmt: skip


# ---------------------------------------------------------------------------- a diagram's file
DIAGRAM_KIND = "orbit_diagram"
_STAT_FILE_NAMES = {"period": "time_between_slips"}
_UNITS = {
    "V": "m/s", "period": "s", "F_mean": "N", "F_slip": "N", "F_stick": "N", "time_between_slips": "s",
    "slip_duration": "s", "approach": "N", "crossing": "N/s", "bif_V": "m/s", "seed_V": "m/s", "seed_period": "s",
    "seed_F_slip": "N", "seed_F_stick": "N", "seed_interval": "s", "V_range": "m/s", "wall_time": "s",
}  # fmt: skip
_TESTS = ("fold", "period_doubling", "torus")


def write_diagram(path: str | os.PathLike, diagram) -> None:
    """Write ``diagram`` to ``path`` (module docstring), atomically."""
    branches = diagram.branches
    cat = lambda get, empty=(0,): np.concatenate([get(b) for b in branches]) if branches else np.zeros(empty)  # noqa: E731
    arrays = {
        "point_branch": np.concatenate([np.full(len(b), i) for i, b in enumerate(branches)] or [np.zeros(0)]).astype(np.int64),
        "point_parameter": cat(lambda b: b.values), "V": cat(lambda b: b.V),
        "slips": cat(lambda b: b.slips).astype(np.int64), "period": cat(lambda b: b.period),
        "multipliers": cat(lambda b: b.multipliers, (0, 2)).astype(complex), "stable": cat(lambda b: b.stable).astype(bool),
        "approach": cat(lambda b: b.approach), "crossing": cat(lambda b: b.crossing),
        "section": cat(lambda b: b.section, (0, 2)),
        **{_STAT_FILE_NAMES.get(k, k): cat(lambda b, k=k: b.statistics[k]) for k in STATISTICS},
        **{k: cat(lambda b, k=k: b.test_functions[k]) for k in _TESTS},
        "branch_parameter": np.array([b.parameter for b in branches], dtype=str),
        "branch_ends": np.array(["\n".join(b.ends) for b in branches], dtype=str),
        "branch_wall_time": np.array([b.wall_time for b in branches], float),
        "V_range": np.asarray(diagram.V_range, float),
        "wall_time": np.asarray(diagram.wall_time, float), "seed_time": np.asarray(diagram.seed_time, float),
        "complete": np.asarray(bool(getattr(diagram, "complete", True))),
    }  # fmt: skip
    found = diagram.bifurcations
    arrays.update({
        "bif_branch": np.array([i for i, _ in found], np.int64), "bif_kind": np.array([b.kind.name for _, b in found], dtype=str),
        "bif_parameter": np.array([b.parameter for _, b in found], float), "bif_V": np.array([b.V for _, b in found], float),
        "bif_slips": np.array([b.slips for _, b in found], np.int64), "bif_note": np.array([b.note for _, b in found], dtype=str),
    })  # fmt: skip
    seeds = diagram.seeds
    arrays.update({
        "seed_V": np.array([s.V for s in seeds], float), "seed_start": np.array([s.start for s in seeds], dtype=str),
        "seed_slips": np.array([s.slips for s in seeds], np.int64), "seed_period": np.array([s.period for s in seeds], float),
        "seed_F_slip": np.array([s.F_slip for s in seeds], float), "seed_F_stick": np.array([s.F_stick for s in seeds], float),
        "seed_interval": np.array([s.interval for s in seeds], float), "seed_orbit": np.array([s.orbit for s in seeds], dtype=str),
        "seed_branch": np.array([s.branch for s in seeds], np.int64),
    })  # fmt: skip
    arrays["meta_json"] = meta_array(DIAGRAM_KIND, _UNITS)
    write_npz(path, arrays)


def diagram_parts(arrays: dict, name: str) -> tuple:
    """(V_range, branches' fields, seeds' fields, wall_time, seed_time, complete) of a diagram
    file's arrays (``name``: the file, for messages); a ValueError naming the file where they are
    malformed. A branch's fields are :class:`~peeljax.orbits.OrbitBranch`'s, its bifurcations
    those of :class:`~peeljax.orbits.Bifurcation` with the kind's name (:mod:`.diagram` makes the
    objects)."""
    try:
        point_branch = np.asarray(arrays["point_branch"])
        n_branches = len(arrays["branch_parameter"])
        if point_branch.size and not (0 <= point_branch.min() and point_branch.max() < n_branches):
            raise ValueError("point_branch names a branch that is not in the file")
        bif_branch = np.asarray(arrays["bif_branch"])
        branches = []
        for i in range(n_branches):
            at = point_branch == i
            stats = {k: np.asarray(arrays[_STAT_FILE_NAMES.get(k, k)], float)[at] for k in STATISTICS}
            mine = np.flatnonzero(bif_branch == i)
            bifurcations = [
                (str(arrays["bif_kind"][j]), float(arrays["bif_parameter"][j]), float(arrays["bif_V"][j]),
                 int(arrays["bif_slips"][j]), -1, str(arrays["bif_note"][j]))
                for j in mine
            ]  # fmt: skip
            branches.append(dict(
                parameter=str(arrays["branch_parameter"][i]), values=np.asarray(arrays["point_parameter"], float)[at],
                V=np.asarray(arrays["V"], float)[at], slips=np.asarray(arrays["slips"])[at],
                period=np.asarray(arrays["period"], float)[at], statistics=stats,
                multipliers=np.asarray(arrays["multipliers"])[at], stable=np.asarray(arrays["stable"], bool)[at],
                test_functions={k: np.asarray(arrays[k], float)[at] for k in _TESTS},
                approach=np.asarray(arrays["approach"], float)[at], crossing=np.asarray(arrays["crossing"], float)[at],
                section=np.asarray(arrays["section"], float)[at], bifurcations=bifurcations,
                ends=[e for e in str(arrays["branch_ends"][i]).split("\n") if e],
                wall_time=float(arrays["branch_wall_time"][i]),
            ))  # fmt: skip
        seeds = [
            (float(arrays["seed_V"][j]), str(arrays["seed_start"][j]), int(arrays["seed_slips"][j]),
                 float(arrays["seed_period"][j]), float(arrays["seed_F_slip"][j]), float(arrays["seed_F_stick"][j]),
                 float(arrays["seed_interval"][j]), str(arrays["seed_orbit"][j]), int(arrays["seed_branch"][j]))
            for j in range(len(arrays["seed_V"]))
        ]  # fmt: skip
        V_range = tuple(float(v) for v in np.asarray(arrays["V_range"], float))
        if len(V_range) != 2:
            raise ValueError("V_range must hold two numbers")
        complete = bool(np.asarray(arrays.get("complete", True)))  # (files before it: complete)
        return V_range, branches, seeds, float(arrays["wall_time"]), float(arrays["seed_time"]), complete
    except (KeyError, IndexError, TypeError, ValueError) as error:
        raise ValueError(f"{name!r} is malformed: not an orbit diagram's arrays ({error})") from None
