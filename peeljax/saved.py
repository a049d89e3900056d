"""Files peeljax wrote, read back: :func:`peeljax.load` for every kind, and a run's file written.

``peeljax.load(path)`` reads any file peeljax writes and returns what it holds: a run (the
``.npz`` of ``peeljax simulate --out`` or :meth:`Solution.save`) as a :class:`SavedRun`, a
sweep as a :class:`~peeljax.SweepResult`, a stick-slip map as a
:class:`~peeljax.StickSlipMap` (``.npz``, or netCDF for sweeps and maps). The file says which
kind it is (``meta_json``, :mod:`peeljax._files`); a new kind registers its reader with
:func:`register_reader`.

A :class:`SavedRun` is a :class:`Solution` that also carries what the file says about the run:
its model (geometry and φ's coefficients), V, τ, t_final, the other settings and the units.
:func:`peeljax.analyze` takes those from it, so ``analyze(peeljax.load("run.npz"))`` analyzes
the run as it was made, and :func:`peeljax.cycle_statistics` reads its jumps (``run.jumps``).

Files are read with ``allow_pickle=False``; a file that is not such an .npz (damaged, another
kind of file, a missing or misshapen array) is refused with a ValueError naming it. Files are
written through :mod:`peeljax._atomic`: a failed write leaves the previous file as it was.
"""

from __future__ import annotations

import errno

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import equinox as eqx
import numpy as np

from ._files import read_meta, read_netcdf
from ._npz import read_npz
from .adhesion import AdhesionLaw
from .model import GEOMETRIES, PeelingModel
from .solution import JumpRecord, Solution, StopReason

__all__ = ["SavedRun", "load", "register_reader"]

_STATES = ("alpha", "omega", "u", "v")
_REQUIRED = ("t", *_STATES, "status", "t_stop")
_SETTINGS = ("dt", "t_final", "rho", "rtol", "atol", "method", "method_option", "geometry", "fold", "max_jumps", "transient")
_JUMPS = ("jump_t", "jump_up", "jump_v_before", "jump_v_after", "jump_G")


class SavedRun(Solution):
    """A :class:`Solution` read from a file, with the run's parameters (see the module docstring).

    Attributes (besides the Solution's; ``diagnostics`` is None, the file does not hold them):
        model: the :class:`PeelingModel` (geometry and φ from the file; None when the run used a
            callable φ, which the file cannot hold: pass the model to ``analyze`` then).
        V, tau: the run's pull velocity [m/s] and τ [s] (0: the DAE itself).
        F: the tape tension at each output time [N] (NaN where not valid).
        settings: the other scalars of the file (dt, t_final, rho, rtol, atol, method,
            geometry, fold, max_jumps, transient; NaN or absent where they do not apply).
        path: the file it was read from.
        units: the units of the file's arrays (empty for a file written before they were kept).
        peeljax_version: the version of the peeljax that wrote the file ("" where unknown).
    """

    model: PeelingModel | None = None
    V: float = math.nan
    tau: float = math.nan
    F: np.ndarray | None = None
    settings: dict = eqx.field(default_factory=dict)
    path: str = eqx.field(static=True, default="")
    units: dict = eqx.field(default_factory=dict)
    peeljax_version: str = eqx.field(static=True, default="")

    def save(self, path, **run) -> None:
        """Write the run to ``path`` as it was read (:meth:`Solution.save`, with this file's
        model, V, τ and settings; ``run`` overrides them)."""
        settings = self.settings
        known = {
            "model": self.model, "V": self.V, "tau": self.tau, "t_final": settings.get("t_final"),
            "dt": settings.get("dt"), "rho": settings.get("rho"), "rtol": settings.get("rtol"),
            "atol": settings.get("atol"), "fold": settings.get("fold"), "max_jumps": settings.get("max_jumps"),
            "transient": settings.get("transient"), "method_option": settings.get("method_option"),
        }  # fmt: skip
        super().save(path, **({key: value for key, value in known.items() if value is not None} | run))

    def __repr__(self) -> str:
        n = int(np.asarray(self.ts).size)
        jumps = "" if self.jumps is None else f", {int(np.asarray(self.jumps.count))} jumps"
        return (
            f"SavedRun({self.path!r}: V = {self.V:g} m/s, tau = {self.tau:g} s, {self.status_name} at "
            f"t = {float(self.t_stop):.6g} s, {n} output times{jumps})"
        )


def _scalar(arrays: dict, key: str, path: str, kind=float):
    value = arrays[key]
    if value.ndim != 0:
        raise ValueError(f"{path!r} is malformed: {key} has shape {value.shape}, expected a scalar")
    try:
        return kind(value.item()) if kind is not str else str(value)
    except (TypeError, ValueError):
        raise ValueError(f"{path!r} is malformed: {key} = {value.item()!r} is not a {kind.__name__}") from None


def _status(arrays: dict, path: str) -> int:
    """The StopReason: ``status_code`` where the file has it, else from ``status`` and ``reason``."""
    if "status_code" in arrays:
        code = _scalar(arrays, "status_code", path, int)
        if code not in StopReason._value2member_map_:
            raise ValueError(f"{path!r} is malformed: status_code {code} is no StopReason")
        return code
    name = _scalar(arrays, "status", path, str)
    if name == "completed":
        return int(StopReason.COMPLETED)
    if name != "stopped":
        raise ValueError(f"{path!r} is malformed: status is {name!r}, expected 'completed' or 'stopped'")
    reason = _scalar(arrays, "reason", path, str) if "reason" in arrays else ""
    for stop in StopReason:  # a file from before status_code: its reason in words
        if stop and (reason == stop.message or reason[:40] == stop.message[:40]):
            return int(stop)
    raise ValueError(f"{path!r}: the run stopped for a reason this peeljax does not know ({reason[:80]!r})")


def _stats(arrays: dict, path: str) -> dict:
    if "stats_json" not in arrays:
        return {}
    try:
        stats = json.loads(_scalar(arrays, "stats_json", path, str))
    except json.JSONDecodeError as error:
        raise ValueError(f"{path!r} is malformed: stats_json is not JSON ({error})") from None
    if not isinstance(stats, dict):
        raise ValueError(f"{path!r} is malformed: stats_json is not a JSON object")
    return {key: np.asarray(math.nan if value is None else value) for key, value in stats.items()}


def _model(arrays: dict, path: str) -> PeelingModel | None:
    geometry = _scalar(arrays, "geometry", path, str) if "geometry" in arrays else "paper"
    if geometry not in GEOMETRIES:
        raise ValueError(f"{path!r} is malformed: geometry {geometry!r} is none of {', '.join(GEOMETRIES)}")
    text = _scalar(arrays, "phi_json", path, str) if "phi_json" in arrays else "{}"
    if text == "":
        return None  # a callable φ: not in the file
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"{path!r} is malformed: phi_json is not JSON ({error})") from None
    adhesion = AdhesionLaw() if data == {} else AdhesionLaw.from_dict(data, source=f"{path!r} (phi_json)")
    return PeelingModel(adhesion=adhesion, geometry=geometry)


def _jumps(arrays: dict, path: str) -> JumpRecord | None:
    if "jump_t" not in arrays:
        return None
    missing = [key for key in _JUMPS if key not in arrays]
    if missing:
        raise ValueError(f"{path!r} is malformed: it has jump_t but not {missing}")
    record = {key: np.asarray(arrays[key]) for key in _JUMPS}
    n = record["jump_t"].shape
    if len(n) != 1 or any(value.shape != n for value in record.values()):
        raise ValueError(f"{path!r} is malformed: the jump arrays {list(_JUMPS)} must be 1-D of one length")
    extra = {}
    if "jump_F" in arrays and "F" in getattr(JumpRecord, "__dataclass_fields__", {}):
        extra["F"] = np.asarray(arrays["jump_F"], float)
    return JumpRecord(
        t=record["jump_t"].astype(float),
        up=record["jump_up"].astype(bool),
        v_before=record["jump_v_before"].astype(float),
        v_after=record["jump_v_after"].astype(float),
        G=record["jump_G"].astype(float),
        count=np.asarray(n[0], np.int32),
        **extra,
    )


def _read_run(arrays: dict, name: str) -> SavedRun:
    """The :class:`SavedRun` of a run's ``.npz`` arrays (``name``: the file, for messages)."""
    missing = [key for key in _REQUIRED if key not in arrays]
    if missing:
        raise ValueError(f"{name!r} is malformed: missing {missing}; expected the .npz of 'peeljax simulate --out'")
    meta = read_meta(arrays, name) or {}
    columns = {key: np.asarray(arrays[key]) for key in ("t", *_STATES)}
    n = columns["t"].shape
    if len(n) != 1 or n[0] == 0 or any(value.shape != n for value in columns.values()):
        shapes = {key: value.shape for key, value in columns.items()}
        raise ValueError(f"{name!r} is malformed: t, alpha, omega, u, v must be 1-D of one length, got {shapes}")
    try:
        ys = np.stack([columns[key].astype(float) for key in _STATES], axis=-1)
        ts = columns["t"].astype(float)
    except ValueError:
        raise ValueError(f"{name!r} is malformed: t, alpha, omega, u, v must be numbers") from None
    valid = np.asarray(arrays["valid"], bool) if "valid" in arrays else np.isfinite(ys).all(axis=-1)
    if valid.shape != n:
        raise ValueError(f"{name!r} is malformed: valid has shape {valid.shape}, expected {n}")
    F = np.asarray(arrays["F"], float) if "F" in arrays and arrays["F"].shape == n else None
    after_jump = np.asarray(arrays["after_jump"]) if "after_jump" in arrays else None  # files since both sides were kept
    if after_jump is not None and (after_jump.shape != n or after_jump.dtype != bool):
        raise ValueError(f"{name!r} is malformed: after_jump must be booleans of shape {n}, got {after_jump.dtype} {after_jump.shape}")
    settings = {}
    for key in _SETTINGS:
        if key in arrays:
            value = arrays[key]
            settings[key] = value.item() if value.ndim == 0 else value.tolist()
    return SavedRun(
        ts=ts,
        ys=ys,
        valid=valid,
        status=np.asarray(_status(arrays, name), np.int32),
        t_stop=np.asarray(_scalar(arrays, "t_stop", name), float),
        stats=_stats(arrays, name),
        diagnostics=None,
        method=_scalar(arrays, "method", name, str) if "method" in arrays else "alpha",
        jumps=_jumps(arrays, name),
        after_jump=after_jump,
        model=_model(arrays, name),
        V=_scalar(arrays, "V", name) if "V" in arrays else math.nan,
        tau=_scalar(arrays, "tau", name) if "tau" in arrays else math.nan,
        F=F,
        settings=settings,
        path=name,
        units=dict(meta.get("units", {})),
        peeljax_version=str(meta.get("peeljax_version", "")),
    )


# ---------------------------------------------------------------------------- every kind of file
# A file's kind: ``kind`` in its ``meta_json``; a file written before files described themselves
# is told by its arrays. A new kind registers a reader here (register_reader), with a few lines.
# kind → reader of an .npz's arrays (arrays, file name) and of a netCDF file's dataset.
# The modules of the other kinds register theirs when they are imported (``import peeljax``
# imports them all): peeljax.sweeps.api (sweeps), peeljax.sweeps.stick_slip_map (maps).
NPZ_READERS: dict[str, Callable[[dict, str], Any]] = {"run": _read_run}
NETCDF_READERS: dict[str, Callable[[Any, str], Any]] = {}


def register_reader(kind: str, npz=None, netcdf=None) -> None:
    """Teach :func:`load` a new kind of file: ``npz(arrays, name)`` reads an ``.npz`` whose
    ``meta_json`` says ``"kind": kind``, ``netcdf(dataset, name)`` a netCDF file whose ``kind``
    attribute says it (ValueError for a malformed one). The module that defines the kind calls
    this when it is imported."""
    if npz is not None:
        NPZ_READERS[kind] = npz
    if netcdf is not None:
        NETCDF_READERS[kind] = netcdf


def _kinds_read() -> str:
    """The kinds of file :func:`load` reads, in words."""
    names = [kind.replace("_", " ").replace("-", " ") for kind in NPZ_READERS]
    return ", ".join(("an " if name[0] in "aeiou" else "a ") + name for name in names)


def _kind(arrays: dict, name: str) -> str:
    meta = read_meta(arrays, name)
    if meta is not None and isinstance(meta.get("kind"), str):
        return meta["kind"]
    if meta is not None and meta.get("format") == "peeljax-sweep":
        return "sweep"  # a sweep written before files named their kind
    if "starts" in arrays and "jump_G" in arrays:
        return "stick-slip-map"
    return "run"


def load(path: str | Path):
    """Any file peeljax writes, read back as what it holds.

    * a run (``peeljax simulate --out``, :meth:`Solution.save`): a :class:`SavedRun`;
    * a sweep (``peeljax sweep --out``, :func:`peeljax.sweep`'s ``out``,
      :meth:`SweepResult.save`), ``.npz`` or netCDF (``.nc``): a :class:`~peeljax.SweepResult`;
    * a stick-slip map (``peeljax sweep --stick-slip-map --out``, :meth:`StickSlipMap.save`):
      a :class:`~peeljax.StickSlipMap`.

    The kind is read from the file (``meta_json``'s ``kind``, or a netCDF file's ``kind``
    attribute; files written before they named it are told by their arrays). An ``.npz`` is
    read with ``allow_pickle=False``; netCDF needs ``pip install "peeljax[xarray]"``.

    Raises:
        FileNotFoundError: there is no file at ``path``.
        ValueError: naming the file, when it cannot be read, is damaged, is another kind of
            file, or lacks or misshapes the arrays of its kind.
    """
    name = str(path)
    if not Path(name).exists():
        raise FileNotFoundError(errno.ENOENT, "no such file (pj.load reads the files peeljax writes)", name)
    if Path(name).suffix.lower() == ".nc":
        dataset = read_netcdf(path)
        kind = dataset.attrs.get("kind")
        if kind not in NETCDF_READERS:
            known = ", ".join(NETCDF_READERS)
            raise ValueError(f"{name!r} is not a netCDF file peeljax wrote: its kind is {kind!r}, expected one of {known}")
        try:
            return NETCDF_READERS[kind](dataset, name)
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"{name!r} is malformed: not a peeljax {kind} ({error})") from None
    arrays = read_npz(path, fix=f"expected an .npz written by peeljax (one of: {_kinds_read()})")
    kind = _kind(arrays, name)
    if kind not in NPZ_READERS:
        raise ValueError(
            f"{name!r} holds a {kind!r}, which this peeljax cannot read (it reads {', '.join(NPZ_READERS)}): "
            "a newer peeljax wrote it"
        )
    return NPZ_READERS[kind](arrays, name)
