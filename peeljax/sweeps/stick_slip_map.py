"""The stick-slip map over V: which pull velocities stick-slip, at which forces, how regularly.

:func:`stick_slip_map` runs one :func:`peeljax.sweep` per starting state (``grid="pairs"``
over V, one τ, runs carried through the folds of φ); each lane accumulates its cycle statistics
after a transient inside its loop, at every jump (the definitions of
:func:`peeljax.cycle_statistics`, :mod:`peeljax.integrators.cycle_accumulator`), and keeps only
its last ``max_jumps`` jumps (a ring buffer): no lane stops for a full record, and a lane costs
a few kilobytes however many jumps it makes (``docs/sweeps.md``). The result,
a :class:`StickSlipMap`, is the classic picture of the field as numbers: for each V and start,
whether the run stick-slips once settled, the forces at which the tape slips and re-sticks (the
bifurcation diagram of the force), the repeat of the stick → slip events, the time between
slips and the range of v on each branch; with φ's folds per V alongside.

Stick-slip is *computed* here, not read off φ: with the paper's φ, stick-slip and steady
peeling coexist for some V (from the paper's start V = 0.35 m/s, below v̂(V), still jumps,
while V = 0.2–0.3 m/s peel steadily), so the starting state decides which one a run shows and
the map keeps one row per start. :func:`peeljax.plots.plot_stick_slip_map` draws it.

Definitions (per V and start, over the lane's window [window_start, t_stop]; see
:mod:`peeljax.cycles`):

* **window_start**: the transient; for a run that stopped before it (``max_steps``: a fast
  cycle can take many steps) the later half of what it ran, t_stop/2, or the later part of it
  whose jumps the lane kept (its last ``max_jumps``) — such lanes are not completed
  (``status``) and say what the run was doing when it stopped.
* **jumps_total**: every jump of the run, transient included.
* **jumps**, **slips**: the jumps of v in the window, and the stick → slip ones among them.
* **crossings**: the sweep's ``events`` over its window: for τ > 0 the upward crossings of v̂
  (the homogenized ODE rises through v̂ before it jumps, or passes a fold smoothly); for τ = 0,
  whose v never crosses v̂, the sweep counts the stick → slip jumps there (= ``slips``).
* **stick_slip**: ``jumps > 0`` or ``crossings > 0``: the run still slips once the transient is
  over. The cycle statistics below read the jumps only (for τ > 0, smooth passages are left out).
* **jump_G**, **jump_up**: the shear force G = (1 + l·sinα/L)·F at the jumps in the window that
  the lane kept (its last ``max_jumps``) and their direction (True: stick → slip). For τ = 0 (the DAE itself) G is φ(v̂, V) at a stick → slip
  jump and φ(v̌, V) at a slip → stick one.
* **G_slip_min/max**, **G_stick_min/max**: the range of G at the stick → slip / slip → stick jumps.
* **period**, **events**, **repeats**: the repeat of the stick → slip events
  (:func:`peeljax.cycles.repeat_pattern`, ``repeat_rtol``) of at most 32 events per period
  (``MAX_REPEAT_EVENTS``): ``events`` of them every ``period`` seconds, ``repeats`` full repeats
  seen; NaN, 0, 0 where none is found ("irregular"). ``repeat_start`` is the time of the first
  event the repeat was matched from (see ``settle``).
* **slip_interval**, **stick_duration**, **slip_duration**, **force_drop**: means over the window.
* **stick_fraction**: the fraction of the window spent on the stick branch.
* **v_stick_min/max**, **v_slip_min/max**: the range of v on the stick branch (lowest landing v
  of a slip → stick jump, 0 when the tape lands fully stuck; highest v before a stick → slip
  jump) and on the slip branch (lowest v before a slip → stick jump; highest landing v of a
  stick → slip jump): the v amplitude of the cycle.
* **v_mean**, **v_lo**, **v_hi**: the sweep's statistics of v over its window, by default
  [transient, t_stop] (the run's time-mean, minimum and maximum of v, jumps or not; for a
  steadily peeling run v ≈ V; NaN for a run that stopped before the window).
* **status**, **t_stop**: how and when each run ended (:class:`peeljax.StopReason` codes). A run
  that stopped early (``max_steps``) is summarized up to t_stop (see window_start).
* **phi_max**, **phi_min**, **v_max**, **v_min** (per V): φ's maximum φ(v̂, V) at v̂ and minimum
  φ(v̌, V) at v̌ (:func:`peeljax.phi_folds`); NaN where φ(·, V) has no fold (the paper's φ loses
  its folds between V = 5 and 5.5 m/s).
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from collections.abc import Mapping, Sequence

import numpy as np
from jaxtyping import ArrayLike

from .._files import json_safe
from ..cycles import cycle_statistics, repeat_pattern
from ..integrators.cycle_accumulator import KEPT_SLIPS, MAX_REPEAT_EVENTS
from ..model import PeelingModel
from ..saved import register_reader
from ..solution import StopReason
from .grid import check_window
from .lane_cycles import kept_slip_times, kept_window_start, repeat_table

__all__ = ["DEFAULT_V", "FOLD_FIELDS", "LANE_FIELDS", "STARTS", "StickSlipMap", "stick_slip_map"]

STARTS: tuple[str, ...] = ("paper", "steady")
DEFAULT_V = np.linspace(0.2, 8.0, 200)  # [m/s]: stick-slip and φ's loss of its folds (5–5.5 m/s)
DEFAULT_V.setflags(write=False)

# Per (start, V): shape (n_starts, n_V).
LANE_FIELDS: tuple[str, ...] = (
    "status",
    "t_stop",
    "window_start",
    "jumps_total",
    "jumps",
    "slips",
    "crossings",
    "G_slip_min",
    "G_slip_max",
    "G_stick_min",
    "G_stick_max",
    "period",
    "events",
    "repeats",
    "repeat_start",
    "slip_interval",
    "stick_duration",
    "slip_duration",
    "force_drop",
    "stick_fraction",
    "v_stick_min",
    "v_stick_max",
    "v_slip_min",
    "v_slip_max",
    "v_mean",
    "v_lo",
    "v_hi",
)
_INT_FIELDS = ("status", "jumps_total", "jumps", "slips", "crossings", "events", "repeats")
# Per V: shape (n_V,).
FOLD_FIELDS: tuple[str, ...] = ("phi_max", "phi_min", "v_max", "v_min")
# Keys the map sets itself: refused in sweep_kwargs.
_OWN_KEYS = ("V", "tau", "grid", "start", "fold", "max_jumps", "rtol", "atol", "progress", "model")


@dataclasses.dataclass(frozen=True, eq=False)
class StickSlipMap:
    """The stick-slip map over V, one row per starting state (definitions: :mod:`.stick_slip_map`).

    Attributes:
        V: the pull velocities [m/s], shape (m,).
        starts: the starting states, one row each (``"paper"``: the tape at rest; ``"steady"``:
            steady peeling, v = V).
        tau: τ [s] of every run (0: the DAE itself). t_final: the runs' end time [s].
        transient: the statistics cover ``[transient, t_stop]`` [s] (``window_start``: per lane).
        status … v_hi: the per-lane fields of :data:`LANE_FIELDS`, shape (len(starts), m):
            int for status, jumps, slips, events and repeats, else float (NaN: no such value).
        jump_G, jump_up: G [N] at the jumps in the window each lane kept (its last
            ``max_jumps``) and their direction (True: stick → slip), shape (len(starts), m, J), J
            the most in any lane; padded with NaN / False (:meth:`jump_forces` gives a lane's).
        phi_max, phi_min, v_max, v_min: φ's folds per V, shape (m,), NaN where φ has none.
        settings: what determined the map: the sweep's settings (JSON-able) and the map's own.
        wall_time: seconds the sweeps and statistics took.
    """

    V: np.ndarray
    starts: tuple[str, ...]
    tau: float
    t_final: float
    transient: float
    status: np.ndarray
    t_stop: np.ndarray
    window_start: np.ndarray
    jumps_total: np.ndarray
    jumps: np.ndarray
    slips: np.ndarray
    crossings: np.ndarray
    G_slip_min: np.ndarray
    G_slip_max: np.ndarray
    G_stick_min: np.ndarray
    G_stick_max: np.ndarray
    period: np.ndarray
    events: np.ndarray
    repeats: np.ndarray
    repeat_start: np.ndarray
    slip_interval: np.ndarray
    stick_duration: np.ndarray
    slip_duration: np.ndarray
    force_drop: np.ndarray
    stick_fraction: np.ndarray
    v_stick_min: np.ndarray
    v_stick_max: np.ndarray
    v_slip_min: np.ndarray
    v_slip_max: np.ndarray
    v_mean: np.ndarray
    v_lo: np.ndarray
    v_hi: np.ndarray
    jump_G: np.ndarray
    jump_up: np.ndarray
    phi_max: np.ndarray
    phi_min: np.ndarray
    v_max: np.ndarray
    v_min: np.ndarray
    settings: dict = dataclasses.field(default_factory=dict)
    wall_time: float = math.nan

    # ------------------------------------------------------------------ derived
    @property
    def stick_slip(self) -> np.ndarray:
        """(len(starts), m) bool: the run still slips after the transient (jumps, or crossings of v̂)."""
        return (self.jumps > 0) | (self.crossings > 0)

    @property
    def regular(self) -> np.ndarray:
        """(len(starts), m) bool: a repeat of the stick → slip events was found."""
        return self.events > 0

    @property
    def irregular(self) -> np.ndarray:
        """(len(starts), m) bool: stick-slip without a repeat found."""
        return self.stick_slip & ~self.regular

    @property
    def completed(self) -> np.ndarray:
        """(len(starts), m) bool: the run reached t_final."""
        return self.status == int(StopReason.COMPLETED)

    @property
    def early(self) -> np.ndarray:
        """(len(starts), m) bool: the run stopped before the transient (summarized over
        [t_stop/2, t_stop])."""
        return self.window_start < self.transient

    @property
    def has_folds(self) -> np.ndarray:
        """(m,) bool: φ(·, V) has its two folds (a maximum and a minimum in v)."""
        return np.isfinite(self.v_max) & np.isfinite(self.v_min)

    def row(self, start: str) -> int:
        """The row of ``start`` in the per-lane arrays."""
        if start not in self.starts:
            raise ValueError(f"start must be one of {self.starts}, got {start!r}")
        return self.starts.index(start)

    def jump_forces(self, start: str, index: int) -> tuple[np.ndarray, np.ndarray]:
        """(G, up) of the jumps in the window of lane ``index`` from ``start`` that the lane kept
        (its last ``max_jumps``), in time order."""
        s = self.row(start)
        n = int(np.count_nonzero(~np.isnan(self.jump_G[s, index])))
        return self.jump_G[s, index, :n].copy(), self.jump_up[s, index, :n].copy()

    def stick_slip_ranges(self, start: str) -> list[tuple[float, float]]:
        """The V ranges that stick-slip from ``start``: (first, last) V of each run of
        consecutive grid values with jumps after the transient (ascending V)."""
        return _runs(self.V, self.stick_slip[self.row(start)])

    def no_fold_ranges(self) -> list[tuple[float, float]]:
        """The V ranges of the grid where φ(·, V) has no fold."""
        return _runs(self.V, ~self.has_folds)

    # ------------------------------------------------------------------ output
    def as_dict(self) -> dict:
        """The map as JSON-able lists: ``V``, ``starts``, ``tau``, ``t_final``, ``transient``, the ranges
        (``stick_slip_ranges`` per start, ``no_fold_ranges``), ``lanes`` (every field of :data:`LANE_FIELDS` and
        ``stick_slip``, rows: starts) and ``folds`` (:data:`FOLD_FIELDS`, per V)."""
        return {
            "V": self.V.tolist(), "starts": list(self.starts), "tau": self.tau, "t_final": self.t_final,
            "transient": self.transient,
            "stick_slip_ranges": {start: [list(r) for r in self.stick_slip_ranges(start)] for start in self.starts},
            "no_fold_ranges": [list(r) for r in self.no_fold_ranges()],
            "lanes": {name: np.asarray(getattr(self, name)).tolist() for name in (*LANE_FIELDS, "stick_slip")},
            "folds": {name: np.asarray(getattr(self, name)).tolist() for name in FOLD_FIELDS},
        }  # fmt: skip

    def as_arrays(self) -> dict[str, np.ndarray]:
        """Plain arrays for ``np.savez`` (loads with ``allow_pickle=False``): V, starts (a
        string array), the scalars tau, t_final, transient and wall_time, every per-lane field,
        stick_slip, jump_G, jump_up, the folds and settings_json (a string). The inverse is
        :meth:`from_arrays`."""
        out = {
            "V": np.asarray(self.V, float),
            "starts": np.asarray(self.starts, dtype=str),
            "tau": np.float64(self.tau),
            "t_final": np.float64(self.t_final),
            "transient": np.float64(self.transient),
            "wall_time": np.float64(self.wall_time),
        }
        for name in LANE_FIELDS:
            out[name] = np.asarray(getattr(self, name), np.int64 if name in _INT_FIELDS else float)
        out["stick_slip"] = np.asarray(self.stick_slip, bool)
        out["jump_G"] = np.asarray(self.jump_G, float)
        out["jump_up"] = np.asarray(self.jump_up, bool)
        for name in FOLD_FIELDS:
            out[name] = np.asarray(getattr(self, name), float)
        out["settings_json"] = np.asarray(json.dumps(json_safe(self.settings), allow_nan=False), dtype=str)
        return out

    @classmethod
    def from_arrays(cls, arrays: Mapping) -> StickSlipMap:
        """The map from :meth:`as_arrays`' dict or a loaded ``.npz`` (``np.load(path)``)."""
        get = {key: np.asarray(arrays[key]) for key in arrays}
        missing = [k for k in ("V", "starts", "tau", "t_final", "transient", *LANE_FIELDS, "jump_G", "jump_up",
                               *FOLD_FIELDS) if k not in get]  # fmt: skip
        if missing:
            raise ValueError(f"not a stick-slip map: missing {', '.join(missing)}")
        settings = json.loads(str(get["settings_json"])) if "settings_json" in get else {}
        return cls(
            V=get["V"].astype(float),
            starts=tuple(str(s) for s in np.atleast_1d(get["starts"])),
            tau=float(get["tau"]),
            t_final=float(get["t_final"]),
            transient=float(get["transient"]),
            **{name: get[name] for name in (*LANE_FIELDS, "jump_G", "jump_up", *FOLD_FIELDS)},
            settings=settings,
            wall_time=float(get["wall_time"]) if "wall_time" in get else math.nan,
        )

    def save(self, path) -> None:
        """Write the map to ``path``: netCDF-4 for a ``.nc`` suffix (:meth:`to_xarray`; needs
        ``pip install "peeljax[xarray]"``), else an ``.npz`` of :meth:`as_arrays` with
        ``meta_json`` (kind, units, peeljax version; the name kept exactly as given).
        :func:`peeljax.load` reads either back. The file is replaced only once it is complete."""
        from .._atomic import write_npz
        from .._files import META_KEY, meta_array, write_netcdf
        from .labelled import MAP_UNITS
        from .storage import is_netcdf

        if is_netcdf(path):
            write_netcdf(self.to_xarray(), path)
        else:
            write_npz(path, {**self.as_arrays(), META_KEY: meta_array("stick-slip-map", MAP_UNITS)})

    def to_xarray(self):
        """The map as an ``xarray.Dataset``: dimensions ``start``, ``V`` (and ``jump`` for
        ``jump_G``, ``jump_up``), a ``units`` attribute on each variable, and ``kind``,
        ``peeljax_version``, tau, t_final, transient and ``settings_json`` as attributes.
        Needs ``pip install "peeljax[xarray]"``."""
        from .labelled import map_dataset

        return map_dataset(self)

    @classmethod
    def from_xarray(cls, dataset) -> StickSlipMap:
        """The map from its dataset (:meth:`to_xarray`, or a netCDF file it was written to)."""
        from .labelled import map_arrays

        return cls.from_arrays(map_arrays(dataset))

    def __str__(self) -> str:
        V = self.V
        tau = "τ = 0 (the DAE)" if self.tau == 0 else f"τ = {self.tau:g} s"
        lines = [
            (
                f"stick-slip map: {V.size} values of V in [{V.min():.4g}, {V.max():.4g}] m/s, {tau}, "
                f"t in [0, {self.t_final:g}] s, statistics over t >= {self.transient:g} s"
            )
        ]
        no_fold = self.no_fold_ranges()
        lines.append(
            "  phi has its folds for every V" if not no_fold
            else f"  phi has no fold {_where_V(no_fold)} (no stick-slip possible)"
        )  # fmt: skip
        header = (f"  {'start':<7} {'stick-slip for V in [m/s]':<34} {'lanes':>5} {'regular':>7} {'irregular':>9} "
                  f"{'stopped':>7}")  # fmt: skip
        lines.append(header)
        for s, start in enumerate(self.starts):
            ranges = self.stick_slip_ranges(start)
            lines.append(
                f"  {start:<7} {_ranges_text(ranges) or 'none':<34} {int(self.stick_slip[s].sum()):>5} "
                f"{int(self.regular[s].sum()):>7} {int(self.irregular[s].sum()):>9} {int((~self.completed[s]).sum()):>7}"
            )
        regular = self.regular
        if regular.any():
            periods = self.period[regular]
            events = self.events[regular]
            k = f"{events.min()}" if events.min() == events.max() else f"{events.min()}–{events.max()}"
            lines.append(
                f"  repeats: T in [{periods.min():.4g}, {periods.max():.4g}] s with {k} stick -> slip event"
                f"{'' if events.max() == 1 else 's'} per repeat"
            )
        if len(self.starts) > 1:
            differ = np.any(self.stick_slip != self.stick_slip[:1], axis=0)
            if differ.any():
                lines.append(f"  the starts disagree (coexisting stick-slip and steady peeling) at V = "
                             f"{', '.join(f'{v:.4g}' for v in V[differ][:8])}{' ...' if differ.sum() > 8 else ''} m/s")  # fmt: skip
        if not np.all(self.completed):
            reasons = sorted({StopReason(int(c)).name.lower() for c in self.status[~self.completed]})
            early = int(self.early.sum())
            lines.append(
                f"  {int((~self.completed).sum())} runs stopped before t_final ({', '.join(reasons)}): summarized up to "
                f"t_stop{f', {early} of them from t_stop/2 (stopped before the transient)' if early else ''}"
            )
        return "\n".join(lines)


def _read_npz(arrays: dict, name: str) -> StickSlipMap:
    try:
        return StickSlipMap.from_arrays(arrays)
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{name!r} is malformed: not a stick-slip map's arrays ({error})") from None


# peeljax.load reads the map's files (.npz and netCDF).
register_reader("stick-slip-map", npz=_read_npz, netcdf=lambda dataset, name: StickSlipMap.from_xarray(dataset))


# ---------------------------------------------------------------------------- helpers
def _runs(V: np.ndarray, mask: np.ndarray) -> list[tuple[float, float]]:
    """(first, last) V of each run of consecutive True in ``mask`` along ascending V."""
    order = np.argsort(V, kind="stable")
    V, mask = np.asarray(V)[order], np.asarray(mask, bool)[order]
    ranges, begin = [], None
    for i, flag in enumerate(mask):
        if flag and begin is None:
            begin = i
        if begin is not None and (not flag or i == mask.size - 1):
            end = i if flag else i - 1
            ranges.append((float(V[begin]), float(V[end])))
            begin = None
    return ranges


def _where_V(ranges: list[tuple[float, float]]) -> str:
    """'at V = 6 m/s' for one value, 'for V in [0.3, 0.5], 6 m/s' otherwise."""
    if len(ranges) == 1 and ranges[0][0] == ranges[0][1]:
        return f"at V = {ranges[0][0]:.4g} m/s"
    return f"for V in {_ranges_text(ranges)} m/s"


def _ranges_text(ranges: list[tuple[float, float]]) -> str:
    return ", ".join(f"{a:.4g}" if a == b else f"[{a:.4g}, {b:.4g}]" for a, b in ranges)


def _check_V(V) -> np.ndarray:
    array = np.array(V, dtype=float)  # a copy: the map keeps it
    if array.ndim > 1:
        raise ValueError(f"V must be a number or 1-d, got shape {array.shape}")
    array = np.atleast_1d(array)
    if array.size == 0:
        raise ValueError("V must hold at least one value")
    if not np.all(np.isfinite(array)) or np.any(array <= 0):
        raise ValueError(f"V must be finite and > 0, got {array[~(np.isfinite(array) & (array > 0))][:3].tolist()}")
    return array


def _check_starts(starts) -> tuple[str, ...]:
    if isinstance(starts, str):
        starts = (starts,)
    starts = tuple(starts)
    if not starts:
        raise ValueError(f"starts must name at least one of {STARTS}")
    bad = [s for s in starts if s not in STARTS]
    if bad:
        raise ValueError(f"starts must be among {STARTS}, got {bad[0]!r}")
    if len(set(starts)) != len(starts):
        raise ValueError(f"starts must not repeat, got {starts}")
    return starts


def _check_scalar(name: str, value, low: float, strict: bool) -> float:
    if isinstance(value, bool):
        raise TypeError(f"{name} must be a real number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(number) or (number <= low if strict else number < low):
        raise ValueError(f"{name} must be finite and {'>' if strict else '>='} {low:g}, got {value!r}")
    return number


def check_map_options(V, tau, t_final, transient, starts, fold, repeat_rtol, sweep_kwargs) -> tuple:
    """The map's own checks (the sweep checks the rest before compiling): returns
    (V, tau, t_final, transient, starts)."""
    V = _check_V(V)
    if np.ndim(tau) != 0:
        raise ValueError(f"tau must be one number (the map runs over V at one tau), got shape {np.shape(tau)}")
    tau = _check_scalar("tau", tau, 0.0, strict=False)
    t_final = _check_scalar("t_final", t_final, 0.0, strict=True)
    transient = t_final / 2 if transient is None else _check_scalar("transient", transient, 0.0, strict=False)
    if not transient < t_final:
        raise ValueError(f"transient must lie in [0, t_final) = [0, {t_final:g}), got {transient:g}")
    starts = _check_starts(starts)
    if fold == "stop":
        raise ValueError(
            "fold='stop' ends every run at its first fold: the map needs fold='jump' (or 'follow', tau > 0)"
        )
    _check_scalar("repeat_rtol", repeat_rtol, 0.0, strict=True)
    own = sorted(set(sweep_kwargs) & set(_OWN_KEYS))
    if own:
        raise ValueError(f"stick_slip_map sets {', '.join(own)} itself: pass it as the map's own argument")
    for key in ("dt", "save_every"):
        if sweep_kwargs.get(key) is not None:
            raise ValueError(
                f"{key} asks for a uniform mesh, which locates no fold and keeps no jumps; the map runs on "
                "error control"
            )
    if sweep_kwargs.get("out") is not None:
        raise ValueError("out: the map runs one sweep per start; save the map itself (StickSlipMap.save)")
    if sweep_kwargs.get("params"):
        raise ValueError("params: the map runs over V only; give the model with the parameters set")
    window = sweep_kwargs.get("window")
    if window is not None:
        w0, _ = check_window(window)
        if not math.isclose(w0 * t_final, transient, rel_tol=1e-12, abs_tol=1e-15):
            raise ValueError(
                f"window starts at {w0 * t_final:g} s, not at transient = {transient:g} s: the lanes accumulate their "
                "cycle statistics over the sweep's window, so its start is the transient "
                f"(give window=({transient / t_final:g}, w1), or transient={w0 * t_final:g})"
            )
    return V, tau, t_final, transient, starts


_FOLD_BLOCK = 4096  # V per compiled call of the fold search (smaller maps: the next power of two)


def fold_table(model: PeelingModel, V: np.ndarray) -> dict[str, np.ndarray]:
    """φ's folds per V (host arrays): phi_max, phi_min, v_max, v_min (NaN where none).

    V goes in blocks of a power of two (at most 4096, the last block padded), so that maps of
    any size share a few compiled searches."""
    V = np.asarray(V, float)
    block = min(_FOLD_BLOCK, 1 << max(4, (V.size - 1).bit_length()))
    padded = np.concatenate([V, np.full(-V.size % block, V[-1])])
    parts = [_folds(model, padded[i : i + block]) for i in range(0, padded.size, block)]
    return {name: np.concatenate([np.asarray(getattr(p, name), float) for p in parts])[: V.size] for name in FOLD_FIELDS}


def _folds(model: PeelingModel, V: np.ndarray):
    import equinox as eqx
    import jax

    from ..branches import phi_folds

    return eqx.filter_jit(jax.vmap(phi_folds, in_axes=(None, 0)))(model, V)


def _capped(repeat):
    """A repeat of at most MAX_REPEAT_EVENTS events per period (the longest the lanes search), else None."""
    return repeat if repeat is not None and repeat.events <= MAX_REPEAT_EVENTS else None


def _settled(kept: np.ndarray, n: int, rtol: float):
    """The repeat on the later half, then the later quarter, of a window's n stick → slip events,
    each at most the last KEPT_SLIPS (a lane keeps no more), with its first time; (None, NaN) if
    none. ``kept``: the last min(n, KEPT_SLIPS) or more of the window's stick → slip times."""
    if n < 5:
        return None, math.nan
    for fraction in (2, 4):
        tail = kept[kept.size - min(n // fraction, KEPT_SLIPS) :]
        repeat = _capped(repeat_pattern(tail, rtol=rtol))
        if repeat is not None:
            return repeat, float(tail[0])
    return None, math.nan


def _early_lane(result, index: int, repeat_rtol: float, settle: bool) -> dict:
    """A lane that stopped before the transient: summarized over the later half of what it ran,
    [t_stop/2, t_stop], or the part of it whose jumps the lane kept (its last max_jumps)."""
    t_stop = float(result.t_stop[index])
    start = max(0.5 * t_stop, kept_window_start(result.jumps, index))
    lane = {name: math.nan for name in _CYCLE_FIELDS} | {"window_start": start, "jumps": 0, "slips": 0,
                                                         "events": 0, "repeats": 0}  # fmt: skip
    if not 0 < t_stop or not start < t_stop:  # stopped at once: nothing to summarize
        return lane
    record = {key: result.jumps[key][index] for key in result.jumps}
    stats = cycle_statistics(record, t_stop, transient=start, rtol=repeat_rtol)
    repeat, repeat_start = _capped(stats.repeat), math.nan
    t, up = np.asarray(record["jump_t"], float), np.asarray(record["jump_up"], bool)
    up_times = t[: min(int(record["jump_count"]), t.size)]
    up_times = up_times[(up_times >= start) & up[: up_times.size]]
    if repeat is not None:
        repeat_start = float(up_times[0])
    elif settle:
        repeat, repeat_start = _settled(up_times, up_times.size, repeat_rtol)
    return lane | {
        "jumps": stats.jumps, "slips": stats.slips, "G_slip_min": stats.G_slip.min, "G_slip_max": stats.G_slip.max,
        "G_stick_min": stats.G_stick.min, "G_stick_max": stats.G_stick.max,
        "period": math.nan if repeat is None else repeat.period, "events": 0 if repeat is None else repeat.events,
        "repeats": 0 if repeat is None else repeat.repeats, "repeat_start": repeat_start,
        "slip_interval": stats.slip_interval.mean, "stick_duration": stats.stick_duration.mean,
        "slip_duration": stats.slip_duration.mean, "force_drop": stats.force_drop.mean,
        "stick_fraction": stats.stick_fraction, "v_stick_min": stats.v_stick[0], "v_stick_max": stats.v_stick[1],
        "v_slip_min": stats.v_slip[0], "v_slip_max": stats.v_slip[1],
    }  # fmt: skip


# The map's cycle fields, from a lane's window sums (SweepResult.cycles) by name.
_FROM_CYCLES = {
    "jumps": "cycle_jumps", "slips": "cycle_slips", "G_slip_min": "cycle_G_slip_min",
    "G_slip_max": "cycle_G_slip_max", "G_stick_min": "cycle_G_stick_min", "G_stick_max": "cycle_G_stick_max",
    "slip_interval": "cycle_slip_interval_mean", "stick_duration": "cycle_stick_duration_mean",
    "slip_duration": "cycle_slip_duration_mean", "force_drop": "cycle_force_drop_mean",
    "stick_fraction": "cycle_stick_fraction", "v_stick_min": "cycle_v_stick_min", "v_stick_max": "cycle_v_stick_max",
    "v_slip_min": "cycle_v_slip_min", "v_slip_max": "cycle_v_slip_max",
}  # fmt: skip
_CYCLE_FIELDS = (*_FROM_CYCLES, "period", "events", "repeats", "repeat_start")


def map_lanes(result, transient: float, repeat_rtol: float, settle: bool) -> dict[str, np.ndarray]:
    """The per-lane fields of one start's sweep (arrays over its lanes), and ``G``, ``up``: the
    kept jumps in each lane's window, (lanes, width) padded with NaN / False.

    The window [transient, t_stop]: its statistics were accumulated in each lane's loop over
    all of its jumps (``result.cycles``); the repeat's settle search reads the last stick → slip
    times the lane kept. A lane that stopped before the transient: :func:`_early_lane`."""
    t_stop = np.asarray(result.t_stop, float)
    cycles = result.cycles
    out = {
        "status": np.asarray(result.status, np.int64),
        "t_stop": t_stop,
        "window_start": np.full(t_stop.shape, float(transient)),
        "jumps_total": np.asarray(result.jumps["jump_count"], np.int64),
        "crossings": np.asarray(result.events, np.int64),
        "v_mean": np.asarray(result.v_mean, float),
        "v_lo": np.asarray(result.v_min, float),
        "v_hi": np.asarray(result.v_max, float),
    }
    out.update({name: np.asarray(cycles[key]).copy() for name, key in _FROM_CYCLES.items()})
    table = repeat_table(cycles, repeat_rtol)
    out.update(period=table["period"], events=table["events"], repeats=table["repeats"])
    out["repeat_start"] = np.where(table["events"] > 0, np.asarray(cycles["cycle_first_slip"], float), np.nan)
    if settle:
        # A long repeat can take longer to settle than the transient: look again on the later
        # half, then the later quarter, of the window's stick → slip events (the last ones kept).
        for i in np.flatnonzero((table["events"] == 0) & (out["slips"] >= 5)):
            repeat, first = _settled(kept_slip_times(cycles, i), int(out["slips"][i]), repeat_rtol)
            if repeat is not None:
                out["period"][i], out["events"][i], out["repeats"][i] = repeat.period, repeat.events, repeat.repeats
                out["repeat_start"][i] = first
    for i in np.flatnonzero(~(transient < t_stop)):
        for name, value in _early_lane(result, int(i), repeat_rtol, settle).items():
            out[name][i] = value
    # The kept jumps in each window: the last ones of the lane's kept jumps (in time order).
    t = np.asarray(result.jumps["jump_t"], float)
    with np.errstate(invalid="ignore"):
        inside = (t >= out["window_start"][:, None]) & (t <= t_stop[:, None])
    count = inside.sum(axis=1)
    first = np.argmax(inside, axis=1)
    width = max(1, int(count.max(initial=0)))
    slot = np.minimum(first[:, None] + np.arange(width), t.shape[1] - 1) if t.shape[1] else np.zeros((t_stop.size, width), int)
    keep = np.arange(width) < count[:, None]
    out["G"] = np.where(keep, np.take_along_axis(np.asarray(result.jumps["jump_G"], float), slot, axis=1), np.nan)
    out["up"] = keep & np.take_along_axis(np.asarray(result.jumps["jump_up"], bool), slot, axis=1)
    return out


# ---------------------------------------------------------------------------- the map
def stick_slip_map(
    model: PeelingModel | None = None,
    V: ArrayLike = DEFAULT_V,
    *,
    tau: float = 0.0,
    t_final: float = 3.0,
    transient: float | None = None,
    starts: Sequence[str] = STARTS,
    rtol: float | None = None,
    atol: float | None = None,
    max_jumps: int | None = None,
    fold: str | None = None,
    repeat_rtol: float = 1e-3,
    settle: bool = True,
    progress: bool = True,
    **sweep_kwargs,
) -> StickSlipMap:
    """The stick-slip map over V: one :func:`peeljax.sweep` per start, each lane summarized.

    Each start runs ``peeljax.sweep(model, V=V, tau=tau, t_final=t_final, grid="pairs",
    start=start, fold=fold, ...)`` (every lane the run :func:`peeljax.simulate` makes with the
    same settings), with the sweep's v window set to [transient, t_final] unless ``window`` is
    given; then each lane's jumps in [transient, t_stop] become its cycle statistics
    (:meth:`peeljax.SweepResult.cycle_statistics`). Definitions: :mod:`.stick_slip_map`.

    Args:
        model: the model (default: the paper's).
        V: pull velocities [m/s], > 0 (a number or 1-d; default 200 values in [0.2, 8]).
        tau: τ [s] of every run: 0 (default) the DAE itself, > 0 the homogenized ODE.
        t_final: end time of the runs [s].
        transient: the statistics start here [s], in [0, t_final) (default t_final/2).
        starts: the starting states, ``"paper"`` (the tape at rest) and/or ``"steady"`` (steady
            peeling, v = V); one sweep and one row of the map each.
        rtol, atol: the error control's tolerances (default: the sweep's, 1e-6 and 1e-9).
        max_jumps: each lane keeps its last ``max_jumps`` jumps (default: the sweep's, 64):
            ``jump_G``/``jump_up``, the settle search (at most the last 65 stick → slip events)
            and a lane that stopped before the transient read them; every other statistic is
            accumulated over all of the window's jumps. No lane stops for a full record.
        fold: ``"jump"`` (default) or ``"follow"`` (τ > 0); ``"stop"`` is refused (no cycles).
        repeat_rtol: the tolerance of the repeat search (:func:`peeljax.cycles.repeat_pattern`).
        settle: where no repeat is found over the whole window, search again on the later half
            and then the later quarter of its stick → slip events, each at most the last 65 (a
            long repeat can take longer to settle than the transient); ``repeat_start`` says
            where the repeat was matched from.
        progress: a tqdm bar per sweep (stderr).
        **sweep_kwargs: other options of :func:`peeljax.sweep` (``chunk``, ``max_steps``,
            ``window`` (it starts at the transient), ``devices``, ``lane_batch``, ``solver``,
            ``rho``, ``dtmin``, …). ``dt``,
            ``save_every`` (a uniform mesh keeps no jumps), ``out`` and ``params`` are refused.

    Returns:
        A :class:`StickSlipMap`.

    Raises:
        ValueError: bad input, before anything is compiled (the sweep checks its own options
            the same way).
    """
    model = PeelingModel() if model is None else model
    if not isinstance(model, PeelingModel):
        raise TypeError(f"model must be a PeelingModel, got {type(model).__name__}")
    V, tau, t_final, transient, starts = check_map_options(
        V, tau, t_final, transient, starts, fold, repeat_rtol, sweep_kwargs
    )
    from .api import sweep

    sweep_kwargs.setdefault("window", (transient / t_final, 1.0))
    begin = time.perf_counter()
    results = []
    for start in starts:
        if progress:
            print(f"stick-slip map: {V.size} values of V from start {start!r}", file=sys.stderr)
        result = sweep(
            model, V=V, tau=tau, t_final=t_final, grid="pairs", rtol=rtol, atol=atol, fold=fold,
            max_jumps=max_jumps, start=start, progress=progress, **sweep_kwargs,
        )  # fmt: skip
        if result.jumps is None:  # cannot happen with the options checked above; be explicit
            raise ValueError("the sweep kept no jump records: the map needs fold='jump' under error control")
        results.append(result)

    rows = [map_lanes(r, transient, float(repeat_rtol), settle) for r in results]
    fields = {
        name: np.stack([row[name] for row in rows]).astype(np.int64 if name in _INT_FIELDS else float)
        for name in LANE_FIELDS
    }
    width = max(row["G"].shape[1] for row in rows)
    jump_G = np.full((len(starts), V.size, width), np.nan)
    jump_up = np.zeros((len(starts), V.size, width), bool)
    for s, row in enumerate(rows):
        jump_G[s, :, : row["G"].shape[1]] = row["G"]
        jump_up[s, :, : row["up"].shape[1]] = row["up"]
    folds = fold_table(model, V)
    settings = {
        "sweep": results[0].settings | {"start": list(starts)},
        "transient": transient,
        "repeat_rtol": float(repeat_rtol),
        "settle": bool(settle),
    }
    return StickSlipMap(
        V=V, starts=starts, tau=tau, t_final=t_final, transient=transient, **fields, jump_G=jump_G,
        jump_up=jump_up, **folds, settings=settings, wall_time=time.perf_counter() - begin,
    )  # fmt: skip
