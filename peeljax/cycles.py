"""Stick-slip cycles from the jumps of a run: durations, forces, branch ranges and the repeat.

A run carried through the folds of φ (``fold="jump"``) records every jump of the peeling
velocity v in a :class:`~peeljax.solution.JumpRecord`: stick → slip at φ's maximum (``up``
True, v jumps up) and slip → stick at its minimum (``up`` False, v jumps down, to 0 when the
tape lands fully stuck). Between two jumps the tape stays on one branch, so the jumps alone
give the cycle statistics, on the host, without the trajectory:

* **stick duration**: from a slip → stick jump to the next (stick → slip) jump;
* **slip duration**: from a stick → slip jump to the next (slip → stick) jump;
* **slip interval**: the time between consecutive stick → slip events;
* **force drop**: G at a stick → slip jump minus G at the following slip → stick jump
  (G = (1 + l·sinα/L)·F is continuous across a jump);
* **G_slip** / **G_stick**: the forces at which the tape slips / re-sticks;
* **v ranges** seen at the jumps on the stick branch (landing v of slip → stick jumps up to the
  v before stick → slip jumps) and on the slip branch (v before slip → stick jumps up to the
  landing v of stick → slip jumps);
* **stick fraction**: the fraction of the window spent on the stick branch;
* **the repeat**: the smallest number k of stick → slip events after which the sequence of
  intervals between them repeats (:func:`repeat_pattern`), with its period. A period is
  reported only together with its k — a period alone says little without its orbit: on the
  paper's V = 1.1 m/s an orbit of 8 events per repeat (T ≈ 0.2183 s) coexists with one of 9
  (T ≈ 0.2362 s) — or the run is called "irregular" when no repeat is found within it.

Only the window [transient, t_end] counts: jumps before ``transient`` (the approach to the
attractor) and after ``t_end`` are left out, and a duration counts only when both of its jumps
lie in the window (a stick under way at ``t_end`` is not a stick duration). The repeat is
searched on the stick → slip times in the window, and every interval there has to match: cut
the settling transient away, or the run reads as irregular.

Everything here is plain NumPy on the host; a batched record has to be indexed first.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .solution import JumpRecord, Solution

__all__ = ["CycleStatistics", "RepeatPattern", "Spread", "cycle_statistics", "repeat_pattern"]

_KEYS = ("jump_t", "jump_up", "jump_v_before", "jump_v_after", "jump_G")


def _json_float(value: float) -> float | None:
    return None if not math.isfinite(value) else float(value)


# ---------------------------------------------------------------------------- results
@dataclass(frozen=True)
class Spread:
    """Mean, minimum and maximum of ``n`` values (NaN for all three when ``n`` is 0)."""

    mean: float
    min: float
    max: float
    n: int

    @classmethod
    def of(cls, values) -> Spread:
        """The spread of a 1-d sequence of numbers (empty: NaN, NaN, NaN, 0)."""
        array = np.asarray(values, dtype=float).ravel()
        if array.size == 0:
            return cls(math.nan, math.nan, math.nan, 0)
        return cls(float(array.mean()), float(array.min()), float(array.max()), int(array.size))

    def as_dict(self) -> dict:
        """``{"mean", "min", "max", "n"}``, JSON-able (NaN -> None)."""
        return {"mean": _json_float(self.mean), "min": _json_float(self.min), "max": _json_float(self.max), "n": self.n}

    def _ms(self) -> str:
        """``mean ms (min–max)``, or ``—`` when empty."""
        if self.n == 0:
            return "—"
        return f"{1e3 * self.mean:.3g} ms ({1e3 * self.min:.3g}–{1e3 * self.max:.3g})"

    def _plain(self, unit: str) -> str:
        if self.n == 0:
            return "—"
        return f"{self.mean:.4g} {unit} ({self.min:.4g}–{self.max:.4g})"


@dataclass(frozen=True)
class RepeatPattern:
    """A repeat of the stick → slip events: ``events`` of them every ``period`` seconds.

    Attributes:
        period: the repeat time T [s] (the mean over the full repeats seen).
        events: the number k of stick → slip events per repeat (1: a regular stick-slip cycle).
        repeats: how many full repeats were seen (≥ 2).
        spread: the largest deviation |d_{i+k} − d_i| between matched intervals [s].
    """

    period: float
    events: int
    repeats: int
    spread: float

    def as_dict(self) -> dict:
        """``{"period", "events", "repeats", "spread"}``, JSON-able."""
        return {"period": _json_float(self.period), "events": self.events, "repeats": self.repeats,
                "spread": _json_float(self.spread)}  # fmt: skip

    def __str__(self) -> str:
        events = "event" if self.events == 1 else "events"
        return (
            f"T = {self.period:.7g} s with {self.events} stick → slip {events} per repeat "
            f"({self.repeats} repeats seen, intervals matched to {self.spread:.2g} s)"
        )


@dataclass(frozen=True)
class CycleStatistics:
    """The stick-slip cycles of one run in the window [``transient``, ``t_end``].

    Attributes:
        transient: the start of the window [s]; earlier jumps are left out.
        t_end: the end of the window [s] (normally the end of the run).
        jumps: the number of jumps in the window.
        slips: the number of stick → slip events in the window.
        stick_duration: from a slip → stick jump to the next jump, a stick → slip one [s].
        slip_duration: from a stick → slip jump to the next jump, a slip → stick one [s].
        slip_interval: the time between consecutive stick → slip events [s].
        force_drop: G at a stick → slip jump minus G at the following slip → stick jump [N].
        G_slip: the force at which the tape slips (G of the stick → slip jumps) [N].
        G_stick: the force at which it re-sticks (G of the slip → stick jumps) [N].
        v_stick: the range of v on the stick branch seen at the jumps [m/s]: (the lowest landing
            v of a slip → stick jump, 0 when it lands fully stuck; the highest v before a
            stick → slip jump). NaN where there is no such jump.
        v_slip: the range of v on the slip branch seen at the jumps [m/s]: (the lowest v before a
            slip → stick jump; the highest landing v of a stick → slip jump).
        stick_fraction: the fraction of [transient, t_end] spent on the stick branch. The branch
            at ``transient`` is inferred from the first jump in the window (stuck before a
            stick → slip jump, slipping before a slip → stick one), else from the last jump
            before it; NaN when the run has no jump at all (the branch is unknown).
        repeat: the repeat of the stick → slip events (:func:`repeat_pattern`), or None:
            "irregular", no repeat found within the window.
    """

    transient: float
    t_end: float
    jumps: int
    slips: int
    stick_duration: Spread
    slip_duration: Spread
    slip_interval: Spread
    force_drop: Spread
    G_slip: Spread
    G_stick: Spread
    v_stick: tuple[float, float]
    v_slip: tuple[float, float]
    stick_fraction: float
    repeat: RepeatPattern | None

    @property
    def regular(self) -> bool:
        """True when a repeat was found."""
        return self.repeat is not None

    def as_dict(self) -> dict:
        """The statistics as plain JSON-able values: NaN -> None, each :class:`Spread` a dict,
        ``"repeat"`` a dict (period, events, repeats, spread) or the string ``"irregular"``."""
        return {
            "transient": float(self.transient),
            "t_end": float(self.t_end),
            "jumps": self.jumps,
            "slips": self.slips,
            "stick_duration": self.stick_duration.as_dict(),
            "slip_duration": self.slip_duration.as_dict(),
            "slip_interval": self.slip_interval.as_dict(),
            "force_drop": self.force_drop.as_dict(),
            "G_slip": self.G_slip.as_dict(),
            "G_stick": self.G_stick.as_dict(),
            "v_stick": [_json_float(v) for v in self.v_stick],
            "v_slip": [_json_float(v) for v in self.v_slip],
            "stick_fraction": _json_float(self.stick_fraction),
            "repeat": "irregular" if self.repeat is None else self.repeat.as_dict(),
        }

    def __str__(self) -> str:
        fraction = "—" if math.isnan(self.stick_fraction) else f"{self.stick_fraction:.3f}"
        head = f"cycles in [{self.transient:.6g}, {self.t_end:.6g}] s: {self.jumps} jumps, {self.slips} stick → slip"
        repeat = f"  repeat: {'irregular' if self.repeat is None else self.repeat}"
        times = (
            f"  stick {self.stick_duration._ms()}, slip {self.slip_duration._ms()}, "
            f"between slips {self.slip_interval._ms()}; stick fraction {fraction}"
        )
        forces = (
            f"  slips at G = {self.G_slip._plain('N')}, re-sticks at G = {self.G_stick._plain('N')}, "
            f"force drop {self.force_drop._plain('N')}"
        )
        return f"{head}\n{repeat}\n{times}\n{forces}"


# ---------------------------------------------------------------------------- the repeat
def repeat_pattern(up_times, *, rtol: float = 1e-3) -> RepeatPattern | None:
    """The repeat of a sequence of stick → slip times, or None when there is none ("irregular").

    With the intervals d_i = t_{i+1} − t_i, the repeat has the smallest k ≥ 1 such that d is
    k-periodic, |d_{i+k} − d_i| ≤ rtol·mean(d) for every i available, with at least two full
    repeats seen (2k + 1 events). Its period is the mean over the m = ⌊len(d)/k⌋ full repeats
    of the sum of k consecutive intervals, (t_{m·k} − t_0)/m.

    Every interval has to match: pass the times after the transient. Fewer than 3 events, or
    times that do not advance, give None.

    Args:
        up_times: the stick → slip times [s], 1-d, finite, non-decreasing.
        rtol: the tolerance relative to the mean interval (> 0).

    Raises:
        ValueError: for an ``rtol`` that is not finite and > 0, or ``up_times`` that are not
            1-d, finite and non-decreasing.
    """
    _check_rtol(rtol)
    t = np.asarray(up_times, dtype=float)
    if t.ndim != 1:
        raise ValueError(f"up_times must be 1-d, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError("up_times must be finite")
    d = np.diff(t)
    if np.any(d < 0):
        raise ValueError("up_times must be non-decreasing")
    if d.size < 2:
        return None
    scale = float(d.mean())
    if not scale > 0:
        return None
    tolerance = rtol * scale
    for k in range(1, d.size // 2 + 1):
        deviation = np.abs(d[k:] - d[:-k])
        spread = float(deviation.max())
        if spread <= tolerance:
            repeats = d.size // k
            period = float(t[repeats * k] - t[0]) / repeats
            return RepeatPattern(period=period, events=k, repeats=repeats, spread=spread)
    return None


# ---------------------------------------------------------------------------- the statistics
def cycle_statistics(jumps, t_end: float, *, transient: float = 0.0, rtol: float = 1e-3) -> CycleStatistics:
    """The stick-slip cycle statistics of one run from its jumps (see :class:`CycleStatistics`).

    Args:
        jumps: the jumps of a single run: a :class:`~peeljax.solution.JumpRecord` (not batched),
            a :class:`~peeljax.solution.Solution` of a ``fold="jump"`` run, or a mapping with the
            arrays ``jump_t``, ``jump_up``, ``jump_v_before``, ``jump_v_after``, ``jump_G``
            (:meth:`JumpRecord.as_numpy`, or a loaded ``.npz``; an optional ``jump_count``
            keeps its first entries only). Jump times must be non-decreasing.
        t_end: the end of the window [s], normally the end of the run (``t_stop``); later jumps
            are left out.
        transient: the start of the window [s] (≥ 0, < ``t_end``); earlier jumps are left out.
        rtol: the tolerance of the repeat search relative to the mean interval between
            stick → slip events (:func:`repeat_pattern`), > 0.

    Raises:
        ValueError: for a bad ``t_end``, ``transient`` or ``rtol`` (named in the message), a
            batched record, a run without a jump record, missing or mismatched arrays, or jump
            times that are not finite and non-decreasing.
    """
    t_end = _finite("t_end", t_end)
    transient = _finite("transient", transient)
    if transient < 0:
        raise ValueError(f"transient must be >= 0, got {transient!r}")
    if not transient < t_end:
        raise ValueError(f"transient must be < t_end = {t_end!r}, got {transient!r}")
    _check_rtol(rtol)

    t, up, v_before, v_after, G = _jump_arrays(jumps)
    up_before = up[t < transient]
    inside = (t >= transient) & (t <= t_end)
    t, up, v_before, v_after, G = (a[inside] for a in (t, up, v_before, v_after, G))
    down = ~up

    # Consecutive pairs of jumps: (up, down) is a slip, (down, up) a stick. On a regular run the
    # jumps alternate; a pair of two jumps the same way (never seen) gives neither.
    slip_pair = up[:-1] & down[1:]
    stick_pair = down[:-1] & up[1:]
    gaps = np.diff(t)

    up_times = t[up]
    # The branch at the start of the window: stuck if the first jump in it is stick → slip;
    # without one, where the last jump before it landed; without any jump, unknown.
    if t.size:
        stuck = bool(up[0])
    else:
        stuck = None if up_before.size == 0 else not bool(up_before[-1])

    return CycleStatistics(
        transient=transient,
        t_end=t_end,
        jumps=int(t.size),
        slips=int(up.sum()),
        stick_duration=Spread.of(gaps[stick_pair]),
        slip_duration=Spread.of(gaps[slip_pair]),
        slip_interval=Spread.of(np.diff(up_times)),
        force_drop=Spread.of(G[:-1][slip_pair] - G[1:][slip_pair]),
        G_slip=Spread.of(G[up]),
        G_stick=Spread.of(G[down]),
        v_stick=(_extreme(np.min, v_after[down]), _extreme(np.max, v_before[up])),
        v_slip=(_extreme(np.min, v_before[down]), _extreme(np.max, v_after[up])),
        stick_fraction=_stick_fraction(t, up, stuck, transient, t_end),
        repeat=repeat_pattern(up_times, rtol=rtol),
    )


def _stick_fraction(t: np.ndarray, up: np.ndarray, stuck: bool | None, start: float, end: float) -> float:
    """The fraction of [start, end] on the stick branch, starting ``stuck`` (None: unknown)."""
    if stuck is None:
        return math.nan
    edges = np.concatenate([[start], t, [end]])
    # the branch on each piece between jumps: the starting one, then the one each jump lands on
    on_stick = np.concatenate([[stuck], ~up])
    return float(np.sum(np.diff(edges)[on_stick]) / (end - start))


def _extreme(reduce, values: np.ndarray) -> float:
    return float(reduce(values)) if values.size else math.nan


# ---------------------------------------------------------------------------- input
def _finite(name: str, value) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(number):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return number


def _check_rtol(rtol) -> None:
    number = _finite("rtol", rtol)
    if not number > 0:
        raise ValueError(f"rtol must be > 0, got {rtol!r}")


def _jump_arrays(jumps) -> tuple[np.ndarray, ...]:
    """``(t, up, v_before, v_after, G)`` as host arrays of one run's recorded jumps."""
    if isinstance(jumps, Solution):
        if jumps.jumps is None:
            raise ValueError("this run has no jump record: run it with fold='jump'")
        jumps = jumps.jumps
    if isinstance(jumps, JumpRecord):
        if np.ndim(jumps.t) != 1:
            raise ValueError(
                f"jumps must be the record of a single run, got a batch of shape {np.shape(jumps.t)[:-1]}: "
                "index the batch first"
            )
        jumps = jumps.as_numpy()
    elif not isinstance(jumps, Mapping) and not (hasattr(jumps, "keys") and hasattr(jumps, "__getitem__")):
        raise ValueError(
            f"jumps must be a JumpRecord, a Solution or a mapping with {', '.join(_KEYS)}; got {type(jumps).__name__}"
        )
    keys = set(jumps.keys())
    missing = [key for key in _KEYS if key not in keys]
    if missing:
        raise ValueError(f"jumps lacks the array(s) {', '.join(missing)}")
    arrays = [np.asarray(jumps[key]) for key in _KEYS]
    for key, array in zip(_KEYS, arrays):
        if array.ndim != 1:
            raise ValueError(f"{key} must be 1-d (a single run), got shape {array.shape}")
    if "jump_count" in keys:
        count = int(np.asarray(jumps["jump_count"]))
        arrays = [array[:count] for array in arrays]
    sizes = {array.size for array in arrays}
    if len(sizes) != 1:
        raise ValueError(f"the jump arrays differ in length: {dict(zip(_KEYS, (a.size for a in arrays)))}")
    t = arrays[0].astype(float)
    if not np.all(np.isfinite(t)):
        raise ValueError("jump_t must be finite (NaN padding? keep the first jump_count entries)")
    if np.any(np.diff(t) < 0):
        raise ValueError("jump_t must be non-decreasing")
    return (t, arrays[1].astype(bool), *(array.astype(float) for array in arrays[2:]))
