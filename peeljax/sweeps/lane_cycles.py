"""A sweep lane's cycle statistics from what the lane kept: the sums of its window, its last jumps.

Each lane of a sweep that goes through the folds of φ accumulates the cycle statistics of its
window inside the loop (:mod:`peeljax.integrators.cycle_accumulator`) and keeps its last
``max_jumps`` jumps (a ring buffer). Here, on the host, those arrays become

* :func:`repeat_table`: the repeat of every lane at once (:func:`peeljax.cycles.repeat_pattern`
  for k ≤ :data:`~peeljax.integrators.cycle_accumulator.MAX_REPEAT_EVENTS`);
* :func:`lane_cycle_statistics`: one lane's :class:`~peeljax.cycles.CycleStatistics`, what
  :func:`peeljax.cycle_statistics` gives for the same run's whole record;
* :func:`sweep_cycle_statistics`: :meth:`peeljax.SweepResult.cycle_statistics`, from the
  window's sums, or from the kept jumps for another window they cover.
"""

from __future__ import annotations

import numpy as np

from ..cycles import CycleStatistics, RepeatPattern, Spread, cycle_statistics, repeat_outlook
from ..integrators.cycle_accumulator import KEPT_SLIPS, MAX_REPEAT_EVENTS, SPREADS

__all__ = ["CYCLE_BYTES", "CYCLE_KEYS", "lane_cycle_statistics", "repeat_table", "sweep_cycle_statistics"]

# The per-lane arrays of the window's cycle statistics in a sweep's result (``SweepResult.cycles``):
# CycleAccumulator.finish's names with the prefix "cycle_".
_NAMES = (
    "jumps", "slips",
    *(f"{name}_{part}" for name in SPREADS for part in ("mean", "min", "max", "n")),
    "v_stick_min", "v_stick_max", "v_slip_min", "v_slip_max", "stick_fraction",
    "first_slip", "interval_sum", "slip_times", "deviation", "slip_state",
)  # fmt: skip
CYCLE_KEYS: tuple[str, ...] = tuple(f"cycle_{name}" for name in _NAMES)
# Host bytes of a lane's cycle statistics: the scalars, the kept stick → slip times and the deviations.
CYCLE_BYTES = 8 * (len(_NAMES) - 3 + KEPT_SLIPS + MAX_REPEAT_EVENTS + 4)


def cycle_arrays(cycles: dict) -> dict:
    """CycleAccumulator.finish's arrays under their :data:`CYCLE_KEYS` names."""
    return {f"cycle_{name}": cycles[name] for name in _NAMES}


def repeat_table(cycles: dict[str, np.ndarray], rtol: float) -> dict[str, np.ndarray]:
    """The repeat of the stick → slip events in every lane's window, as
    :func:`peeljax.cycles.repeat_pattern` finds it on those events (k ≤ MAX_REPEAT_EVENTS).

    With n events, the n − 1 intervals d and the largest deviations max_j |d_{j+k} − d_j| the
    loop kept: the smallest k ≤ (n − 1)/2 whose deviation is ≤ rtol·mean(d) (n ≥ 3 and
    mean(d) > 0); its period (τ_{r·k} − τ_0)/r with r = ⌊(n − 1)/k⌋ full repeats.

    Returns ``period``, ``events`` (0: none), ``repeats``, ``spread`` (NaN / 0 where none), per lane.
    """
    n = np.asarray(cycles["cycle_slips"], np.int64)
    intervals = n - 1
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.asarray(cycles["cycle_interval_sum"], float) / np.maximum(intervals, 1)
    deviation = np.asarray(cycles["cycle_deviation"], float)
    k = np.arange(1, MAX_REPEAT_EVENTS + 1)
    usable = (intervals >= 2) & (scale > 0)
    match = usable[:, None] & (k[None, :] <= (intervals // 2)[:, None]) & (deviation <= (rtol * scale)[:, None])
    found = match.any(axis=1)
    events = np.where(found, np.argmax(match, axis=1) + 1, 0)
    lanes = np.arange(n.size)
    repeats = np.where(found, intervals // np.maximum(events, 1), 0)
    # τ_{r·k} among the kept times: the kept ones are τ_{n − kept} … τ_{n − 1}
    kept = np.minimum(n, KEPT_SLIPS)
    position = np.clip(repeats * events - (n - kept), 0, KEPT_SLIPS - 1)
    times = np.asarray(cycles["cycle_slip_times"], float)
    with np.errstate(invalid="ignore", divide="ignore"):
        period = (times[lanes, position] - np.asarray(cycles["cycle_first_slip"], float)) / np.maximum(repeats, 1)
    spread = deviation[lanes, np.maximum(events - 1, 0)]
    return {
        "period": np.where(found, period, np.nan),
        "events": events.astype(np.int64),
        "repeats": repeats.astype(np.int64),
        "spread": np.where(found, spread, np.nan),
    }


def kept_slip_times(cycles: dict, index: int) -> np.ndarray:
    """The last (at most KEPT_SLIPS) stick → slip times in lane ``index``'s window, in time order."""
    times = np.asarray(cycles["cycle_slip_times"][index], float)
    return times[: min(int(cycles["cycle_slips"][index]), KEPT_SLIPS)]


def lane_cycle_statistics(
    cycles: dict, index: int, transient: float, t_end: float, rtol: float = 1e-3
) -> CycleStatistics:
    """Lane ``index``'s :class:`~peeljax.cycles.CycleStatistics` over its window
    [``transient``, ``t_end``] from the loop's sums (``cycles``: ``SweepResult.cycles``).

    Everything but ``too_few`` is what :func:`peeljax.cycle_statistics` gives for the whole
    record (the repeat for k ≤ MAX_REPEAT_EVENTS); ``too_few`` is
    :func:`peeljax.cycles.repeat_outlook` of the last KEPT_SLIPS stick → slip times.
    """

    def value(name):
        return np.asarray(cycles[f"cycle_{name}"][index]).item()

    def spread(name):
        return Spread(value(f"{name}_mean"), value(f"{name}_min"), value(f"{name}_max"), int(value(f"{name}_n")))

    one = {key: np.asarray(cycles[key][index])[None] for key in ("cycle_slips", "cycle_interval_sum",
                                                                  "cycle_deviation", "cycle_slip_times", "cycle_first_slip")}  # fmt: skip
    table = repeat_table(one, rtol)
    repeat = None
    if table["events"][0] > 0:
        repeat = RepeatPattern(
            period=float(table["period"][0]), events=int(table["events"][0]), repeats=int(table["repeats"][0]),
            spread=float(table["spread"][0]),
        )  # fmt: skip
    too_few = None
    if repeat is None:
        times = kept_slip_times(cycles, index)
        too_few = repeat_outlook(times, rtol=rtol, t_end=t_end) if times.size else None
    return CycleStatistics(
        transient=float(transient),
        t_end=float(t_end),
        jumps=int(value("jumps")),
        slips=int(value("slips")),
        stick_duration=spread("stick_duration"),
        slip_duration=spread("slip_duration"),
        slip_interval=spread("slip_interval"),
        force_drop=spread("force_drop"),
        G_slip=spread("G_slip"),
        G_stick=spread("G_stick"),
        v_stick=(value("v_stick_min"), value("v_stick_max")),
        v_slip=(value("v_slip_min"), value("v_slip_max")),
        stick_fraction=value("stick_fraction"),
        repeat=repeat,
        too_few=too_few,
    )


def kept_window_start(jumps: dict, index: int) -> float:
    """The earliest time from which lane ``index``'s kept jumps are all its jumps: 0 when it
    kept every jump, else the time of its oldest kept jump."""
    count = int(jumps["jump_count"][index])
    kept = min(count, int(np.shape(jumps["jump_t"])[-1]))
    return 0.0 if count <= kept else float(jumps["jump_t"][index, 0])


def sweep_cycle_statistics(result, index: int, transient: float | None = None, **kwargs) -> CycleStatistics:
    """:meth:`peeljax.SweepResult.cycle_statistics`: lane ``index`` over [transient, t_end].

    The sweep's window (``transient`` None or its start; t_end = min(its end, t_stop)): from
    the loop's sums (:func:`lane_cycle_statistics`). Another ``transient``: from the lane's kept
    jumps with :func:`peeljax.cycle_statistics` up to t_stop, where they hold every jump after
    it; else a ValueError naming what the lane kept.
    """
    if result.jumps is None:
        raise ValueError("this sweep located no folds (fold='stop' or dt given): it has no jump records")
    t_final = float(result.settings["t_final"])
    w0, w1 = (float(w) * t_final for w in result.settings["window"])
    t_stop = float(result.t_stop[index])
    cycles = getattr(result, "cycles", None)
    if cycles is not None and (transient is None or float(transient) == w0):
        return lane_cycle_statistics(cycles, index, w0, min(w1, t_stop), **kwargs)
    transient = w0 if transient is None else float(transient)
    oldest = kept_window_start(result.jumps, index)
    if transient < oldest:
        raise ValueError(
            f"lane {index} kept its last {int(np.shape(result.jumps['jump_t'])[-1])} jumps only (max_jumps), from "
            f"t = {oldest:.6g} s, not all those after transient = {transient:.6g} s: give transient >= {oldest:.6g}, "
            "None (the sweep's window, summarized in the loop), or sweep with a larger max_jumps"
        )
    lane = {key: result.jumps[key][index] for key in result.jumps}
    return cycle_statistics(lane, t_stop, transient=transient, **kwargs)
