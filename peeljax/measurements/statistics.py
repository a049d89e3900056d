"""The stick-slip statistics, measured and modelled side by side: what a table holds and a fit compares.

:data:`STATISTICS` names them (``F_mean``, ``F_slip``, ``F_stick``, ``period``,
``slip_duration``); each is computed here from both sides with one set of definitions.

**A measured force record** F(t), a sawtooth: plain NumPy on the host, in float64:
:func:`record_statistics` for one record, :func:`record_cycles` for the per-cycle values that
:meth:`StickSlipTable.from_force_records <peeljax.measurements.StickSlipTable.from_force_records>` pools
over the records at one V. The slips are detected as force drops with hysteresis (see
:func:`record_statistics` for the definitions and the default threshold).

**A simulated run**, differentiably (:func:`jump_statistics`, what a stick-slip table is fitted
to by the window rows). A run carried through the folds (``fold="jump"``) records every jump of v
(:class:`~peeljax.JumpRecord`); its times and the tension F = (k/l)·u at each jump carry
derivatives (the implicit function theorem on the fold event, :mod:`peeljax.integrators.events`).
Over the window [t_start, t_end] (after a transient), with the same definitions as
:func:`peeljax.measurements.record_statistics` applies to a measured force record:

* ``F_slip``: the mean of F at the stick → slip jumps (F's maxima: during a stick F rises,
  during a slip it falls);
* ``F_stick``: the mean of F at the slip → stick jumps (F's minima);
* ``period``: the mean time between consecutive stick → slip jumps,
  (t_last − t_first)/(n − 1) over the n in the window;
* ``slip_duration``: the mean time from a stick → slip jump to the next slip → stick jump,
  both in the window;
* ``F_mean``: the time average of F over whole cycles, from the first to the last stick → slip
  jump in the window (over the whole window where there are fewer than two), by the trapezoid
  rule on F at ``n_samples`` equally spaced times of the dense output (its cumulative integral
  interpolated at the two jump times, so F_mean moves continuously with them). A mean over
  the fixed window would follow the phase of its partial cycle, which drifts with every
  coefficient (``docs/fitting.md``).

**Cycle-to-cycle scatter** (:func:`window_scatter`): the model's slips come in bursts of
unequal size, so a window statistic depends on which slips fall in the window: it jumps where
a slip crosses the window's edge, by about s/n — s the sample standard deviation of the
per-cycle values (F at each stick → slip / slip → stick jump, each time between consecutive
stick → slip jumps, each slip's duration; 0 for ``F_mean``, a mean over whole cycles), n their
number: one cycle more or less in a mean of n. That is what a table fit adds to the table's σ
(:mod:`peeljax.fit.table`). Not s/√n: the cycles are not independent draws but a
deterministic sequence, of which the window mean differs from the long-run one by its edges.

**Tapered statistics** (``taper`` > 0): every per-slip value weighted by w(t), 0 at the window's
edges and rising as ½(1 − cos) over the first and last ``taper`` of its length — F_slip, F_stick
at their jump times, each gap between consecutive stick → slip jumps and each slip duration at
its midpoint, F_mean the w-weighted time average of F. A slip crossing an edge then enters with
weight 0, so the statistics are continuous in the coefficients (with taper 0 they jump there).

A statistic is *available* when the window holds what it needs (two stick → slip jumps for
``period``, one slip for ``slip_duration``, …); a steady run (no fold of φ at V, or a stable
steady state) has only ``F_mean``. The number of jumps in the window is held fixed in the
derivative (it changes only where an event crosses the window's edge).
"""

from __future__ import annotations

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ..cycles import STATISTICS
from ..solution import JumpRecord

__all__ = [
    "MIN_DROP_NOISE",
    "MIN_DROP_RANGE",
    "STATISTICS",
    "jump_statistics",
    "noise_level",
    "record_cycles",
    "record_statistics",
    "sample_std",
    "window_scatter",
]


MIN_DROP_NOISE = 10.0  # default min_drop: this many times the estimated noise …
MIN_DROP_RANGE = 0.01  # … and at least this fraction of the record's peak-to-peak range


def noise_level(F) -> float:
    """The white-noise level σ of a sampled signal: the median absolute deviation of its second
    differences × 1.4826/√6 (a second difference of white noise has variance 6σ²; the median is
    robust: the few samples of each slip, or a smooth signal's curvature, do not move it)."""
    F = np.asarray(F, float)
    if F.size < 3:
        return 0.0
    d2 = np.diff(F, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


def _extrema(F: np.ndarray, drop: float) -> tuple[np.ndarray, np.ndarray]:
    """Hysteresis extrema: indices of the maxima (each followed by a fall of more than ``drop``
    below it) and of the minima (each followed by a rise of more than ``drop``), alternating.
    The first extremum of the window is left out: the window may have cut its rise or fall.

    These are the samples whose topographic prominence exceeds ``drop`` (``find_peaks`` on F
    and −F: both the rise before and the fall after a maximum exceed ``drop``, which also leaves
    out the first extremum, whose rise the window cut). Of a flat top (or bottom) the first
    sample is taken; of equal maxima with no minimum deeper than ``drop`` between them (a
    quantized record), the first.
    """
    from scipy.signal import find_peaks  # here, not at the top: scipy.signal takes seconds to import

    bound = np.nextafter(drop, np.inf)  # find_peaks keeps prominence >= bound; a swing must exceed drop
    peaks = find_peaks(F, prominence=bound, plateau_size=1)[1]["left_edges"]
    troughs = find_peaks(-F, prominence=bound, plateau_size=1)[1]["left_edges"]
    index = np.concatenate([peaks, troughs])
    is_peak = np.concatenate([np.ones(peaks.size, bool), np.zeros(troughs.size, bool)])
    order = np.argsort(index, kind="stable")
    index, is_peak = index[order], is_peak[order]
    first = np.ones(index.size, bool)  # equal extrema of one kind in a row: one slip, the first
    first[1:] = is_peak[1:] != is_peak[:-1]
    return index[first & is_peak].astype(int), index[first & ~is_peak].astype(int)


def _integral(F: np.ndarray, t: np.ndarray) -> float:
    """∫ F dt by the trapezoid rule."""
    return float(np.sum(0.5 * (F[1:] + F[:-1]) * np.diff(t)))


def sample_std(x: np.ndarray) -> float:
    """The sample standard deviation (ddof = 1); NaN for fewer than 2 values."""
    return float(np.std(x, ddof=1)) if x.size >= 2 else math.nan


def smoothed(t: np.ndarray, F: np.ndarray, smooth: float) -> tuple[np.ndarray, int]:
    """F averaged over a moving window of ``smooth`` seconds (w = round(smooth/Δt) samples, the
    ends held), and w; F itself where w < 2."""
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    w = int(round(smooth / dt)) if smooth > 0 and dt > 0 else 1
    if w < 2:
        return F, 1
    from scipy.ndimage import uniform_filter1d

    return uniform_filter1d(F, w, mode="nearest"), w


def record_cycles(t, F, *, transient: float = 0.0, min_drop: float | None = None, smooth: float = 0.0,
                  noise_factor: float = MIN_DROP_NOISE) -> dict:  # fmt: skip
    """The slips and cycles of one record (the definitions: :func:`record_statistics`): a dict
    with the time average ``F_mean`` and ``duration`` of the window, ``cycles`` (name → the
    per-cycle values of each statistic), ``t_slip``, ``t_stick``, ``min_drop``, ``noise`` and
    ``window``."""
    t = np.asarray(t, dtype=np.float64)
    F = np.asarray(F, dtype=np.float64)
    if t.ndim != 1 or t.shape != F.shape:
        raise ValueError(f"t and F must be 1-D arrays of one length, got shapes {t.shape} and {F.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(F))):
        raise ValueError("t and F must be finite")
    if np.any(np.diff(t) <= 0):
        raise ValueError("t must increase strictly")
    transient = float(transient)
    if not (math.isfinite(transient) and transient >= 0):
        raise ValueError(f"transient must be a finite number >= 0, got {transient!r}")
    window = t >= transient
    if window.sum() < 2:
        raise ValueError(f"fewer than 2 samples after the transient {transient:g} s (the record ends at {t[-1]:g} s)")
    t, F = t[window], F[window]
    noise = noise_level(F)
    if not (math.isfinite(smooth) and smooth >= 0):
        raise ValueError(f"smooth must be a number >= 0 [s], got {smooth!r}")
    F, w = smoothed(t, F, smooth)
    if min_drop is None:
        drop = max(noise_factor * noise / math.sqrt(w), MIN_DROP_RANGE * float(np.ptp(F)))
    else:
        drop = float(min_drop)
        if not (math.isfinite(drop) and drop > 0):
            raise ValueError(f"min_drop must be > 0 [N], got {min_drop!r}")
    peaks, troughs = _extrema(F, drop) if drop > 0 else (np.zeros(0, int), np.zeros(0, int))
    # a slip: a maximum and the minimum that follows it (they alternate: before the next maximum)
    nxt = np.searchsorted(troughs, peaks)
    has = nxt < troughs.size
    slip_duration = t[troughs[nxt[has]]] - t[peaks[has]]
    cycle_means = np.asarray(
        [_integral(F[a : b + 1], t[a : b + 1]) / (t[b] - t[a]) for a, b in itertools.pairwise(peaks)]
    )
    duration = float(t[-1] - t[0])
    return {
        "F_mean": float(_integral(F, t) / duration),
        "duration": duration,
        "cycles": {
            "F_mean": cycle_means,
            "F_slip": F[peaks],
            "F_stick": F[troughs],
            "period": np.diff(t[peaks]),
            "slip_duration": slip_duration,
        },
        "t_slip": t[peaks],
        "t_stick": t[troughs],
        "min_drop": drop,
        "noise": noise,
        "window": (float(t[0]), float(t[-1])),
    }


def record_statistics(t, F, *, transient: float = 0.0, min_drop: float | None = None, smooth: float = 0.0,
                      noise_factor: float = MIN_DROP_NOISE) -> dict:  # fmt: skip
    """The stick-slip statistics of a measured force record F(t) (a sawtooth), after ``transient``.

    **Slips.** A slip is a fall of F by more than ``min_drop`` [N] below its running maximum;
    the next one counts only after F has risen by more than ``min_drop`` above its running
    minimum (hysteresis: noise smaller than ``min_drop`` neither makes nor splits a slip). The
    first extremum found in the window is left out (the window may cut it). These are the
    maxima and minima of prominence above ``min_drop`` (``scipy.signal.find_peaks``). Default
    ``min_drop``: the larger of 10 times the record's white-noise level (estimated from the
    median absolute deviation of its second differences, which assumes samples dense enough
    that F changes smoothly between slips) and 1 % of its peak-to-peak range. Not a fixed
    fraction of the range: the model's slips come in bursts of unequal size (V = 1.1 m/s:
    drops of 17–28 N and re-stick rises of 6–20 N within a range of 118 N; V = 3 m/s: drops
    down to 2.3 N, rises to 0.4 N in 220 N), so a quarter of the range would see none of them.
    Slips smaller than ``min_drop`` — or whose re-stick rise is — are merged with their
    neighbours: check ``slips`` against the record, and pass ``min_drop`` where it misjudges.

    **Per slip**: ``F_slip``, the maximum of F before the fall (the stick → slip instant: in
    the model F is continuous and largest there); ``F_stick``, the minimum after it (slip →
    stick); ``slip_duration``, from that maximum to that minimum; ``period``, between
    consecutive maxima. ``F_mean`` is the time average of F over the window (trapezoid rule),
    its ``F_mean_std`` the spread of the time averages over the cycles (maximum to maximum).
    Each statistic is given as its mean over the slips in the window and ``<name>_std``, their
    sample standard deviation (NaN for fewer than 2 values). The times are those of the
    samples: within a sample spacing of the true instants.

    **Noisy records** (``smooth`` > 0 [s]): the slips are found on, and every statistic taken
    from, F averaged over a moving window of ``smooth`` seconds, whose noise is the record's /√w
    (w samples in the window); the default ``min_drop`` is then ``noise_factor`` times that.
    Measured on records at V = 1.1 and 1.6 m/s with white noise of 0.5 % of F (``docs/fitting.md``):
    at 10 kHz, 0.6 ms and a factor 6 find 108 and 198 of their 107 and 204 slips (no smoothing and
    the default factor 10: 38 and 28). The statistics are then those of the smoothed record: a
    model compared with it has to be smoothed alike (:mod:`.instrument` does).

    Returns:
        a dict with ``F_mean``, ``F_mean_std`` and, where at least one value was found,
        ``F_slip``, ``F_stick``, ``period``, ``slip_duration`` with their ``_std``; and
        ``slips`` (the number of maxima found), ``t_slip``/``t_stick`` (the times of the
        maxima/minima), ``min_drop`` (the threshold used), ``noise`` (the estimated noise
        level) and ``window`` (first and last time used). A record without slips (steady
        peeling) has only ``F_mean`` of the statistics.
    """
    r = record_cycles(t, F, transient=transient, min_drop=min_drop, smooth=smooth, noise_factor=noise_factor)
    out = {"F_mean": r["F_mean"], "F_mean_std": sample_std(r["cycles"]["F_mean"])}
    for name in ("F_slip", "F_stick", "period", "slip_duration"):
        values = r["cycles"][name]
        if values.size:
            out[name], out[f"{name}_std"] = float(np.mean(values)), sample_std(values)
    out.update(
        slips=int(r["t_slip"].size), t_slip=r["t_slip"], t_stick=r["t_stick"], min_drop=r["min_drop"],
        noise=r["noise"], window=r["window"],
    )  # fmt: skip
    return out


# ---------------------------------------------------------------------------- a simulated run
def _taper(t, t_start, t_end, taper: float):
    """w(t): 0 at the window's edges, rising as ½(1 − cos) over the first and last ``taper`` of
    its length, 1 between."""
    width = taper * (t_end - t_start)
    rise = jnp.clip((t - t_start) / width, 0.0, 1.0)
    fall = jnp.clip((t_end - t) / width, 0.0, 1.0)
    return (0.5 - 0.5 * jnp.cos(jnp.pi * rise)) * (0.5 - 0.5 * jnp.cos(jnp.pi * fall))


def _tapered(jumps: JumpRecord, F_samples, t_start, t_end, taper: float):
    """The statistics as weighted means, each slip (gap, re-stick, sample of F) weighted by
    :func:`_taper` at its time: a slip crossing the window's edge enters with weight 0, so the
    statistics are continuous in the coefficients (module docstring)."""
    slot = jnp.arange(jumps.max_jumps)
    inside = (slot < jumps.count) & (jumps.t >= t_start) & (jumps.t <= t_end)
    t = jnp.where(inside, jumps.t, 0.5 * (t_start + t_end))
    F = jnp.where(inside, jumps.F, 0.0)
    up = inside & jumps.up
    down = inside & ~jumps.up
    w = _taper(t, t_start, t_end, taper)

    def weighted(mask, values, weights):
        total = jnp.sum(jnp.where(mask, weights, 0.0))
        return jnp.sum(jnp.where(mask, weights * values, 0.0)) / jnp.where(total > 0, total, 1.0)

    t_up = jnp.sort(jnp.where(up, t, jnp.inf))
    gap = jnp.isfinite(t_up[1:])
    t_up = jnp.where(jnp.isfinite(t_up), t_up, 0.0)
    gaps = t_up[1:] - t_up[:-1]
    pair = up[:-1] & down[1:]
    t_samples = jnp.linspace(t_start, t_end, F_samples.shape[0])
    ws = _taper(t_samples, t_start, t_end, taper)
    F_mean = jnp.sum(ws * F_samples) / jnp.sum(ws)
    return jnp.stack([
        F_mean,
        weighted(up, F, w),
        weighted(down, F, w),
        weighted(gap, gaps, _taper(0.5 * (t_up[1:] + t_up[:-1]), t_start, t_end, taper)),
        weighted(pair, t[1:] - t[:-1], _taper(0.5 * (t[1:] + t[:-1]), t_start, t_end, taper)),
    ])  # fmt: skip


def jump_statistics(
    jumps: JumpRecord, F_samples: Float[Array, " n"], t_start, t_end, taper: float = 0.0
) -> tuple[Float[Array, " 5"], Bool[Array, " 5"]]:
    """(values, available) of :data:`STATISTICS` (``F_mean``, ``F_slip``, ``F_stick``,
    ``period``, ``slip_duration``) of one run over [t_start, t_end] (module docstring).

    ``F_samples``: F at equally spaced times from t_start to t_end (``F_mean`` integrates them).
    Unavailable statistics are 0 (finite, with zero derivatives). ``taper`` > 0: the weighted
    means of the module docstring (each edge's ramp that fraction of the window).
    """
    slot = jnp.arange(jumps.max_jumps)
    t = jnp.where(slot < jumps.count, jumps.t, jnp.inf)
    inside = (slot < jumps.count) & (t >= t_start) & (t <= t_end)
    t_safe = jnp.where(inside, t, 0.0)
    F = jnp.where(inside, jumps.F, 0.0)
    up = inside & jumps.up
    down = inside & ~jumps.up

    def mean_over(mask, values):
        n = jnp.sum(mask)
        return jnp.sum(jnp.where(mask, values, 0.0)) / jnp.maximum(n, 1), n

    F_slip, n_up = mean_over(up, F)
    F_stick, n_down = mean_over(down, F)
    t_first = jnp.min(jnp.where(up, t_safe, jnp.inf))
    t_last = jnp.max(jnp.where(up, t_safe, -jnp.inf))
    period = jnp.where(n_up >= 2, (jnp.where(n_up >= 2, t_last - t_first, 0.0)) / jnp.maximum(n_up - 1, 1), 0.0)
    # a slip: a stick → slip jump followed by a slip → stick jump, both inside
    pair = up[:-1] & down[1:]
    slip_duration, n_slips = mean_over(pair, t_safe[1:] - t_safe[:-1])
    # F_mean over whole cycles, [first slip, last slip] in the window, where there are two:
    # the mean over a fixed window would follow the phase of its partial cycle, which drifts.
    t_samples = jnp.linspace(t_start, t_end, F_samples.shape[0])
    cumulative = jnp.concatenate([jnp.zeros(1), jnp.cumsum(0.5 * (F_samples[1:] + F_samples[:-1]) * jnp.diff(t_samples))])
    cycles = n_up >= 2
    a = jnp.where(cycles, t_first, t_start)
    b = jnp.where(cycles, t_last, t_end)
    F_mean = (jnp.interp(b, t_samples, cumulative) - jnp.interp(a, t_samples, cumulative)) / jnp.where(b > a, b - a, 1.0)
    values = jnp.stack([F_mean, F_slip, F_stick, period, slip_duration])
    if taper > 0:
        values = _tapered(jumps, F_samples, t_start, t_end, taper)
    available = jnp.stack([jnp.asarray(True), n_up >= 1, n_down >= 1, n_up >= 2, n_slips >= 1])
    return jnp.where(available, values, 0.0), available


def window_scatter(jumps: JumpRecord, t_start, t_end) -> Float[Array, " 5"]:
    """s/n over the window's cycles for each of :data:`STATISTICS` (module docstring; 0 where
    fewer than two values): how much the window statistic moves with one cycle more or less in
    the window. Not differentiated (a weight, as the table's σ)."""
    jumps = jax.tree_util.tree_map(jax.lax.stop_gradient, jumps)
    slot = jnp.arange(jumps.max_jumps)
    inside = (slot < jumps.count) & (jumps.t >= t_start) & (jumps.t <= t_end)
    up = inside & jumps.up
    down = inside & ~jumps.up

    def edge_error(mask, values):
        n = jnp.sum(mask)
        mean = jnp.sum(jnp.where(mask, values, 0.0)) / jnp.maximum(n, 1)
        var = jnp.sum(jnp.where(mask, (values - mean) ** 2, 0.0)) / jnp.maximum(n - 1, 1)
        return jnp.where(n >= 2, jnp.sqrt(var) / jnp.maximum(n, 1), 0.0)

    # the stick → slip times in order (jumps are recorded in time order), then their gaps
    t_up = jnp.sort(jnp.where(up, jumps.t, jnp.inf))
    gaps = jnp.where(jnp.isfinite(t_up[1:]), t_up[1:] - jnp.where(jnp.isfinite(t_up[:-1]), t_up[:-1], 0.0), 0.0)
    pair = up[:-1] & down[1:]
    return jnp.stack([
        jnp.asarray(0.0),
        edge_error(up, jumps.F),
        edge_error(down, jumps.F),
        edge_error(jnp.isfinite(t_up[1:]), gaps),
        edge_error(pair, jnp.where(pair, jumps.t[1:] - jumps.t[:-1], 0.0)),
    ])  # fmt: skip
