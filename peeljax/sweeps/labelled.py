"""Sweeps and stick-slip maps as labelled data: ``xarray.Dataset`` and netCDF files.

A :class:`~peeljax.SweepResult` becomes a dataset whose dimensions are the sweep's axes:
``("V", "tau", <swept parameters>…)`` for ``grid="outer"`` (coordinates: the values swept),
``("trajectory",)`` for ``grid="pairs"`` (V, τ and the parameters as coordinates along it);
saved states add the dimension ``t`` (one variable per state: ``alpha``, ``omega``, ``u``,
``v``), jump records the dimension ``jump`` (the record's slots). A
:class:`~peeljax.sweeps.StickSlipMap` has the dimensions ``("start", "V")`` and ``jump``.

Every variable carries ``units`` (and ``long_name``); the dataset's attributes carry
``kind`` ("sweep" or "stick-slip-map"), ``peeljax_version``, the scalar settings one by one and
every setting as ``settings_json``. The inverse functions give back the arrays the ``.npz``
holds, so a netCDF file loads as the same result (:func:`peeljax.load`).

xarray and a netCDF engine (h5netcdf) are an optional extra: ``pip install "peeljax[xarray]"``.
"""

from __future__ import annotations

import json
import math

import numpy as np

from .._files import PARAMETER_UNITS, STATE_UNITS, json_safe, peeljax_version, require_xarray
from ..solution import StopReason

__all__ = ["MAP_UNITS", "SWEEP_UNITS", "map_arrays", "map_dataset", "sweep_arrays", "sweep_dataset", "sweep_units"]

# (units, long_name) of the per-trajectory summaries and jump records of a sweep.
_SWEEP_FIELDS: dict[str, tuple[str | None, str]] = {
    "V": ("m/s", "pull velocity"),
    "tau": ("s", "homogenization time scale (0: the DAE)"),
    "completed": (None, "the run reached t_final"),
    "status": (None, "stop reason (peeljax.StopReason)"),
    "t_stop": ("s", "time of the last accepted state"),
    "v_mean": ("m/s", "mean peeling velocity over the window"),
    "v_std": ("m/s", "standard deviation of the peeling velocity over the window"),
    "v_min": ("m/s", "least peeling velocity in the window"),
    "v_max": ("m/s", "greatest peeling velocity in the window"),
    "v_final": ("m/s", "peeling velocity at t_stop"),
    "events": ("1", "stick-slip events in the window"),
    "v_slip": ("m/s", "peeling velocity at the maximum of phi"),
    "window_count": ("1", "accepted step points in the window"),
    "newton_iterations": ("1", "Newton iterations"),
    "subdivided_steps": ("1", "subdivided steps (uniform mesh)"),
    "max_subdivision_level": ("1", "deepest subdivision (uniform mesh)"),
    "accepted_steps": ("1", "accepted steps"),
    "rejected_steps": ("1", "rejected steps"),
    "window_time": ("s", "part of the window the run covered"),
    "ts": ("s", "save times"),
    "t": ("s", "time"),
    "jump_count": ("1", "jumps recorded"),
    "jump_t": ("s", "jump time"),
    "jump_up": (None, "stick to slip (v jumps up)"),
    "jump_v_before": ("m/s", "peeling velocity just before the jump"),
    "jump_v_after": ("m/s", "peeling velocity just after the jump"),
    "jump_G": ("N", "shear force G at the jump"),
}
_STATE_NAMES = {"alpha": "peel-front angle", "omega": "spool angular velocity", "u": "tape stretch",
                "v": "peeling velocity"}  # fmt: skip
SWEEP_UNITS: dict[str, str] = {key: unit for key, (unit, _) in _SWEEP_FIELDS.items() if unit is not None}


def sweep_units(params) -> dict:
    """The units of a sweep's ``.npz`` arrays (``param_<name>`` for each swept parameter;
    ``ys``: one unit per state, in the order alpha, omega, u, v)."""
    return {**SWEEP_UNITS, **{f"param_{name}": PARAMETER_UNITS[name] for name in params},
            "ys": list(STATE_UNITS.values())}  # fmt: skip


def _attrs(name: str, table: dict) -> dict:
    unit, long_name = table.get(name, (None, None))
    attrs = {} if long_name is None else {"long_name": long_name}
    if unit is not None:
        attrs["units"] = unit
    if name == "status":  # CF flags: the codes and their names
        attrs["flag_values"] = np.asarray([int(s) for s in StopReason], np.int32)
        attrs["flag_meanings"] = " ".join(s.name.lower() for s in StopReason)
    return attrs


def _setting_attrs(settings: dict, skip: set) -> dict:
    """The scalar settings (numbers, strings, flat lists of numbers) as netCDF attributes."""
    attrs = {}
    for key, value in settings.items():
        if key in skip or value is None:
            continue
        if isinstance(value, bool):
            attrs[key] = int(value)
        elif isinstance(value, (int, float, str)):
            attrs[key] = value
        elif isinstance(value, (list, tuple)) and value and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
        ):
            attrs[key] = np.asarray(value, float)
    return attrs


def _axis_values(flat: np.ndarray, shape: tuple[int, ...], axis: int) -> np.ndarray:
    """The values along ``axis`` of a C-order grid whose flattening is ``flat``."""
    index = [0] * len(shape)
    index[axis] = slice(None)
    return np.asarray(flat).reshape(shape)[tuple(index)]


# ---------------------------------------------------------------------------- sweeps
def sweep_dataset(result):
    """The :class:`~peeljax.SweepResult` as an ``xarray.Dataset`` (the module docstring)."""
    xr = require_xarray("SweepResult.to_xarray")
    names = list(result.params)
    n = len(result)
    if result.grid_shape is not None:
        shape = tuple(result.grid_shape)
        dims = ("V", "tau", *names)
        flat = {"V": result.V, "tau": result.tau, **result.params}
        coords = {dim: (dim, _axis_values(flat[dim], shape, i)) for i, dim in enumerate(dims)}
    else:
        shape, dims = (n,), ("trajectory",)
        coords = {"V": (dims, np.asarray(result.V)), "tau": (dims, np.asarray(result.tau))}
        coords.update({name: (dims, np.asarray(value)) for name, value in result.params.items()})
    coords = {key: (d, v, {"units": PARAMETER_UNITS[key], **_attrs(key, _SWEEP_FIELDS)}) for key, (d, v) in coords.items()}

    def grid(value) -> np.ndarray:
        value = np.asarray(value)
        return value.reshape(shape + value.shape[1:])

    data = {}
    for key in (k for k in _SWEEP_FIELDS if k in result.__dataclass_fields__ and k not in ("V", "tau", "ts")):
        data[key] = (dims, grid(getattr(result, key)), _attrs(key, _SWEEP_FIELDS))
    if result.ys is not None:
        coords["t"] = ("t", np.asarray(result.ts, float), _attrs("t", _SWEEP_FIELDS))
        ys = grid(result.ys)
        for i, state in enumerate(STATE_UNITS):
            data[state] = ((*dims, "t"), ys[..., i], {"units": STATE_UNITS[state], "long_name": _STATE_NAMES[state]})
    if result.jumps is not None:
        for key, value in result.jumps.items():
            extra = () if key == "jump_count" else ("jump",)
            data[key] = ((*dims, *extra), grid(value), _attrs(key, _SWEEP_FIELDS))
    for key, value in (getattr(result, "cycles", None) or {}).items():  # per-lane arrays of any shape
        value = grid(value)
        extra = tuple(f"{key}_{axis}" for axis in range(value.ndim - len(dims)))
        data[key] = ((*dims, *extra), value, _attrs(key, _SWEEP_FIELDS))
    settings = json_safe(result.settings)
    attrs = {
        "kind": "sweep",
        "peeljax_version": result.peeljax_version or peeljax_version(),
        "grid": "pairs" if result.grid_shape is None else "outer",
        **_setting_attrs(settings, {"V", "tau", "params", "grid", "kind", "peeljax_version"}),
        "settings_json": json.dumps(settings, allow_nan=False),
    }
    return xr.Dataset(data, coords=coords, attrs=attrs)


def sweep_arrays(dataset, source: str = "the dataset") -> tuple[dict[str, np.ndarray], dict]:
    """The ``.npz`` arrays of a sweep's dataset (:func:`sweep_dataset`) and its settings."""
    settings = _settings(dataset, source)
    names = list(settings.get("params", {}))
    dims = ("trajectory",) if "trajectory" in dataset.dims else ("V", "tau", *names)
    missing = [d for d in ("V", "tau", *names) if d not in dataset.coords]
    if missing or "t_stop" not in dataset:
        raise ValueError(f"{source} is not a peeljax sweep: missing {missing or ['t_stop']}")
    if dims == ("trajectory",):
        per = {key: np.asarray(dataset[key].values) for key in ("V", "tau", *names)}
    else:
        mesh = np.meshgrid(*(np.asarray(dataset[d].values) for d in dims), indexing="ij")
        per = {key: m.reshape(-1) for key, m in zip(dims, mesh)}
    n = per["V"].size

    def flat(name: str, *extra: str) -> np.ndarray:
        value = dataset[name].transpose(*dims, *extra).values
        return np.asarray(value).reshape((n, *value.shape[len(dims) :]))

    arrays = {"V": per["V"], "tau": per["tau"], **{f"param_{name}": per[name] for name in names}}
    for key, variable in dataset.data_vars.items():
        if key not in STATE_UNITS:
            arrays[key] = flat(key, *(d for d in variable.dims if d not in dims))
    if "t" in dataset.coords and "v" in dataset:
        arrays["ts"] = np.asarray(dataset["t"].values, float)
        arrays["ys"] = np.stack([flat(state, "t") for state in STATE_UNITS], axis=-1)
    return arrays, settings


def _settings(dataset, source: str) -> dict:
    try:
        settings = json.loads(dataset.attrs["settings_json"])
    except (KeyError, TypeError, json.JSONDecodeError) as error:
        raise ValueError(f"{source} is malformed: no settings_json attribute ({error})") from None
    if not isinstance(settings, dict):
        raise ValueError(f"{source} is malformed: settings_json is not a JSON object")
    return settings


# ---------------------------------------------------------------------------- stick-slip maps
MAP_FIELDS: dict[str, tuple[str | None, str]] = {
    "V": ("m/s", "pull velocity"),
    "status": (None, "stop reason (peeljax.StopReason)"),
    "t_stop": ("s", "time of the last accepted state"),
    "window_start": ("s", "start of the statistics' window"),
    "jumps_total": ("1", "jumps of the whole run"),
    "jumps": ("1", "jumps in the window"),
    "slips": ("1", "stick to slip jumps in the window"),
    "crossings": ("1", "stick-slip events counted by the sweep in its window"),
    "G_slip_min": ("N", "least shear force at a stick to slip jump"),
    "G_slip_max": ("N", "greatest shear force at a stick to slip jump"),
    "G_stick_min": ("N", "least shear force at a slip to stick jump"),
    "G_stick_max": ("N", "greatest shear force at a slip to stick jump"),
    "period": ("s", "period of the repeat of the stick to slip events"),
    "events": ("1", "stick to slip events per repeat"),
    "repeats": ("1", "full repeats seen"),
    "repeat_start": ("s", "time of the first event the repeat was matched from"),
    "slip_interval": ("s", "mean time between slips"),
    "stick_duration": ("s", "mean stick duration"),
    "slip_duration": ("s", "mean slip duration"),
    "force_drop": ("N", "mean force drop at a slip"),
    "stick_fraction": ("1", "fraction of the window on the stick branch"),
    "v_stick_min": ("m/s", "least peeling velocity on the stick branch"),
    "v_stick_max": ("m/s", "greatest peeling velocity on the stick branch"),
    "v_slip_min": ("m/s", "least peeling velocity on the slip branch"),
    "v_slip_max": ("m/s", "greatest peeling velocity on the slip branch"),
    "v_mean": ("m/s", "mean peeling velocity over the window"),
    "v_lo": ("m/s", "least peeling velocity in the window"),
    "v_hi": ("m/s", "greatest peeling velocity in the window"),
    "stick_slip": (None, "the run still slips after the transient"),
    "jump_G": ("N", "shear force G at each jump in the window"),
    "jump_up": (None, "stick to slip (v jumps up)"),
    "phi_max": ("N", "maximum of phi(., V)"),
    "phi_min": ("N", "minimum of phi(., V)"),
    "v_max": ("m/s", "peeling velocity at the maximum of phi"),
    "v_min": ("m/s", "peeling velocity at the minimum of phi"),
    "tau": ("s", "homogenization time scale (0: the DAE)"),
    "t_final": ("s", "end time of the runs"),
    "transient": ("s", "the statistics start here"),
    "wall_time": ("s", "seconds the map took"),
}
MAP_UNITS: dict[str, str] = {key: unit for key, (unit, _) in MAP_FIELDS.items() if unit is not None}
_MAP_SCALARS = ("tau", "t_final", "transient", "wall_time")


_MAP_DIMS = {0: (), 1: ("V",), 2: ("start", "V"), 3: ("start", "V", "jump")}


def map_dataset(smap):
    """The :class:`~peeljax.sweeps.StickSlipMap` as an ``xarray.Dataset`` (the module docstring):
    its :meth:`~peeljax.sweeps.StickSlipMap.as_arrays` labelled by their shapes (per V, per
    start and V, per start, V and jump)."""
    xr = require_xarray("StickSlipMap.to_xarray")
    arrays = smap.as_arrays()
    data = {
        name: (_MAP_DIMS[value.ndim], value, _attrs(name, MAP_FIELDS))
        for name, value in arrays.items()
        if name not in ("V", "starts", "settings_json", *_MAP_SCALARS)
    }
    coords = {"start": ("start", list(smap.starts)), "V": ("V", arrays["V"], _attrs("V", MAP_FIELDS))}
    settings = json_safe(smap.settings)
    attrs = {
        "kind": "stick-slip-map",
        "peeljax_version": getattr(smap, "peeljax_version", None) or peeljax_version(),
        **{name: float(arrays[name]) for name in _MAP_SCALARS},
        **{f"{name}_units": MAP_UNITS[name] for name in _MAP_SCALARS},
        "settings_json": json.dumps(settings, allow_nan=False),
    }
    return xr.Dataset(data, coords=coords, attrs=attrs)


def map_arrays(dataset, source: str = "the dataset") -> dict[str, np.ndarray]:
    """The ``.npz`` arrays (:meth:`StickSlipMap.as_arrays`) of a map's dataset (:func:`map_dataset`)."""
    missing = [name for name in ("start", "V", "tau", "t_final", "transient") if name not in dataset.coords
               and name not in dataset.attrs]  # fmt: skip
    if missing:
        raise ValueError(f"{source} is not a peeljax stick-slip map: missing {', '.join(missing)}")
    arrays = {"V": np.asarray(dataset["V"].values, float), "starts": np.asarray(dataset["start"].values, dtype=str)}
    for name, variable in dataset.data_vars.items():
        dims = next((d for d in _MAP_DIMS.values() if set(d) == set(variable.dims)), None)
        if dims is None:
            raise ValueError(f"{source} is malformed: {name} has dimensions {variable.dims}")
        arrays[name] = np.asarray(variable.transpose(*dims).values)
    arrays.update({name: np.float64(dataset.attrs.get(name, math.nan)) for name in _MAP_SCALARS})
    arrays["settings_json"] = np.asarray(json.dumps(_settings(dataset, source)), dtype=str)
    return arrays
