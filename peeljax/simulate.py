"""The public entry points: validate once, then run a compiled integrator.

A :func:`simulate` call whose options (all but V, τ and y0) were seen before runs through a
:class:`~peeljax.Simulator` kept for them (:func:`_kept_simulator`): the options' checks, the
integrator and the packed parameters are then made once, as a ``Simulator`` makes them, and
the call costs what a ``Simulator`` call does (``benchmarks/guard.py``'s ``simulator_call``).
"""

from __future__ import annotations

import collections

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from ._arrays import float_array
from ._validation import check_max_steps, check_mesh, check_output_times, check_positive, check_tau
from .bound import Simulator, _number
from .integrators.alpha import AlphaMethod
from .integrators.reference import integrate_reference
from .integrators.select import DEFAULT_MAX_JUMPS, integrator_for, refuse_with_dt, resolve_max_steps
from .model import PeelingModel
from .run_program import (
    FIRST_MAX_JUMPS, _bucketed, _check_memory, _finished, _first_rows, _initial_state, _prepare, _run,
    check_run_memory, grown_until_it_holds, is_dae,
)  # fmt: skip
from .solution import Solution, is_traced

__all__ = ["check_run_memory", "simulate", "simulate_reference"]

def simulate(
    model: PeelingModel | None = None,
    V: ArrayLike = 1.1,
    tau: ArrayLike = 0.01,
    dt: float | None = None,
    t_final: float = 3.0,
    rho: ArrayLike = 0.0,
    y0: ArrayLike | None = None,
    *,
    rtol: float | None = None,
    atol: float | None = None,
    ts: ArrayLike | None = None,
    dtmin: float | None = None,
    max_steps: int | None = None,
    adjoint: str = "reverse",
    solver: str | AlphaMethod | diffrax.AbstractSolver | None = None,
    truncation: int | None = None,
    checkpoint_every: int | str | None = None,
    fold: str | None = None,
    max_jumps: int | None = None,
    memory_limit: float | None = None,
) -> Solution:
    """Integrate the peeling problem with error control or the paper's α-method mesh, through the folds of φ.

    ``tau > 0``: the homogenized ODE (eq. ``hv``); ``tau = 0``: the DAE itself, x' = f(x, v)
    with v solved from the constraint on its stable branch (:class:`~peeljax.ConstrainedDAE`).
    At a fold of φ v jumps, at constant x, to the other stable branch of G(x) = φ(v, V) — the
    tape slips at φ's maximum and re-sticks at its minimum — and the run goes on
    (``fold="jump"``, the default under error control; every jump is in ``result.jumps``).

    Two modes:

    * ``dt=None`` (default): error control (:mod:`peeljax.integrators.adaptive`), a step size
      chosen by a PI controller so that each step's local error estimate is within
      ``rtol``/``atol``; output at ``ts`` by the step's interpolant. The stepper: ``solver``,
      or by default (measured, docs/theory.md "Choosing the stepper") Tsit5 in pseudo-time at
      τ = 0 and at τ > 0 ``"auto"``: Tsit5, switching to the α-method where the homogenized
      ODE turns stiff (:class:`~peeljax.integrators.SwitchingStepper`; ``stats`` count each
      one's steps and the switches). A ρ ≠ 0 asks for the α-method.
    * ``dt`` a number: the uniform mesh of the paper, the α-method (:func:`peeljax.integrate_alpha`).

    ``solver`` may also be any ``diffrax.AbstractSolver`` (e.g. ``diffrax.Kvaerno5()``): the
    same problem, tolerances, stops and output then run through diffrax with its PID controller
    (:class:`~peeljax.integrators.DiffraxIntegrator`; error control only). The options become
    an integrator in one place, :func:`peeljax.integrators.integrator_for`.

    Args:
        model: spool, tape and adhesion law (default: the paper's, ``PeelingModel()``).
        V: pull velocity [m/s], > 0.
        tau: homogenization time scale τ [s], ≥ 0 (0: the DAE itself, with jumps at the folds).
        dt: None for error control; else the requested uniform step [s]: the mesh has
            N = round(t_final/dt) steps of t_final/N (``result.stats["step_size"]``), so it
            ends exactly at t_final.
        t_final: end time [s], > 0 (≥ dt).
        rho: the α-method's ρ ∈ [0, 1) (ignored when ``solver`` is given).
        y0: initial (α, ω, u, v) with v > 0 (default: the paper's consistent data,
            :meth:`PeelingModel.initial_state`).
        solver: a name (``"auto"``, ``"alpha"``, ``"tsit5"``, ``"dopri5"``, ``"dopri8"``,
            ``"kvaerno3/4/5"``), an :class:`AlphaMethod` to set Newton tolerances and
            safeguards, a stepper, or a ``diffrax.AbstractSolver`` (error control: ``dt=None``).
        truncation: ``None`` for the exact J_t, m ≥ 1 for the m-term eq. ``hvex``, 0 for the
            τ → 0 index-1 ODE.
        rtol, atol: error control only (default 1e-6 and 1e-9): relative tolerance in
            (0, 1) and absolute tolerance > 0 of the weighted RMS error norm; log v is
            weighted by rtol alone (a relative error of v). Giving either with ``dt`` is an error.
        ts: error control only: output times in [0, t_final], increasing. None: the
            accepted step points, in ``max_steps + 1`` rows NaN-padded (``valid`` False).
            Grids whose lengths fall in one bucket (8, 10, 12, 14, 16, 20, 24, … rows) share
            one compiled run (:func:`_bucketed`).
        dtmin: error control only: a proposed step below it stops the run with "step size
            collapsed" (default 1e-12·t_final, at most 3e-12 s: the first step from the paper's
            start is about 1e-11 s whatever t_final is, so a dtmin growing with t_final would
            stop a long run at t = 0). Must be < t_final.
        max_steps: error control only: most step attempts (accepted + rejected; static).
            Reaching it stops the run with its own reason. Default: 100 000 when the
            accepted steps are the output (``ts=None``: memory grows with it), 10⁷ with
            output at ``ts`` (nothing is kept per step: the budget only guards against a
            run that never ends).
        adjoint: error control only: ``"reverse"`` (default: ``jax.grad`` works; with few
            perturbed numbers — at most 7 at τ = 0, 16 at τ > 0 — by their tangents through
            the plain while loop, otherwise by the checkpointed loop's pullback; a run with
            no derivative takes the plain loop), ``"checkpointed"`` (``jax.grad`` always
            through the checkpointed while loop: memory bounded, any number of parameters)
            or ``"forward"`` (the plain while loop, for ``jax.jvp``/``jacfwd``).
        checkpoint_every: uniform mesh only, for reverse-mode gradients of long runs: chunks
            of this many steps under ``jax.checkpoint`` (``"sqrt"``: ≈ √N), memory ∝ √N (see
            :func:`peeljax.integrate_alpha`); values are unchanged.
        fold: what happens at a fold of φ (:mod:`peeljax.integrators.events`): ``"jump"``
            (default under error control), ``"stop"`` (the paper's behaviour; the default, and
            the only choice, with ``dt`` or a diffrax solver) or ``"follow"`` (τ > 0: jump at
            impasse points only, follow the homogenized ODE through singular passages).
        max_jumps: size of the jump record (static); one more jump stops the run with that
            reason, keeping what it computed. None (default): as many as the run makes. Called
            with host numbers, the record starts with 1024 slots (room costs time whether it
            is used or not); a run that fills it runs again with room for the jumps its rate
            predicts, while that fits in ``memory_limit``. Traced (under ``jit``, ``vmap``,
            ``grad`` of an input) the size must be known before the run: 10⁴; inside a ``jit``
            that closes over every input, 1024 without growth.
        memory_limit: bytes the run's output may take in host memory (default: half the RAM);
            a run whose output rows (``ts``, ``max_steps + 1`` accepted steps, or the mesh
            points) would take more is refused before anything compiles.

    Returns:
        A :class:`Solution` (its arrays read-only NumPy arrays, traced under ``jit``, ``vmap``
        and ``grad``). Uniform mesh: N + 1 time points. Error control: the points of
        ``ts``, or the accepted steps; ``stats`` has ``accepted_steps``, ``rejected_steps``
        and the smallest, mean and largest step. A run that cannot continue has
        ``status != 0``, ``t_stop`` and ``reason``; its later states are NaN. With folds
        located (error control), ``jumps`` is the :class:`~peeljax.JumpRecord` and
        ``stats["jumps"]`` its count; :func:`peeljax.cycle_statistics` summarizes it.
        Each jump is two rows at its time, the states just before and just after it
        (``after_jump`` marks the second; :class:`Solution`): the points of ``ts`` and the
        jumps in time order (under ``jit``, ``len(ts) + 2·max_jumps`` rows, the unused ones at
        the end repeating the last row).

    Gradients through a run with jumps follow the jumps: each jump time by the implicit
    function theorem on its fold event, the state after it through the constraint (see
    :mod:`peeljax.integrators.events`; the step sizes and the number of jumps are held fixed).
    ``jax.grad`` with respect to one φ coefficient costs 1.1× the run at τ = 0 and 1.9× at
    τ = 1e-3 through 210 and 158 jumps (``benchmarks/results/jump_gradient_cost*.md``); the
    checkpointed loop 4.3× and 17.4×.

    V, tau, rho, y0, the model's parameters and the adhesion coefficients are traced: ``jit``,
    ``vmap`` and ``grad`` work over them without recompiling. ``dt`` and ``t_final`` set the
    mesh's shape and must be Python numbers. Input is checked before compilation.

    Called a second time with the same options (all but V, τ and y0; the model, ``ts`` and a
    solver module by their values) on host numbers, ``simulate`` makes a :class:`Simulator`
    for them and keeps it (the 16 most recently used): the same solution, bit for bit, without
    the ~0.2 ms of checks and packing a call otherwise costs.
    """
    options = {
        "t_final": t_final, "ts": ts, "dt": dt, "rtol": rtol, "atol": atol, "rho": rho, "solver": solver, "fold": fold,
        "max_steps": max_steps, "max_jumps": max_jumps, "dtmin": dtmin, "truncation": truncation, "adjoint": adjoint,
        "checkpoint_every": checkpoint_every, "memory_limit": memory_limit,
    }  # fmt: skip
    simulator = _kept_simulator(model, V, tau, y0, options)
    if simulator is not None:
        return simulator(V, tau, y0)
    if dt is not None:
        refuse_with_dt(dt, ts=ts)
    check_tau(tau, allow_zero=True)
    max_steps = resolve_max_steps(max_steps, keeps_steps=ts is None)
    concrete = not is_traced((model, V, tau, rho, y0, ts))
    grows = max_jumps is None and concrete

    def integrator_with(max_jumps: int):
        return integrator_for(
            solver, rho=rho, dt=dt, t_final=t_final, rtol=rtol, atol=atol, dtmin=dtmin, max_steps=max_steps,
            adjoint=adjoint, checkpoint_every=checkpoint_every, fold=fold, max_jumps=max_jumps, dae=is_dae(tau),
            merge_jump_rows=False,  # merged below: on the host, the rows in use only
            folds_at_first_jump=concrete,  # neither batched nor differentiated
        )  # fmt: skip

    size = max_jumps if max_jumps is not None else FIRST_MAX_JUMPS if grows else DEFAULT_MAX_JUMPS
    integrator = integrator_with(size)
    requested = None if ts is None else check_output_times(ts, t_final)
    ts = None if requested is None else _bucketed(requested)
    _check_memory(integrator, requested, max_steps, memory_limit)  # (the added rows are dropped)
    ode, y0 = _prepare(model, V, tau, y0, truncation, allow_dae=True)
    solution = _run(integrator, ode, y0, float_array(t_final), ts)
    if grows:
        run = lambda integrator: _run(integrator, ode, y0, float_array(t_final), ts)  # noqa: E731
        solution = grown_until_it_holds(solution, size, integrator_with, run, requested, max_steps, memory_limit, t_final)
    return _finished(solution if ts is None else _first_rows(solution, requested.shape[0]), requested)


# Simulators kept for the options of recent calls (most recently used last), and the options
# seen once: a Simulator is made on the second call with them, so that a loop over models or
# options that never repeat pays no more than before.
_KEPT_SIMULATORS: collections.OrderedDict = collections.OrderedDict()
_SEEN_ONCE: collections.OrderedDict = collections.OrderedDict()
KEPT_SIMULATORS = 16  # (0: none kept, every call takes simulate's own route)


def _kept_simulator(model, V, tau, y0, options: dict) -> Simulator | None:
    """The :class:`Simulator` kept for these options, or None where the call takes
    :func:`simulate`'s own route: V or τ not a host number, y0 not a host vector of 4, an
    option or model leaf that is not a host value (traced, a JAX array, a function), options
    seen for the first time, or options a Simulator refuses (simulate then raises its own
    error, in its own order)."""
    if KEPT_SIMULATORS == 0 or _number(V) is None or _number(tau) is None:
        return None
    if y0 is not None and not (isinstance(y0, np.ndarray) and y0.shape == (4,)):
        return None
    key = _options_key(model, options)
    if key is None:
        return None
    simulator = _KEPT_SIMULATORS.get(key)
    if simulator is not None:
        _KEPT_SIMULATORS.move_to_end(key)
        return simulator
    if _SEEN_ONCE.pop(key, None) is None:
        _SEEN_ONCE[key] = True
        if len(_SEEN_ONCE) > KEPT_SIMULATORS:
            _SEEN_ONCE.popitem(last=False)
        return None
    try:
        simulator = Simulator(model, **options)
    except (TypeError, ValueError):
        return None
    _KEPT_SIMULATORS[key] = simulator
    if len(_KEPT_SIMULATORS) > KEPT_SIMULATORS:
        _KEPT_SIMULATORS.popitem(last=False)
    return simulator


def _options_key(model, options: dict) -> tuple | None:
    """A hashable key of the model and the options (``ts``, and a model or solver given as a
    module, by their values), or None where one is not a host value."""
    ts = options["ts"]
    if ts is not None:
        ts = _host_values([ts]) if isinstance(ts, (np.ndarray, list, tuple)) else None
        if ts is None:
            return None
    parts = [None if model is None else _module_key(model)]
    for name in sorted(options):
        value = options[name]
        if name != "ts":
            parts.append((name, _module_key(value) if isinstance(value, eqx.Module) else value))
    if any(isinstance(part, _NotHost) for part in (parts[0], *(value for _, value in parts[1:]))):
        return None
    try:
        key = (ts, *parts)
        hash(key)
    except TypeError:  # a JAX array, a tracer, an object that is not hashable
        return None
    return key


class _NotHost:
    """A module with a leaf that is not a host number or array (traced, a JAX array, a function)."""


def _module_key(module) -> tuple | _NotHost:
    """A module (the model, a solver) by its structure and its leaves' values."""
    leaves, treedef = jax.tree_util.tree_flatten(module)
    values = _host_values(leaves)
    return _NotHost() if values is None else (treedef, values)


def _host_values(leaves) -> tuple | None:
    """The leaves' values as bytes (with dtype and shape), or None where one is not a host number or array."""
    values = []
    for leaf in leaves:
        if isinstance(leaf, (bool, int, float)):
            values.append(leaf)
            continue
        if isinstance(leaf, (list, tuple)):
            leaf = np.asarray(leaf)
        if not isinstance(leaf, (np.ndarray, np.generic)) or leaf.dtype == object:
            return None
        values.append((leaf.dtype.str, leaf.shape, leaf.tobytes()))
    return tuple(values)


@eqx.filter_jit
def _run_reference(ode, y0, ts, solver, rtol, atol, dtmin, max_steps):
    return integrate_reference(
        ode, _initial_state(ode, y0), ts, solver=solver, rtol=rtol, atol=atol, dtmin=dtmin, max_steps=max_steps
    )


def simulate_reference(
    model: PeelingModel | None = None,
    V: ArrayLike = 1.1,
    tau: ArrayLike = 0.01,
    dt: float | None = 1 / 82,
    t_final: float = 3.0,
    y0: ArrayLike | None = None,
    *,
    ts: ArrayLike | None = None,
    solver: diffrax.AbstractSolver | None = None,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    dtmin: float | None = None,
    max_steps: int = 200_000,
    truncation: int | None = None,
    memory_limit: float | None = None,
) -> Solution:
    """The same problem with diffrax (Kvaerno5 by default), output on the α-method's grid.

    ``dt`` sets only the output grid (N = round(t_final/dt) intervals), or ``ts`` (with
    ``dt=None``) gives the output times; the steps are adaptive with a PID controller at
    ``rtol``/``atol``. A collapsing step (< ``dtmin``, default 1e-12·t_final, at most
    3e-12 s) stops the run with status ``STALLED``. Output that would take more than
    ``memory_limit`` bytes (default: half the RAM) is refused before anything compiles.
    """
    if (ts is None) == (dt is None):
        raise ValueError("simulate_reference: give the output grid either as dt or as ts (with dt=None)")
    if ts is None:
        n_steps = check_mesh(dt, t_final)
        check_run_memory(
            n_steps + 1, "ts", remedy="a larger dt or a shorter t_final, or raise memory_limit", limit=memory_limit
        )
        ts = jnp.linspace(0.0, float(t_final), n_steps + 1)
    else:
        check_positive("t_final", t_final)
        ts = check_output_times(ts, t_final)
        if ts[0] != 0.0:
            raise ValueError("ts must start at 0 for the reference solver (its start time)")
        ts = jnp.asarray(ts)
    check_positive("rtol", rtol)
    check_positive("atol", atol)
    if dtmin is not None:
        check_positive("dtmin", dtmin)
    check_max_steps(max_steps)
    check_run_memory(ts.size, "ts", remedy="fewer output times ts, or raise memory_limit", limit=memory_limit)
    ode, y0 = _prepare(model, V, tau, y0, truncation)
    solver = diffrax.Kvaerno5() if solver is None else solver
    dtmin = min(1e-12 * float(t_final), 3e-12) if dtmin is None else dtmin
    return _run_reference(ode, y0, ts, solver, jnp.asarray(rtol), jnp.asarray(atol), jnp.asarray(dtmin), max_steps)
