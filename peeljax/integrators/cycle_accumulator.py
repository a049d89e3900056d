"""The cycle statistics of a window, accumulated at each jump inside the loop.

:func:`peeljax.cycle_statistics` reduces a run's whole jump record to its stick-slip cycle
statistics on the host. A sweep lane keeps no whole record (its
:class:`~peeljax.JumpRecord` is a short ring buffer), so the same statistics are accumulated
here, jump by jump, over the window W = [w0, w1], in O(1) memory per lane: the jump record
calls :meth:`CycleAccumulator.add` at every jump and :meth:`CycleAccumulator.finish` turns the
sums into the statistics once the run's end t_end is known (the window then ends at
min(w1, t_end)).

With the jumps in W in time order, (t_i, up_i, v⁻_i, v⁺_i, G_i), the definitions are those
of :mod:`peeljax.cycles`, term by term:

* jumps, slips: how many, and how many with up_i (stick → slip);
* stick duration t_{i+1} − t_i for each pair (down, up), slip duration for each (up, down),
  force drop G_i − G_{i+1} for each (up, down), slip interval between consecutive stick → slip
  times; G_slip = G at up jumps, G_stick at down ones: each as a :class:`~peeljax.cycles.Spread`
  (sum → mean, min, max, n);
* v_stick = (min v⁺ of down jumps, max v⁻ of up ones), v_slip = (min v⁻ of down, max v⁺ of up);
* stick fraction: the time on the stick branch over |W|, the branch before the first jump in W
  being stuck iff that jump is up (none in W: the branch the last jump before W landed on);
* the repeat (:func:`peeljax.cycles.repeat_pattern`) of the stick → slip times τ_0 … τ_{n−1}
  in W, with the intervals d_j = τ_{j+1} − τ_j: for every k ≤ :data:`MAX_REPEAT_EVENTS`, the
  largest deviation max_j |d_{j+k} − d_j| (each new interval compared with the k before it),
  with Σ d_j, τ_0 and the last :data:`KEPT_SLIPS` stick → slip times. The host then takes the
  smallest k with 2k + 1 ≤ n whose deviation is within rtol·mean(d), and its period
  (τ_{r·k} − τ_0)/r, r = ⌊(n − 1)/k⌋, whose τ_{r·k} is among the times kept (r·k ≥ n − k).
  A repeat of more than :data:`MAX_REPEAT_EVENTS` events per period is not searched.

Each statistic is computed with the same arithmetic as the host's (differences of the same
times and forces); only the sums behind the means are added in another order (equal to
rounding, ``tests/test_sweep_cycles.py``).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

__all__ = ["KEPT_SLIPS", "MAX_REPEAT_EVENTS", "SPREADS", "CycleAccumulator"]

MAX_REPEAT_EVENTS = 32  # the longest repeat searched: k ≤ 32 stick → slip events per period
KEPT_SLIPS = 2 * MAX_REPEAT_EVENTS + 1  # the stick → slip times kept: two full repeats of the longest k
# The spreads, in the order of the accumulator's rows.
SPREADS: tuple[str, ...] = ("stick_duration", "slip_duration", "slip_interval", "force_drop", "G_slip", "G_stick")
_STICK, _SLIP, _INTERVAL, _DROP, _G_SLIP, _G_STICK = range(len(SPREADS))


class CycleAccumulator(eqx.Module):
    """Running cycle statistics over the window [w0, w1] (module docstring); a pytree carried
    by the loop inside :class:`~peeljax.JumpRecord` (``statistics``). :meth:`over` makes an
    empty one."""

    w0: Float[Array, ""]
    w1: Float[Array, ""]
    jumps: Int[Array, ""]
    slips: Int[Array, ""]
    spread_sum: Float[Array, " 6"]
    spread_min: Float[Array, " 6"]
    spread_max: Float[Array, " 6"]
    spread_n: Int[Array, " 6"]
    v_range: Float[Array, " 4"]  # min v⁺ down, max v⁻ up, min v⁻ down, max v⁺ up
    last_t: Float[Array, ""]  # the latest jump in the window
    last_up: Bool[Array, ""]
    last_G: Float[Array, ""]
    stick_time: Float[Array, ""]  # on the stick branch from w0 to the latest jump in the window
    before: Int[Array, ""]  # the last jump before the window: −1 none, 0 down, 1 up
    first_slip: Float[Array, ""]  # τ_0
    interval_sum: Float[Array, ""]  # Σ d_j
    slip_times: Float[Array, " R"]  # the last KEPT_SLIPS stick → slip times, slot j mod KEPT_SLIPS
    deviation: Float[Array, " K"]  # max_j |d_{j+k} − d_j|, k = 1 … MAX_REPEAT_EVENTS
    slip_state: Float[Array, " 4"]  # the state (α, ω, u, v) at the latest stick → slip fold in the window

    @classmethod
    def over(cls, w0, w1) -> CycleAccumulator:
        """Nothing accumulated yet, over the window [w0, w1] [s]."""
        n = len(SPREADS)
        return cls(
            w0=jnp.asarray(w0, float),
            w1=jnp.asarray(w1, float),
            jumps=jnp.asarray(0, jnp.int32),
            slips=jnp.asarray(0, jnp.int32),
            spread_sum=jnp.zeros(n),
            spread_min=jnp.full(n, jnp.inf),
            spread_max=jnp.full(n, -jnp.inf),
            spread_n=jnp.zeros(n, jnp.int32),
            v_range=jnp.array([jnp.inf, -jnp.inf, jnp.inf, -jnp.inf]),
            last_t=jnp.asarray(jnp.nan),
            last_up=jnp.asarray(False),
            last_G=jnp.asarray(jnp.nan),
            stick_time=jnp.asarray(0.0),
            before=jnp.asarray(-1, jnp.int32),
            first_slip=jnp.asarray(jnp.nan),
            interval_sum=jnp.asarray(0.0),
            slip_times=jnp.full(KEPT_SLIPS, jnp.nan),
            deviation=jnp.full(MAX_REPEAT_EVENTS, -jnp.inf),
            slip_state=jnp.full(4, jnp.nan),
        )

    def add(self, do: Bool[Array, ""], t, up, v_before, v_after, G, y=None) -> CycleAccumulator:
        """The statistics with the jump (t, up, v⁻, v⁺, G) added where ``do``; ``y``: the state at
        the fold (before the jump), kept at stick → slip ones (``slip_state``)."""
        t = jnp.asarray(t, float)
        up = jnp.asarray(up, bool)
        down = ~up
        inside = do & (t >= self.w0) & (t <= self.w1)
        first = self.jumps == 0
        pair = inside & ~first  # the previous jump in the window and this one
        gap = t - self.last_t
        slip = inside & up
        has_slip = self.slips > 0
        interval = t - self.slip_times[(self.slips - 1) % KEPT_SLIPS]
        values = jnp.stack([gap, gap, interval, self.last_G - G, G, G])
        use = jnp.stack([
            pair & ~self.last_up & up,  # stick: (down, up)
            pair & self.last_up & down,  # slip: (up, down)
            slip & has_slip,
            pair & self.last_up & down,
            slip,
            inside & down,
        ])  # fmt: skip
        values = jnp.where(use, values, 0.0)
        v_new = jnp.stack([v_after, v_before, v_before, v_after])
        v_use = inside & jnp.stack([down, up, down, up])
        # The piece of the window that ends at this jump: on the stick branch iff the branch before
        # the first jump is stuck (that jump is up), else iff the previous jump landed on it (down).
        on_stick = jnp.where(first, up, ~self.last_up)
        start = jnp.where(first, self.w0, self.last_t)

        # The repeat: the new interval d_new against the k intervals before it, k = 1 … K.
        k = jnp.arange(1, MAX_REPEAT_EVENTS + 1)
        n_intervals = self.slips - 1  # before this one
        newer = self.slip_times[(self.slips - k) % KEPT_SLIPS]
        older = self.slip_times[(self.slips - k - 1) % KEPT_SLIPS]
        compared = slip & (n_intervals - k >= 0)
        deviation = jnp.where(
            compared, jnp.maximum(self.deviation, jnp.abs(interval - (newer - older))), self.deviation
        )
        return CycleAccumulator(
            w0=self.w0,
            w1=self.w1,
            jumps=self.jumps + inside,
            slips=self.slips + slip,
            spread_sum=self.spread_sum + values,
            spread_min=jnp.where(use, jnp.minimum(self.spread_min, values), self.spread_min),
            spread_max=jnp.where(use, jnp.maximum(self.spread_max, values), self.spread_max),
            spread_n=self.spread_n + use,
            v_range=jnp.where(
                v_use,
                jnp.stack(
                    [
                        jnp.minimum(self.v_range[0], v_new[0]),
                        jnp.maximum(self.v_range[1], v_new[1]),
                        jnp.minimum(self.v_range[2], v_new[2]),
                        jnp.maximum(self.v_range[3], v_new[3]),
                    ]
                ),
                self.v_range,
            ),  # fmt: skip
            last_t=jnp.where(inside, t, self.last_t),
            last_up=jnp.where(inside, up, self.last_up),
            last_G=jnp.where(inside, G, self.last_G),
            stick_time=jnp.where(inside & on_stick, self.stick_time + (t - start), self.stick_time),
            before=jnp.where(do & (t < self.w0), up.astype(jnp.int32), self.before),
            first_slip=jnp.where(slip & ~has_slip, t, self.first_slip),
            interval_sum=jnp.where(slip & has_slip, self.interval_sum + interval, self.interval_sum),
            slip_times=jnp.where(slip, self.slip_times.at[self.slips % KEPT_SLIPS].set(t), self.slip_times),
            deviation=deviation,
            slip_state=self.slip_state if y is None else jnp.where(slip, jnp.asarray(y, float), self.slip_state),
        )

    def finish(self, t_end) -> dict[str, Array]:
        """The statistics over [w0, min(w1, t_end)] (``t_end``: where the run ended), as arrays:
        ``jumps``, ``slips``, ``<spread>_mean|min|max|n`` for each of :data:`SPREADS`,
        ``v_stick_min|max``, ``v_slip_min|max``, ``stick_fraction`` (NaN: no jump at all, or an
        empty window), and for the repeat ``first_slip``, ``interval_sum``, ``slip_times`` (the
        last :data:`KEPT_SLIPS` in time order, NaN-padded) and ``deviation`` (per k; −inf where
        no pair was compared); ``slip_state``, the state at the window's last stick → slip fold
        (on the section of :mod:`peeljax.orbits`; NaN: none)."""
        end = jnp.minimum(self.w1, jnp.asarray(t_end, float))
        length = end - self.w0
        have = self.spread_n > 0
        nan = jnp.nan
        mean = self.spread_sum / jnp.where(have, self.spread_n, 1)
        out = {"jumps": self.jumps, "slips": self.slips}
        for i, name in enumerate(SPREADS):
            out[f"{name}_mean"] = jnp.where(have[i], mean[i], nan)
            out[f"{name}_min"] = jnp.where(have[i], self.spread_min[i], nan)
            out[f"{name}_max"] = jnp.where(have[i], self.spread_max[i], nan)
            out[f"{name}_n"] = self.spread_n[i]
        v = jnp.where(jnp.isfinite(self.v_range), self.v_range, nan)
        out.update(v_stick_min=v[0], v_stick_max=v[1], v_slip_min=v[2], v_slip_max=v[3])
        inside = self.jumps > 0
        # after the latest jump in the window: on the stick branch iff it landed there (down)
        stick = jnp.where(inside & ~self.last_up, self.stick_time + (end - self.last_t), self.stick_time)
        # no jump in the window: the whole of it on the branch the last jump before it landed on
        stick = jnp.where(inside, stick, jnp.where(self.before == 0, length, 0.0))
        known = (inside | (self.before >= 0)) & (length > 0)
        out["stick_fraction"] = jnp.where(known, stick / jnp.where(known, length, 1.0), nan)
        kept = jnp.minimum(self.slips, KEPT_SLIPS)
        slots = (self.slips - kept + jnp.arange(KEPT_SLIPS)) % KEPT_SLIPS
        out.update(
            first_slip=self.first_slip,
            interval_sum=self.interval_sum,
            slip_times=jnp.where(jnp.arange(KEPT_SLIPS) < kept, self.slip_times[slots], nan),
            deviation=self.deviation,
            slip_state=self.slip_state,
        )
        return out
