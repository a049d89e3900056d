"""The batched α-method run behind :func:`peeljax.sweep`: one compiled, ``vmap``ped scan.

Every trajectory (lane) integrates the homogenized ODE y' = ψ(y; τ) (eq. ``hv`` with
(``av``)–(``str``)) by the α-method of the section "Numerical Integration" on a uniform mesh
of N steps, exactly as :func:`peeljax.simulate` does (same :func:`alpha_start` /
:func:`alpha_advance`), but instead of returning every state it accumulates per-lane
summaries inside the scan:

* status and t_stop (the time of the last accepted state, as in :class:`peeljax.Solution`);
* over the window W = [w0·t_final, w1·t_final]: the count, mean and (population) standard
  deviation of v by Welford's update, its minimum and maximum, over the accepted states
  t_i ∈ W (i = 0 … N, the initial state included when w0 = 0);
* events: the number of stick-slip events in W, i.e. the upward crossings
  v_{i−1} < v̂ ≤ v_i of v̂(V), the peeling velocity at the maximum of φ(·, V) (the onset of
  slip, where ∂φ/∂v = 0 and J_t → τ·F̃·(…)·∂f/∂v, Lemma ``hi``), counted for each step whose
  end time t_i lies in W;
* the work done: Newton iterations, steps that needed the subdivision safeguard, the deepest
  subdivision level.

Saved states (optional) come from a nested scan: an outer scan over save points, an inner
one over ``save_every`` steps, so memory is O(N/save_every), never O(N).

v̂(V) is found per lane inside the compiled function: ∂φ/∂v (by ``jax.grad``) is sampled at
``_PEAK_GRID`` points log-spaced in v ∈ [1e-8, 1e2]·max(V, 1) … the first sign change from
+ to − brackets the maximum, refined by ``_PEAK_BISECTIONS`` bisection steps in log v (a
relative accuracy of ~1e-14). A φ with no maximum in that range gives v̂ = inf (no events).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..adhesion import COEFFICIENT_NAMES
from ..homogenized import HomogenizedODE
from ..integrators.alpha import AlphaMethod, alpha_advance, alpha_start, to_physical
from ..model import PeelingModel

__all__ = ["MODEL_PARAMETERS", "BatchSummary", "run_batch", "slip_velocity", "with_parameters"]

MODEL_PARAMETERS: tuple[str, ...] = ("R", "I", "k", "l", *COEFFICIENT_NAMES)
_PEAK_GRID = 96
_PEAK_BISECTIONS = 60
_PEAK_RANGE = (1e-8, 1e2)


class BatchSummary(eqx.Module):
    """Per-lane results of :func:`run_batch` (leading axis: the batch)."""

    status: Int[Array, " B"]
    t_stop: Float[Array, " B"]
    v_mean: Float[Array, " B"]
    v_std: Float[Array, " B"]
    v_min: Float[Array, " B"]
    v_max: Float[Array, " B"]
    v_final: Float[Array, " B"]
    window_count: Int[Array, " B"]
    events: Int[Array, " B"]
    v_slip: Float[Array, " B"]
    newton_iterations: Int[Array, " B"]
    subdivided_steps: Int[Array, " B"]
    max_subdivision_level: Int[Array, " B"]
    ys: Float[Array, "B S 4"] | None


def with_parameters(model: PeelingModel, params: dict[str, Array]) -> PeelingModel:
    """``model`` with the named parameters replaced (R, I, k, l or a coefficient of φ)."""
    for name, value in params.items():
        if name in ("R", "I", "k", "l"):
            model = eqx.tree_at(lambda m, name=name: getattr(m, name), model, jnp.asarray(value, float))
        else:
            model = eqx.tree_at(lambda m, name=name: getattr(m.adhesion, name), model, jnp.asarray(value, float))
    return model


def slip_velocity(model: PeelingModel, V: Float[Array, ""]) -> Float[Array, ""]:
    """v̂(V) = argmax of φ(·, V): the first maximum in v ∈ [1e-8, 1e2]·max(V, 1) (inf if none).

    ∂φ/∂v changes sign from + to − at v̂; sampled on a log grid, then bisected in log v.
    """
    scale = jnp.maximum(V, 1.0)
    log_v = jnp.linspace(jnp.log(_PEAK_RANGE[0]), jnp.log(_PEAK_RANGE[1]), _PEAK_GRID) + jnp.log(scale)

    def slope(log_v):
        return jax.grad(lambda v: model.phi(v, V))(jnp.exp(log_v))

    slopes = jax.vmap(slope)(log_v)
    falls = (slopes[:-1] > 0) & (slopes[1:] <= 0)
    found = jnp.any(falls)
    index = jnp.argmax(falls)
    lo, hi = log_v[index], log_v[index + 1]

    def bisect(_, bracket):
        lo, hi = bracket
        mid = 0.5 * (lo + hi)
        rising = slope(mid) > 0
        return jnp.where(rising, mid, lo), jnp.where(rising, hi, mid)

    lo, hi = jax.lax.fori_loop(0, _PEAK_BISECTIONS, bisect, (lo, hi))
    return jnp.where(found, jnp.exp(0.5 * (lo + hi)), jnp.inf)


class _Accumulator(eqx.Module):
    count: Array
    mean: Array
    m2: Array
    vmin: Array
    vmax: Array
    events: Array
    v_prev: Array
    t_last: Array
    newton: Array
    subdivided: Array
    level: Array

    def add(self, v, t, ok, in_window, v_slip):
        use = ok & in_window
        count = self.count + use.astype(self.count.dtype)
        delta = v - self.mean
        mean = jnp.where(use, self.mean + delta / jnp.maximum(count, 1), self.mean)
        m2 = jnp.where(use, self.m2 + delta * (v - mean), self.m2)
        crossed = use & (self.v_prev < v_slip) & (v >= v_slip)
        return eqx.tree_at(
            lambda a: (a.count, a.mean, a.m2, a.vmin, a.vmax, a.events, a.v_prev, a.t_last),
            self,
            (
                count,
                mean,
                m2,
                jnp.where(use, jnp.minimum(self.vmin, v), self.vmin),
                jnp.where(use, jnp.maximum(self.vmax, v), self.vmax),
                self.events + crossed.astype(self.events.dtype),
                jnp.where(ok, v, self.v_prev),
                jnp.where(ok, t, self.t_last),
            ),
        )


def _lane(
    model: PeelingModel,
    solver: AlphaMethod,
    V,
    tau,
    params: dict,
    t_final,
    window,
    n_steps: int,
    save_every: int | None,
    truncation: int | None,
):
    """One trajectory: the α-method scan with on-the-fly summaries (and saved states)."""
    model = with_parameters(model, params)
    ode = HomogenizedODE(model, V, tau, truncation)
    h = t_final / n_steps
    w0, w1 = window[0] * t_final, window[1] * t_final
    v_slip = slip_velocity(model, ode.V)
    y0 = model.initial_state(ode.V)
    ode_c, state = alpha_start(ode, solver, y0)
    start_ok = state.status == 0
    y_start = to_physical(solver, state.y)
    v0 = y_start[3]
    zero_i = jnp.asarray(0, jnp.int32)
    acc = _Accumulator(
        count=zero_i,
        mean=jnp.asarray(0.0),
        m2=jnp.asarray(0.0),
        vmin=jnp.asarray(jnp.inf),
        vmax=jnp.asarray(-jnp.inf),
        events=zero_i,
        v_prev=jnp.where(start_ok, v0, jnp.nan),
        t_last=jnp.asarray(0.0),
        newton=zero_i,
        subdivided=zero_i,
        level=zero_i,
    )
    # The initial state counts in the window like any accepted state (no crossing before it).
    acc = acc.add(v0, jnp.asarray(0.0), start_ok, (w0 <= 0.0) & (0.0 <= w1), jnp.inf)

    def step(carry, index):
        state, acc = carry
        state, info, ok = alpha_advance(ode_c, solver, state, h)
        t = h * (index + 1)
        v = to_physical(solver, state.y)[3]
        acc = acc.add(v, t, ok, (t >= w0 - 1e-9 * h) & (t <= w1 + 1e-9 * h), v_slip)
        acc = eqx.tree_at(
            lambda a: (a.newton, a.subdivided, a.level),
            acc,
            (
                acc.newton + info.newton_iterations,
                acc.subdivided + (info.level > 0),
                jnp.maximum(acc.level, info.level),
            ),
        )
        return (state, acc), None

    if save_every is None:
        (state, acc), _ = jax.lax.scan(step, (state, acc), jnp.arange(n_steps, dtype=jnp.int32))
        ys = None
    else:
        n_outer, n_tail = divmod(n_steps, save_every)

        def outer(carry, k):
            carry, _ = jax.lax.scan(step, carry, k * save_every + jnp.arange(save_every, dtype=jnp.int32))
            state = carry[0]
            y = jnp.where(state.status == 0, to_physical(solver, state.y), jnp.nan)
            return carry, y

        (state, acc), ys = jax.lax.scan(outer, (state, acc), jnp.arange(n_outer, dtype=jnp.int32))
        if n_tail:
            (state, acc), _ = jax.lax.scan(
                step, (state, acc), n_outer * save_every + jnp.arange(n_tail, dtype=jnp.int32)
            )
        ys = jnp.concatenate([jnp.where(start_ok, y_start, jnp.nan)[None], ys])

    have = acc.count > 0
    nan = jnp.asarray(jnp.nan)
    return BatchSummary(
        status=state.status,
        t_stop=acc.t_last,
        v_mean=jnp.where(have, acc.mean, nan),
        v_std=jnp.where(have, jnp.sqrt(acc.m2 / jnp.maximum(acc.count, 1)), nan),
        v_min=jnp.where(have, acc.vmin, nan),
        v_max=jnp.where(have, acc.vmax, nan),
        v_final=jnp.where(start_ok, acc.v_prev, nan),
        window_count=acc.count,
        events=acc.events,
        v_slip=v_slip,
        newton_iterations=acc.newton,
        subdivided_steps=acc.subdivided,
        max_subdivision_level=acc.level,
        ys=ys,
    )


@eqx.filter_jit
def run_batch(
    model: PeelingModel,
    solver: AlphaMethod,
    V: Float[Array, " B"],
    tau: Float[Array, " B"],
    params: dict[str, Float[Array, " B"]],
    t_final: Float[Array, ""],
    window: Float[Array, " 2"],
    n_steps: int,
    save_every: int | None,
    truncation: int | None,
    mesh: jax.sharding.Mesh | None = None,
) -> BatchSummary:
    """All lanes at once: ``vmap`` of the single-trajectory scan over V, τ and ``params``.

    Compiled once per (B, n_steps, save_every, truncation, mesh, the solver's static fields,
    the model's structure, the names in ``params``); the values of every array are traced.
    With a ``mesh`` (one axis, ``"batch"``), ``shard_map`` runs the same ``vmap``ped program on
    each device's B/n_devices lanes (B must be a multiple of n_devices); no data moves between
    devices. Statuses, t_stop and event counts are those of one device; floating-point values
    agree to rounding (measured ≤ 4e-14 absolute on v over 40 steps): XLA compiles the
    partitioned program with other fusions than the single-device one.
    """

    def lanes(model, solver, t_final, window, V, tau, params):
        return jax.vmap(
            lambda V, tau, params: _lane(
                model, solver, V, tau, params, t_final, window, n_steps, save_every, truncation
            )
        )(V, tau, params)

    if mesh is None:
        return lanes(model, solver, t_final, window, V, tau, params)
    P = jax.sharding.PartitionSpec
    model_arrays, model_static = eqx.partition(model, eqx.is_array)
    solver_arrays, solver_static = eqx.partition(solver, eqx.is_array)

    def per_device(model_arrays, solver_arrays, t_final, window, V, tau, params):
        model = eqx.combine(model_arrays, model_static)
        solver = eqx.combine(solver_arrays, solver_static)
        return lanes(model, solver, t_final, window, V, tau, params)

    sharded = jax.shard_map(
        per_device,
        mesh=mesh,
        in_specs=(P(), P(), P(), P(), P("batch"), P("batch"), P("batch")),
        out_specs=P("batch"),
        check_vma=False,
    )
    return sharded(model_arrays, solver_arrays, t_final, window, V, tau, params)
