"""An orbit's file, the format: what :meth:`PeriodicOrbit.save` writes and :func:`peeljax.load`
reads back (as a :class:`~peeljax.orbits.saved_orbit.SavedOrbit`).

The file is an ``.npz`` of plain arrays and scalars (``np.load(path, allow_pickle=False)``
reads it; nothing in it is code), with ``meta_json`` saying its kind (``"orbit"``), the units
of its arrays and the peeljax that wrote it (:mod:`peeljax._files`). It holds every field of a
:class:`~peeljax.orbits.PeriodicOrbit`, so the orbit read back is whole: its trajectory,
statistics and multipliers are there without shooting again, and its section point starts
Newton for a neighbouring orbit. This module knows the arrays only (it imports no orbit
class: :mod:`.orbit` writes through it, :mod:`.saved_orbit` reads through it).

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
"""

from __future__ import annotations

import json
import os

import jax.numpy as jnp
import numpy as np

from .._atomic import write_npz
from .._files import META_KEY, json_safe, meta_array, read_meta
from ..adhesion import AdhesionLaw
from ..model import GEOMETRIES, PeelingModel
from ..solution import StopReason
from .shooting import OrbitStatus

__all__ = ["KIND", "ORBIT_UNITS", "orbit_arrays", "orbit_fields", "write_orbit"]

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
    if not isinstance(model.adhesion, AdhesionLaw):
        raise ValueError(
            "save: the orbit's adhesion law is a Python callable, which a file cannot hold (files are data, "
            "never code); use an AdhesionLaw to save it"
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
