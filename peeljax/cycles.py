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
  (T ≈ 0.2362 s). Without a repeat the window is either **too short to tell**
  (:class:`TooFewRepeats`: a near repeat still settling, with a window that would show it, or
  fewer than 31 stick → slip events) or **irregular**: measured as such, no repeat forming
  (:func:`repeat_outlook`).

Only the window [transient, t_end] counts: jumps before ``transient`` (the approach to the
attractor) and after ``t_end`` are left out, and a duration counts only when both of its jumps
lie in the window (a stick under way at ``t_end`` is not a stick duration). The repeat is
searched on the stick → slip times in the window, and every interval there has to match: a
window that still holds the settling reads as "too few repeats to tell", with the window (after
the settling) that would show the repeat.

Everything here is plain NumPy on the host; a batched record has to be indexed first.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields

import numpy as np

from .solution import JumpRecord, Solution

__all__ = [
    "STATISTICS",
    "CycleStatistics",
    "RepeatPattern",
    "Spread",
    "TooFewRepeats",
    "cycle_statistics",
    "repeat_outlook",
    "repeat_pattern",
]

# The five statistics of stick-slip that a table gives per V, a periodic orbit has exactly and a
# fit compares (the one definition: the fit's tables, the orbits and their files read it here):
# the mean force, the forces at the slip and at the re-stick [N], the time between slips and the
# slip's duration [s].
STATISTICS = ("F_mean", "F_slip", "F_stick", "period", "slip_duration")

# repeat_outlook: a near repeat matches its last repeat to within NEAR of the intervals' range, and a
# settling one shrinks its deviation by at least CONTRACTION per repeat; below MIN_EVENTS stick →
# slip events (each k ≤ 10 seen three times) nothing is called irregular.
NEAR = 0.05
CONTRACTION = 0.8
MIN_EVENTS = 31

_KEYS = ("jump_t", "jump_up", "jump_v_before", "jump_v_after", "jump_G")


def _json_float(value: float) -> float | None:
    return None if not math.isfinite(value) else float(value)


def _json_fields(record) -> dict:
    """A result dataclass's fields as a dict, its float fields through :func:`_json_float`."""
    return {f.name: _json_float(getattr(record, f.name)) if f.type == "float" else getattr(record, f.name)
            for f in fields(record)}  # fmt: skip


def _slip_events(k: int) -> str:
    return f"{k} stick → slip event{'' if k == 1 else 's'}"


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
        return _json_fields(self)

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
        return _json_fields(self)

    def __str__(self) -> str:
        return (
            f"T = {self.period:.7g} s with {_slip_events(self.events)} per repeat "
            f"({self.repeats} repeats seen, intervals matched to {self.spread:.2g} s)"
        )


@dataclass(frozen=True)
class TooFewRepeats:
    """No repeat confirmed, and the window too short to call the run irregular.

    Either a near repeat of ``events`` events is in the window, not matched over all of it (it
    matches at the end of the window but not from its start, or its latest repeat matches the
    one before to within 5 % of the intervals' range and the deviation shrinks), or there is none
    and the window holds fewer than ``MIN_EVENTS`` (31) stick → slip events (``events`` 0): too
    few to call it irregular. See :func:`repeat_outlook`.

    Attributes:
        events: k of the near repeat (0: too few events to try one).
        period: its period estimate, the sum of the last k intervals [s] (NaN for k = 0).
        spread: max |d_{i+k} − d_i| over its last k matched intervals [s] (NaN for k = 0).
        tolerance: what a repeat has to match, rtol·mean interval [s] (NaN for k = 0).
        start, end: a window [s] that would show the repeat: from where it has settled (seen, or
            extrapolated from the shrinking deviation) over 2.5 periods; NaN where it cannot be
            estimated (see ``length``).
        length: the least window length that could show it [s]: 2.5 periods, or one period
            more than the window seen when it gives no rate; for k = 0 the length holding
            31 events at the mean interval seen (NaN with a single event).
    """

    events: int
    period: float
    spread: float
    tolerance: float
    start: float
    end: float
    length: float

    def as_dict(self) -> dict:
        """The fields as a dict, JSON-able (NaN -> None)."""
        return _json_fields(self)

    def __str__(self) -> str:
        if math.isfinite(self.start):
            would = f"a window [{self.start:.3g}, {self.end:.3g}] s would do"
        elif math.isfinite(self.length):
            would = f"a window of at least {self.length:.3g} s would do"
        else:
            would = "a longer window would do"
        if self.events == 0:
            return f"too few repeats to tell (no near repeat in fewer than {MIN_EVENTS} stick → slip events; {would})"
        return (
            f"too few repeats to tell (near repeat: T ≈ {self.period:.4g} s with {_slip_events(self.events)}, "
            f"matched to {self.spread:.2g} s of {self.tolerance:.2g} s; {would})"
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
        repeat: the repeat of the stick → slip events (:func:`repeat_pattern`), or None.
        too_few: without a repeat, :class:`TooFewRepeats` when the window is too short to tell
            (:func:`repeat_outlook`); None otherwise (a repeat, "irregular", or no stick → slip).
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
    too_few: TooFewRepeats | None = None

    @property
    def regular(self) -> bool:
        """True when a repeat was found."""
        return self.repeat is not None

    @property
    def verdict(self) -> str:
        """``"regular"`` (a repeat), ``"too few repeats to tell"``, ``"irregular"`` (measured: no
        repeat forming) or ``"none"`` (no stick → slip event in the window)."""
        if self.repeat is not None:
            return "regular"
        if self.too_few is not None:
            return "too few repeats to tell"
        return "none" if self.slips == 0 else "irregular"

    def as_dict(self) -> dict:
        """The statistics as plain JSON-able values: NaN -> None, each :class:`Spread` a dict,
        ``"repeat"`` a dict (period, events, repeats, spread) or the :attr:`verdict` string
        (``"too few repeats to tell"``, ``"irregular"``, ``"none"``); ``"too_few_repeats"`` the
        :class:`TooFewRepeats` dict or None."""
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
            "repeat": self.verdict if self.repeat is None else self.repeat.as_dict(),
            "too_few_repeats": None if self.too_few is None else self.too_few.as_dict(),
        }

    def __str__(self) -> str:
        fraction = "—" if math.isnan(self.stick_fraction) else f"{self.stick_fraction:.3f}"
        head = f"cycles in [{self.transient:.6g}, {self.t_end:.6g}] s: {self.jumps} jumps, {self.slips} stick → slip"
        if self.repeat is not None:
            repeat = f"  repeat: {self.repeat}"
        elif self.too_few is not None:
            repeat = f"  repeat: {self.too_few}"
        elif self.slips == 0:
            repeat = "  repeat: none (no stick → slip in the window)"
        else:
            repeat = "  repeat: irregular (no repeat forming)"
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


def repeat_outlook(up_times, *, rtol: float = 1e-3, t_end: float | None = None) -> TooFewRepeats | None:
    """Whether a sequence of stick → slip times without a repeat is too short to tell.

    For a sequence where :func:`repeat_pattern` finds no repeat: :class:`TooFewRepeats` when
    the window cannot tell, None when it is measured irregular. With the intervals d_i and, for
    each k ≤ len(d)/2, the deviations e_i = |d_{i+k} − d_i|, the last repeat's deviation
    L_k = max of the last k of them, its rate q_k = the median of e_i / e_{i−k} over the
    window (a settling orbit shrinks every one of them, a chance match does not), the tolerance
    rtol·mean(d):

    * a near repeat forming: some L_k within 5 % of the range of the intervals (``NEAR``), no
      larger than the largest e_i of any earlier repeat, and shrinking, q_k ≤ 0.8
      (``CONTRACTION``). Too few: if L_k is within the tolerance, the repeat settled inside the
      window (its start still holds the settling) and the window from the first interval after
      the last mismatch shows it; else, with q_k from three ratios at least, L_k·q_k^n is
      extrapolated to the repeat n where it meets the tolerance, and without any ratio (one
      repeat of comparisons) k ≥ 3 intervals have to match;
    * otherwise, fewer than 31 events (``MIN_EVENTS``: every k up to 10 seen three times):
      too few (k = 0);
    * otherwise irregular (None): no repeat of up to len(d)/2 events forming.

    The window proposed holds 2.5 periods from where the repeat has settled (a repeat needs
    two full ones, 2k + 1 events). Among several k: the smallest that settled, else the one
    with the smallest L_k.

    Args:
        up_times: the stick → slip times [s] (as :func:`repeat_pattern`).
        rtol: the tolerance of the repeat (as :func:`repeat_pattern`).
        t_end: the end of the window [s] (default the last event): a settling repeat is
            extrapolated from here.
    """
    _check_rtol(rtol)
    t = np.asarray(up_times, dtype=float)
    if t.ndim != 1 or not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise ValueError("up_times must be 1-d, finite and non-decreasing")
    if t.size == 0:
        return None
    d = np.diff(t)
    end = float(t[-1]) if t_end is None else _finite("t_end", t_end)
    scale = float(d.mean()) if d.size else math.nan
    if t.size >= 3 and not scale > 0:  # times that do not advance
        return None
    tolerance = rtol * scale
    spread = float(d.max() - d.min()) if d.size else math.nan  # how much the intervals differ
    near = []  # (L_k, k, q_k) of the near repeats forming
    for k in range(1, d.size // 2 + 1):
        e = np.abs(d[k:] - d[:-k])
        last = float(e[-k:].max())
        if last > max(NEAR * spread, tolerance):
            continue
        # settling: the last repeat matched best of all (block maxima from the end) ...
        blocks = [float(e[max(0, j - k) : j].max()) for j in range(e.size - k, 0, -k)]
        if blocks and last > max(min(blocks), tolerance):
            continue
        # ... at a rate per repeat, the median of e_i / e_{i−k} over the window (chance matches do not shrink)
        now, before = e[k:], e[:-k]
        ok = before > 0
        rate = float(np.median(now[ok] / before[ok])) if ok.any() else math.nan
        if rate > CONTRACTION:
            continue
        if last <= tolerance:  # matched at the end of the window, not from its start: settled in it
            mismatched = np.flatnonzero(e > tolerance)
            start = float(t[int(mismatched[-1]) + 1]) if mismatched.size else float(t[0])
            period = float(d[-k:].sum())
            return TooFewRepeats(k, period, last, tolerance, start, start + 2.5 * period, 2.5 * period)
        # not yet within the tolerance: a rate from three ratios at least, or without any, k ≥ 3
        # matched intervals (a burst's smoothly levelling intervals look like k = 1 settling)
        if (ok.sum() >= 3) if ok.any() else k >= 3:
            near.append((last, k, rate))
    if near:
        last, k, rate = min(near)
        period = float(d[-k:].sum())
        if math.isnan(rate):  # one repeat of comparisons: no rate to extrapolate
            return TooFewRepeats(k, period, last, tolerance, math.nan, math.nan,
                                 max(2.5 * period, end - float(t[0]) + period))  # fmt: skip
        # deviation ∝ rate^n after n more repeats: within the tolerance after ⌈log(tol/L)/log rate⌉
        more = math.ceil(math.log(tolerance / last) / math.log(rate)) if rate > 0 else 1
        start = end + more * period
        return TooFewRepeats(k, period, last, tolerance, start, start + 2.5 * period, 2.5 * period)
    if t.size < MIN_EVENTS:
        length = (MIN_EVENTS - 1) * scale if scale > 0 else math.nan  # MIN_EVENTS events at the mean interval
        return TooFewRepeats(0, math.nan, math.nan, math.nan, math.nan, math.nan, length)
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
    repeat = repeat_pattern(up_times, rtol=rtol)
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
        repeat=repeat,
        too_few=None if repeat is not None else repeat_outlook(up_times, rtol=rtol, t_end=t_end),
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
