"""The batched runs behind :func:`peeljax.sweep`: per-lane summaries, no full trajectories.

One engine for every integrator (:mod:`peeljax.integrators.base`). Each lane is the run the
integrator makes alone (:meth:`~peeljax.integrators.AbstractIntegrator.observe`, the loop of
:func:`peeljax.simulate`), and its steps are shown to observers that accumulate the summaries
inside the compiled loop, over the window W = [w0·t_final, w1·t_final]:

* an integrator with dense output (error control, the default of ``sweep``; a diffrax
  solver): :class:`WindowStatistics`, time integrals. Mean and (population) standard
  deviation of v as (1/T)∫_W v dt and ((1/T)∫_W (v − v̄)² dt)^(1/2), T the covered part of W,
  by Gauss–Legendre quadrature of each step's Hermite interpolant; v_min, v_max over the
  dense output at the window's ends and the quadrature nodes;
* the uniform mesh (``sweep(dt=…)``): :class:`PointStatistics`, over the accepted mesh points
  t_i ∈ W (the initial state included when w0 = 0): count, mean and standard deviation by
  Welford's update, minimum and maximum;
* for both, events (τ = 0, the DAE: its stick → slip jumps in W, since its v never crosses v̂):
  the upward crossings v_{i−1} < v̂ ≤ v_i of v̂(V), the peeling velocity
  at the maximum of φ(·, V) (the onset of slip, where ∂φ/∂v = 0 and J_t → τ·F̃·(…)·∂f/∂v,
  Lemma ``hi``), counted for each accepted step whose end lies in W; and the work done
  (accepted and rejected steps, Newton iterations, the uniform mesh's subdivided steps);
* saved states (optional): at given times by the dense output (:class:`DenseOutput`), or
  every k-th mesh point (:class:`EveryNthPoint`); memory O(saved points), never O(steps);
* where the runs go through the folds of φ (error control, ``fold="jump"``): the cycle
  statistics of the window W, accumulated at each jump inside the loop
  (:class:`~peeljax.integrators.cycle_accumulator.CycleAccumulator`: the definitions of
  :func:`peeljax.cycle_statistics`, however many jumps W holds), and the lane's last
  ``max_jumps`` jumps (a ring buffer, :class:`~peeljax.JumpRecord`): a lane never stops for
  a full record, and holds O(max_jumps) numbers however long it runs.

Lanes run in groups of ``lane_batch`` under ``vmap``, the groups one after another
(``lax.map``): a ``vmap``ped while loop runs until its slowest lane is done, so with error
control one lane at a time is fastest on a CPU, while a GPU takes a whole chunk at once
(:func:`peeljax.sweeps.devices.default_lane_batch`); the uniform mesh takes every lane at once.
With a device mesh the lanes run under ``shard_map``, each device on its share.

v̂(V) is found per lane inside the compiled function by :func:`peeljax.structure.phi_extremum`
(the same search :func:`peeljax.phi_extrema` runs on the host). A φ with no maximum in its
range gives v̂ = inf (no events).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..adhesion import COEFFICIENT_NAMES
from .._devices import over_devices
from ..constrained import ConstrainedDAE
from ..homogenized import HomogenizedODE
from ..integrators.cycle_accumulator import CycleAccumulator
from ..integrators.log_variables import from_log
from ..integrators.base import AbstractIntegrator
from ..integrators.observers import Observer, Observers
from ..model import PAPER_ALPHA0, PeelingModel
from ..solution import JumpRecord
from ..structure import phi_extremum

__all__ = [
    "MODEL_PARAMETERS",
    "STARTS",
    "BatchSummary",
    "GIVEN_START",
    "keep_last_jumps",
    "PointStatistics",
    "WindowStatistics",
    "run_batch",
    "slip_velocity",
    "with_parameters",
]

MODEL_PARAMETERS: tuple[str, ...] = ("R", "I", "k", "l", *COEFFICIENT_NAMES)
STARTS = ("paper", "steady")
GIVEN_START = "given"  # each lane's state given (a sweep's ``start`` array)


def initial_state(model: PeelingModel, V, start: str, given: dict | None = None):
    """The lane's start: the paper's consistent data (v0 = 1e-10·V, the tape at rest),
    ``"steady"``: steady peeling, v = V and ω = V/R at the paper's α0, u from the constraint,
    or :data:`GIVEN_START`: the state ``given["y0"]``."""
    if start == GIVEN_START:
        return given["y0"]
    if start == "paper":
        return model.initial_state(V)
    return model.consistent_state(V, PAPER_ALPHA0, V / model.R, V)


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
    # Where folds are located: each lane's last max_jumps jumps in time order (slots below
    # min(count, max_jumps)), ``count`` its total, and the window's cycle statistics
    # (CycleAccumulator.finish: name → (B, …) arrays).
    jumps: JumpRecord | None = None
    cycles: dict[str, Array] | None = None


def keep_last_jumps(integrator: AbstractIntegrator) -> AbstractIntegrator:
    """``integrator`` with its jump record a ring buffer (:class:`~peeljax.JumpRecord`): each
    lane keeps its last ``max_jumps`` jumps and never stops for a full record. Unchanged
    where no fold is located."""
    events = getattr(integrator, "events", None)
    if events is None:
        return integrator
    return dataclasses.replace(integrator, events=dataclasses.replace(events, ring=True))


def _with_cycle_window(integrator: AbstractIntegrator, w0, w1) -> AbstractIntegrator:
    """``integrator`` accumulating the cycle statistics of [w0, w1] at every jump."""
    events = getattr(integrator, "events", None)
    if events is None:
        return integrator
    return dataclasses.replace(integrator, events=dataclasses.replace(events, statistics=CycleAccumulator.over(w0, w1)))


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


# ---------------------------------------------------------------------------- statistics
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
        ys = step.evaluate(times)
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

    def summary(self, record: _WindowRecord) -> dict[str, Array]:
        have = record.time > 0
        nan = jnp.asarray(jnp.nan)
        std = jnp.sqrt(jnp.maximum(record.m2, 0.0) / jnp.where(have, record.time, 1.0))
        return {
            "v_mean": jnp.where(have, record.mean, nan),
            "v_std": jnp.where(have, std, nan),
            "v_min": jnp.where(have, record.vmin, nan),
            "v_max": jnp.where(have, record.vmax, nan),
            "window_count": record.count,
            "events": record.events,
        }


class _PointRecord(eqx.Module):
    count: Array
    mean: Array
    m2: Array  # Σ (v − mean)² over the points
    vmin: Array
    vmax: Array
    events: Array
    v_prev: Array  # v at the last accepted point


class PointStatistics(Observer):
    """Statistics of v over the accepted points t_i ∈ W = [w0, w1] (an integrator without dense
    output: the uniform mesh, as in the paper).

    Count, mean and population standard deviation by Welford's update, minimum and maximum,
    over the accepted states with t_i ∈ W (the initial state included when w0 ≤ t0); events:
    the upward crossings v_{i−1} < v̂ ≤ v_i of each step whose end t_i lies in W. A tolerance
    of 1e-9·h on the window's ends keeps mesh points on them inside.
    """

    w0: Array
    w1: Array
    v_slip: Array
    carried_log: tuple[int, ...] = eqx.field(static=True)

    def _add(self, record: _PointRecord, v, ok, in_window, v_slip) -> _PointRecord:
        use = ok & in_window
        count = record.count + use.astype(record.count.dtype)
        delta = v - record.mean
        mean = jnp.where(use, record.mean + delta / jnp.maximum(count, 1), record.mean)
        return _PointRecord(
            count=count,
            mean=mean,
            m2=jnp.where(use, record.m2 + delta * (v - mean), record.m2),
            vmin=jnp.where(use, jnp.minimum(record.vmin, v), record.vmin),
            vmax=jnp.where(use, jnp.maximum(record.vmax, v), record.vmax),
            events=record.events + (use & (record.v_prev < v_slip) & (v >= v_slip)).astype(record.events.dtype),
            v_prev=jnp.where(ok, v, record.v_prev),
        )

    def init(self, t0, y0, J0, ok):
        v0 = from_log(y0, self.carried_log)[3]
        zero = jnp.asarray(0, jnp.int32)
        record = _PointRecord(
            count=zero,
            mean=jnp.asarray(0.0),
            m2=jnp.asarray(0.0),
            vmin=jnp.asarray(jnp.inf),
            vmax=jnp.asarray(-jnp.inf),
            events=zero,
            v_prev=jnp.where(ok, v0, jnp.nan),
        )
        # The initial state counts in the window like any accepted state (no crossing before it).
        return self._add(record, v0, ok, (self.w0 <= t0) & (t0 <= self.w1), jnp.inf)

    def update(self, record, step, kind):
        v = from_log(step.y1, self.carried_log)[3]
        slack = 1e-9 * step.h
        in_window = (step.t1 >= self.w0 - slack) & (step.t1 <= self.w1 + slack)
        return self._add(record, v, step.advance, in_window, self.v_slip)

    def summary(self, record: _PointRecord) -> dict[str, Array]:
        have = record.count > 0
        nan = jnp.asarray(jnp.nan)
        return {
            "v_mean": jnp.where(have, record.mean, nan),
            "v_std": jnp.where(have, jnp.sqrt(record.m2 / jnp.maximum(record.count, 1)), nan),
            "v_min": jnp.where(have, record.vmin, nan),
            "v_max": jnp.where(have, record.vmax, nan),
            "window_count": record.count,
            "events": record.events,
        }


# ---------------------------------------------------------------------------- the lanes
def _lane(
    model: PeelingModel,
    integrator: AbstractIntegrator,
    V,
    tau,
    params: dict,
    t_final,
    window,
    save: Observer | None,
    truncation: int | None,
    dae: bool = False,
    start: str = "paper",
    given: dict | None = None,
) -> BatchSummary:
    """One trajectory: the integrator's steps shown to the window statistics (and ``save``).

    ``dae``: τ = 0, the DAE itself (:class:`~peeljax.ConstrainedDAE`); ``start``, ``given``:
    see :func:`initial_state`."""
    model = with_parameters(model, params)
    integrator = _with_cycle_window(integrator, window[0] * t_final, window[1] * t_final)
    ode = ConstrainedDAE(model, V) if dae else HomogenizedODE(model, V, tau, truncation)
    v_slip = slip_velocity(model, ode.V)
    carried_log = integrator.carried_log
    statistics_type = WindowStatistics if integrator.dense_output else PointStatistics
    statistics = statistics_type(window[0] * t_final, window[1] * t_final, v_slip, carried_log)
    observers = (statistics,) if save is None else (statistics, save)
    run = integrator.observe(ode, initial_state(model, ode.V, start, given), 0.0, t_final, Observers(observers))
    summary = statistics.summary(run.record[0])
    jumps, cycles = run.jumps, None
    if jumps is not None:
        cycles = jumps.statistics.finish(run.t_stop)
        # the slots in time order; count stays the lane's total
        jumps = eqx.tree_at(lambda r: r.count, jumps.latest(), jumps.count)
    if dae and cycles is not None:
        # The DAE's v never crosses v̂ (its stick branch ends there): its slips are its
        # stick → slip jumps. (The homogenized ODE's v rises through v̂ before J_t → 0: a crossing.)
        summary["events"] = cycles["slips"].astype(summary["events"].dtype)
    ys = None
    if save is not None:
        out = run.record[1]
        ys = jnp.where(out.valid[:, None], from_log(out.y, carried_log), jnp.nan)
    return BatchSummary(
        status=run.status,
        t_stop=run.t_stop,
        **summary,
        v_final=run.y_final[3],
        v_slip=v_slip,
        newton_iterations=run.newton_iterations,
        subdivided_steps=run.subdivided_steps,
        max_subdivision_level=run.max_subdivision_level,
        accepted_steps=run.accepted_steps,
        rejected_steps=run.rejected_steps,
        ys=ys,
        jumps=jumps,
        cycles=cycles,
    )


@eqx.filter_jit
def run_batch(
    model: PeelingModel,
    integrator: AbstractIntegrator,
    V: Float[Array, " B"],
    tau: Float[Array, " B"],
    params: dict[str, Float[Array, " B"]],
    t_final: Float[Array, ""],
    window: Float[Array, " 2"],
    save: Observer | None,
    truncation: int | None,
    lane_batch: int,
    mesh: jax.sharding.Mesh | None = None,
    dae: bool = False,
    start: str = "paper",
    given: dict[str, Float[Array, "B 4"]] | None = None,
) -> BatchSummary:
    """All lanes, each the run the integrator makes alone, summarised by :func:`_lane`.

    ``lax.map`` runs groups of ``lane_batch`` lanes one after another, each group ``vmap``ped:
    a group's while loop runs until its slowest lane is done, so a small group wastes little
    on lanes that finish early, and a large one vectorizes the step over lanes. Lanes are
    grouped in order of increasing τ (small τ takes the most steps), so that lanes of similar
    cost share a group. ``lane_batch = B`` is one ``vmap`` over all lanes (the uniform mesh's
    choice: every lane takes the same steps). With a ``mesh`` (one axis, ``"batch"``),
    ``shard_map`` runs the same program on each device's B/n_devices lanes (B a multiple of
    n_devices); no data moves between devices. Statuses, t_stop and event counts are those of
    one device; floating-point values agree to rounding (``tests/test_sweep.py`` checks 1e-12):
    XLA compiles the partitioned program with other fusions than the single-device one.

    Compiled once per (B, lane_batch, the integrator's and ``save``'s static fields and
    shapes, truncation, mesh, the model's structure, the names in ``params``); the values of
    every array are traced.
    """

    def lanes(model, integrator, t_final, window, save, V, tau, params, given):
        def one(lane):
            V, tau, params, given = lane
            return _lane(model, integrator, V, tau, params, t_final, window, save, truncation, dae, start, given)

        if lane_batch >= V.shape[0]:  # one group: nothing to sort
            return jax.vmap(one)((V, tau, params, given))
        order = jnp.argsort(tau)
        inverse = jnp.argsort(order)
        lanes = jax.tree_util.tree_map(lambda x: x[order], (V, tau, params, given))
        results = jax.lax.map(one, lanes, batch_size=lane_batch) if lane_batch > 1 else jax.lax.map(one, lanes)
        return jax.tree_util.tree_map(lambda x: x[inverse], results)

    shared = (model, integrator, t_final, window, save)
    return over_devices(lanes, mesh, shared, (V, tau, params, {} if given is None else given))
