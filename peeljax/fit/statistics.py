"""Stick-slip statistics of a simulated run, differentiable: what a stick-slip table is fitted to.

A run carried through the folds (``fold="jump"``) records every jump of v
(:class:`~peeljax.JumpRecord`); its times and the tension F = (k/l)·u at each jump carry
derivatives (the implicit function theorem on the fold event, :mod:`peeljax.integrators.events`).
Over the window [t_start, t_end] (after a transient), with the same definitions as
:func:`peeljax.fit.record_statistics` applies to a measured force record:

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

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ..solution import JumpRecord
from .stick_slip_table import STATISTICS

__all__ = ["STATISTICS", "jump_statistics", "window_scatter"]


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
