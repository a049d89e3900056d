"""The batched α-method runs behind :func:`peeljax.sweep`: per-lane summaries, no full trajectories.

Two engines, one per integrator; both give each lane the steps :func:`peeljax.simulate` takes
with the same settings, and accumulate the summaries inside the compiled loop.

**Error control** (:func:`run_batch_adaptive`, the default of ``sweep``): each lane runs
:func:`peeljax.integrators.adaptive.adaptive_loop`, the loop of
:func:`~peeljax.integrate_alpha_adaptive`, with its own step sizes, and a
:class:`WindowStatistics` observer that integrates over the window W = [w0·t_final, w1·t_final]:

* mean and (population) standard deviation of v as time averages, (1/T)∫_W v dt and
  ((1/T)∫_W (v − v̄)² dt)^(1/2), T the covered part of W, by Gauss–Legendre quadrature of each
  step's Hermite interpolant (exact on the dense output up to rounding);
* v_min, v_max over the dense output at the window's ends and the quadrature nodes;
* events: upward crossings v_n < v̂ ≤ v_{n+1} between accepted step points with t_{n+1} ∈ W;
* the work: accepted and rejected steps, Newton iterations;
* saved states (optional) at given times by the dense output.

Lanes run in groups of ``lane_batch`` under ``vmap``, the groups one after another
(``lax.map``): a ``vmap``ped while loop runs until its slowest lane is done, so on a CPU one
lane at a time is fastest, while a GPU takes a whole chunk at once (:func:`peeljax.sweeps.devices.default_lane_batch`).

**Uniform mesh** (:func:`run_batch`, ``sweep(dt=…)``): every lane integrates on the mesh of N
steps (same :func:`alpha_start` / :func:`alpha_advance` as :func:`peeljax.simulate`), one
``vmap``ped scan, and the summaries are over the accepted mesh points:

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

With a device mesh both engines run under ``shard_map``, each device on its share of the lanes.

v̂(V) is found per lane inside the compiled function by :func:`peeljax.structure.phi_extremum`
(the same search :func:`peeljax.phi_extrema` runs on the host). A φ with no maximum in its
range gives v̂ = inf (no events).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..adhesion import COEFFICIENT_NAMES
from ..homogenized import HomogenizedODE
from ..integrators.alpha import AlphaMethod, alpha_advance, alpha_start, from_log, to_physical
from ..integrators.base import AbstractAdaptiveIntegrator
from ..integrators.dense import hermite
from ..integrators.observers import DenseOutput, Observer, Observers
from ..model import PeelingModel
from ..structure import phi_extremum

__all__ = [
    "MODEL_PARAMETERS",
    "BatchSummary",
    "WindowStatistics",
    "run_batch",
    "run_batch_adaptive",
    "slip_velocity",
    "with_parameters",
]

MODEL_PARAMETERS: tuple[str, ...] = ("R", "I", "k", "l", *COEFFICIENT_NAMES)


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
    accepted_steps: Int[Array, " B"]
    rejected_steps: Int[Array, " B"]
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
    """v̂(V) = the first maximum of φ(·, V) (:func:`peeljax.structure.phi_extremum`); inf if none (no events)."""
    v_hat = phi_extremum(model, V, "max")
    return jnp.where(jnp.isnan(v_hat), jnp.inf, v_hat)


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
        accepted_steps=jnp.round(acc.t_last / h).astype(jnp.int32),
        rejected_steps=zero_i,
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
    agree to rounding (``tests/test_sweep.py`` checks 1e-12; ``docs/sweeps.md``): XLA compiles
    the partitioned program with other fusions than the single-device one.
    """

    def lanes(model, solver, t_final, window, V, tau, params):
        return jax.vmap(
            lambda V, tau, params: _lane(
                model, solver, V, tau, params, t_final, window, n_steps, save_every, truncation
            )
        )(V, tau, params)

    return _over_devices(lanes, mesh, (model, solver, t_final, window), (V, tau, params))


def _over_devices(lanes, mesh, shared, batched):
    """``lanes(*shared, *batched)``, with ``shard_map`` over ``mesh`` (axis "batch") if given.

    ``shared`` (pytrees of arrays and static fields) is replicated; ``batched`` is split along
    its leading axis; the result is split the same way.
    """
    if mesh is None:
        return lanes(*shared, *batched)
    P = jax.sharding.PartitionSpec
    arrays, static = eqx.partition(shared, eqx.is_array)

    def per_device(arrays, *batched):
        return lanes(*eqx.combine(arrays, static), *batched)

    sharded = jax.shard_map(
        per_device,
        mesh=mesh,
        in_specs=(P(), *(P("batch") for _ in batched)),
        out_specs=P("batch"),
        check_vma=False,
    )
    return sharded(arrays, *batched)


# ---------------------------------------------------------------------------- error control
_GAUSS_NODES = (0.5 - 0.5 * 0.6**0.5, 0.5, 0.5 + 0.5 * 0.6**0.5)  # on [0, 1]
_GAUSS_WEIGHTS = (5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0)


class _WindowRecord(eqx.Module):
    time: Array  # covered time of the window
    mean: Array
    m2: Array  # ∫ (v − mean)² dt over the covered window
    vmin: Array
    vmax: Array
    count: Array  # accepted step points in the window
    events: Array


class WindowStatistics(Observer):
    """Time integrals of v over the window W = [w0, w1] on the dense output (error control).

    For each accepted step [t_n, t_n+1], the part inside W, [a, b], contributes
    ∫_a^b v dt and ∫_a^b (v − v̄)² dt by 3-point Gauss–Legendre quadrature of the step's cubic
    Hermite interpolant (in log v, then v = exp(log v)): exact for a quintic, so its error is
    far below the integrator's. The running mean v̄ and the second moment are combined by the
    weighted form of Welford's update (West 1979), which does not cancel when std ≪ mean.
    v_min and v_max are taken over v(a), v(b) and the three nodes of each step in W; events
    are the upward crossings v_n < v̂ ≤ v_n+1 of v̂ between accepted step points with
    t_n+1 ∈ W, the uniform mesh's definition.
    """

    w0: Array
    w1: Array
    v_slip: Array
    carried_log: tuple[int, ...] = eqx.field(static=True)

    def init(self, t0, y0, J0, ok):
        zero = jnp.asarray(0, jnp.int32)
        in_window = (self.w0 <= t0) & (t0 <= self.w1) & ok
        return _WindowRecord(
            time=jnp.asarray(0.0),
            mean=jnp.asarray(0.0),
            m2=jnp.asarray(0.0),
            vmin=jnp.asarray(jnp.inf),
            vmax=jnp.asarray(-jnp.inf),
            count=zero + in_window,
            events=zero,
        )

    def update(self, record, step, kind):
        a = jnp.clip(step.t0, self.w0, self.w1)
        b = jnp.clip(step.t1, self.w0, self.w1)
        length = b - a
        inside = step.advance & (length > 0)
        times = jnp.stack([a, *(a + node * length for node in _GAUSS_NODES), b])
        ys = hermite(step.t0, step.h, step.y0, step.psi0, step.y1, step.psi1, times)
        v = from_log(ys, self.carried_log)[:, 3]
        time, mean, m2 = record.time, record.mean, record.m2
        for weight, v_node in zip(_GAUSS_WEIGHTS, v[1:4]):
            w = jnp.where(inside, weight * length, 0.0)
            total = time + w
            delta = v_node - mean
            mean = jnp.where(w > 0, mean + (w / jnp.where(w > 0, total, 1.0)) * delta, mean)
            m2 = jnp.where(w > 0, m2 + w * delta * (v_node - mean), m2)
            time = total
        v0, v1 = (from_log(y, self.carried_log)[3] for y in (step.y0, step.y1))
        end_inside = step.advance & (self.w0 <= step.t1) & (step.t1 <= self.w1)
        crossed = end_inside & (v0 < self.v_slip) & (v1 >= self.v_slip)
        return _WindowRecord(
            time=time,
            mean=mean,
            m2=m2,
            vmin=jnp.where(inside, jnp.minimum(record.vmin, jnp.min(v)), record.vmin),
            vmax=jnp.where(inside, jnp.maximum(record.vmax, jnp.max(v)), record.vmax),
            count=record.count + end_inside,
            events=record.events + crossed,
        )


def _adaptive_lane(
    model: PeelingModel,
    integrator: AbstractAdaptiveIntegrator,
    V,
    tau,
    params: dict,
    t_final,
    window,
    save_ts,
    truncation: int | None,
) -> BatchSummary:
    """One trajectory by an integrator that picks its own steps, with window statistics (time integrals)."""
    model = with_parameters(model, params)
    ode = HomogenizedODE(model, V, tau, truncation)
    v_slip = slip_velocity(model, ode.V)
    carried_log = integrator.carried_log
    statistics = WindowStatistics(window[0] * t_final, window[1] * t_final, v_slip, carried_log)
    observers = (statistics,) if save_ts is None else (statistics, DenseOutput(save_ts))
    run = integrator.observe(ode, model.initial_state(ode.V), 0.0, t_final, Observers(observers))
    record = run.record[0]
    have = record.time > 0
    nan = jnp.asarray(jnp.nan)
    ys = None
    if save_ts is not None:
        out = run.record[1]
        ys = jnp.where(out.valid[:, None], from_log(out.y, carried_log), jnp.nan)
    zero = jnp.asarray(0, jnp.int32)
    return BatchSummary(
        status=run.status,
        t_stop=run.t_stop,
        v_mean=jnp.where(have, record.mean, nan),
        v_std=jnp.where(have, jnp.sqrt(jnp.maximum(record.m2, 0.0) / jnp.where(have, record.time, 1.0)), nan),
        v_min=jnp.where(have, record.vmin, nan),
        v_max=jnp.where(have, record.vmax, nan),
        v_final=run.y_final[3],
        window_count=record.count,
        events=record.events,
        v_slip=v_slip,
        newton_iterations=run.newton_iterations,
        subdivided_steps=zero,
        max_subdivision_level=zero,
        accepted_steps=run.accepted_steps,
        rejected_steps=run.rejected_steps,
        ys=ys,
    )


@eqx.filter_jit
def run_batch_adaptive(
    model: PeelingModel,
    integrator: AbstractAdaptiveIntegrator,
    V: Float[Array, " B"],
    tau: Float[Array, " B"],
    params: dict[str, Float[Array, " B"]],
    t_final: Float[Array, ""],
    window: Float[Array, " 2"],
    save_ts: Float[Array, " S"] | None,
    truncation: int | None,
    lane_batch: int,
    mesh: jax.sharding.Mesh | None = None,
) -> BatchSummary:
    """All lanes by an integrator that picks its own steps (the error-controlled α-method, a
    diffrax solver), each lane with its own step sizes.

    ``lax.map`` runs groups of ``lane_batch`` lanes one after another, each group ``vmap``ped:
    a group's while loop runs until its slowest lane is done, so a small group wastes little
    on lanes that finish early, and a large one vectorizes the step over lanes. Lanes are
    grouped in order of increasing τ (small τ takes the most steps), so that lanes of similar
    cost share a group. ``lane_batch = B`` is one ``vmap`` over all lanes. With a ``mesh`` each
    device runs its own share of the lanes this way (``shard_map``).
    """

    def lanes(model, integrator, t_final, window, save_ts, V, tau, params):
        def one(lane):
            return _adaptive_lane(model, integrator, *lane, t_final, window, save_ts, truncation)

        order = jnp.argsort(tau)
        inverse = jnp.argsort(order)
        lanes = jax.tree_util.tree_map(lambda x: x[order], (V, tau, params))
        batch = min(lane_batch, V.shape[0])
        results = jax.lax.map(one, lanes, batch_size=batch) if batch > 1 else jax.lax.map(one, lanes)
        return jax.tree_util.tree_map(lambda x: x[inverse], results)

    shared = (model, integrator, t_final, window, save_ts)
    return _over_devices(lanes, mesh, shared, (V, tau, params))
