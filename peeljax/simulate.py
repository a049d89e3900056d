"""The public entry points: validate once, then run a compiled integrator."""

from __future__ import annotations

import functools

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from ._arrays import float_array
from ._validation import (
    check_max_steps,
    check_mesh,
    check_output_times,
    check_positive,
    check_rho,
    check_tau,
    check_tolerance,
    check_truncation,
    check_y0,
)
from .homogenized import HomogenizedODE
from .integrators.adaptive import integrate_alpha_adaptive
from .integrators.alpha import AlphaMethod, integrate_alpha
from .integrators.controller import PIController
from .integrators.reference import integrate_reference
from .model import PeelingModel
from .solution import Solution

__all__ = ["simulate", "simulate_reference"]


def _prepare(model, V, tau, y0, truncation):
    model = PeelingModel() if model is None else model
    if not isinstance(model, PeelingModel):
        raise TypeError(f"model must be a PeelingModel, got {type(model).__name__}")
    check_positive("V", V)
    check_tau(tau)
    check_y0(y0)
    check_truncation(truncation)
    for name in ("R", "I", "k", "l"):
        check_positive(f"model.{name}", getattr(model, name))
    ode = HomogenizedODE(model, V, tau, truncation)
    # None: the paper's initial data, computed inside the compiled run (eagerly, its dozen
    # small operations would cost more than a short run).
    return ode, (None if y0 is None else jnp.asarray(y0, float))


def _initial_state(ode, y0):
    return ode.model.initial_state(ode.V) if y0 is None else y0


@functools.lru_cache(maxsize=64)
def _default_solver(rho: float) -> AlphaMethod:
    return AlphaMethod(rho=rho)


@functools.lru_cache(maxsize=64)
def _controller(rtol: float, atol: float) -> PIController:
    return PIController(rtol=rtol, atol=atol)


def checked_solver(solver: AlphaMethod | None, rho: ArrayLike) -> AlphaMethod:
    """``solver``, or ``AlphaMethod(rho=rho)`` when it is None, with ρ checked (before compiling)."""
    if solver is None:
        check_rho(rho)
        # Modules are immutable: one per ρ serves every call (building one costs ~50 µs).
        return _default_solver(float(rho)) if type(rho) in (float, int) else AlphaMethod(rho=rho)
    if not isinstance(solver, AlphaMethod):
        raise TypeError(f"solver must be an AlphaMethod, got {type(solver).__name__}")
    check_rho(solver.rho)
    return solver


@eqx.filter_jit
def _run_alpha(ode, solver, y0, t_final, n_steps, checkpoint_every=None):
    return integrate_alpha(
        ode, solver, _initial_state(ode, y0), 0.0, t_final, n_steps, checkpoint_every=checkpoint_every
    )


def _integrate_adaptive(ode, solver, y0, t_final, controller, ts, dtmin, max_steps, adjoint):
    return integrate_alpha_adaptive(
        ode,
        solver,
        _initial_state(ode, y0),
        0.0,
        t_final,
        controller=controller,
        ts=ts,
        dtmin=dtmin,
        max_steps=max_steps,
        adjoint=adjoint,
    )


def _integrate_packed(packed, rest, *, treedef, scalars, max_steps, adjoint):
    leaves, k, j = [], 0, 0
    for is_scalar in scalars:
        if is_scalar:
            leaves.append(packed[k])
            k += 1
        else:
            leaves.append(rest[j])
            j += 1
    args = jax.tree_util.tree_unflatten(treedef, leaves)
    return _integrate_adaptive(*args, max_steps=max_steps, adjoint=adjoint)


_adaptive_jit = jax.jit(_integrate_packed, static_argnames=("treedef", "scalars", "max_steps", "adjoint"))
_adaptive_filter_jit = eqx.filter_jit(_integrate_adaptive)


def _run_adaptive(ode, solver, y0, t_final, controller, ts, dtmin, max_steps, adjoint):
    """The compiled run, with ``jax.jit``'s C++ dispatch when every leaf is an array.

    The float parameters held on the host (about 30: the model's, φ's, the solver's, the
    controller's) travel as one vector, one host-to-device copy instead of one each (65 µs
    less per call). A leaf that is not an array (a φ given as a plain Python function) takes
    ``eqx.filter_jit`` instead.
    """
    leaves, treedef = jax.tree_util.tree_flatten((ode, solver, y0, t_final, controller, ts, dtmin))
    scalars = tuple(
        isinstance(leaf, (np.ndarray, np.generic)) and leaf.shape == () and leaf.dtype == np.float64 for leaf in leaves
    )
    if all(isinstance(leaf, (jax.Array, np.ndarray, np.generic)) for leaf in leaves):
        packed = np.array([leaf for leaf, is_scalar in zip(leaves, scalars) if is_scalar], dtype=float)
        rest = [leaf for leaf, is_scalar in zip(leaves, scalars) if not is_scalar]
        return _adaptive_jit(packed, rest, treedef=treedef, scalars=scalars, max_steps=max_steps, adjoint=adjoint)
    return _adaptive_filter_jit(ode, solver, y0, t_final, controller, ts, dtmin, max_steps, adjoint)


DEFAULT_RTOL, DEFAULT_ATOL = 1e-6, 1e-9
DEFAULT_MAX_STEPS = 100_000


def refuse_with_dt(dt, **options) -> None:
    """Error control's options (not None) cannot be combined with a uniform mesh ``dt``."""
    for name, value in options.items():
        if value is not None:
            raise ValueError(f"{name} applies to error control (dt=None); it cannot be combined with dt={dt!r}")


def check_error_control(t_final, rtol, atol, dtmin, max_steps) -> tuple[float, float]:
    """Error control's options, checked before anything compiles; returns (rtol, atol) with defaults."""
    check_positive("t_final", t_final)
    rtol = DEFAULT_RTOL if rtol is None else rtol
    atol = DEFAULT_ATOL if atol is None else atol
    check_tolerance("rtol", rtol, upper=1.0)
    check_tolerance("atol", atol)
    if dtmin is not None:
        check_positive("dtmin", dtmin)
    check_max_steps(max_steps)
    return float(rtol), float(atol)


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
    max_steps: int = DEFAULT_MAX_STEPS,
    adjoint: str = "reverse",
    solver: AlphaMethod | None = None,
    truncation: int | None = None,
    checkpoint_every: int | str | None = None,
) -> Solution:
    """Integrate the homogenized peeling ODE (eq. ``hv``) with the α-method.

    Two modes share the α-method's step (:mod:`peeljax.integrators.alpha`):

    * ``dt=None`` (default): error control (:func:`~peeljax.integrators.adaptive.integrate_alpha_adaptive`),
      a step size chosen by a PI controller so that each step's local error estimate is
      within ``rtol``/``atol``; output at ``ts`` by cubic Hermite interpolation.
    * ``dt`` a number: the uniform mesh of the paper (:func:`peeljax.integrate_alpha`).

    Args:
        model: spool, tape and adhesion law (default: the paper's, ``PeelingModel()``).
        V: pull velocity [m/s], > 0.
        tau: homogenization time scale τ [s], > 0.
        dt: None for error control; else the requested uniform step [s]: the mesh has
            N = round(t_final/dt) steps of t_final/N (``result.stats["step_size"]``), so it
            ends exactly at t_final.
        t_final: end time [s], > 0 (≥ dt).
        rho: the α-method's ρ ∈ [0, 1) (ignored when ``solver`` is given).
        y0: initial (α, ω, u, v) with v > 0 (default: the paper's consistent data,
            :meth:`PeelingModel.initial_state`).
        solver: an :class:`AlphaMethod` to set Newton tolerances and safeguards.
        truncation: ``None`` for the exact J_t, m ≥ 1 for the m-term eq. ``hvex``, 0 for the
            τ → 0 index-1 ODE.
        rtol, atol: error control only (default 1e-6 and 1e-9): relative tolerance in
            (0, 1) and absolute tolerance > 0 of the weighted RMS error norm; log v is
            weighted by rtol alone (a relative error of v). Giving either with ``dt`` is an error.
        ts: error control only: output times in [0, t_final], increasing. None: the
            accepted step points, in ``max_steps + 1`` rows NaN-padded (``valid`` False).
        dtmin: error control only: a proposed step below it stops the run with "step size
            collapsed" (default 1e-12·t_final).
        max_steps: error control only: most step attempts (accepted + rejected; static).
            Reaching it stops the run with its own reason.
        adjoint: error control only: ``"reverse"`` (default; a checkpointed while loop, for
            ``jax.grad``) or ``"forward"`` (a plain while loop, for ``jax.jvp``/``jacfwd``).
        checkpoint_every: uniform mesh only, for reverse-mode gradients of long runs: chunks
            of this many steps under ``jax.checkpoint`` (``"sqrt"``: ≈ √N), memory ∝ √N (see
            :func:`peeljax.integrate_alpha`); values are unchanged.

    Returns:
        A :class:`Solution`. Uniform mesh: N + 1 time points. Error control: the points of
        ``ts``, or the accepted steps; ``stats`` has ``accepted_steps``, ``rejected_steps``
        and the smallest, mean and largest step. A run that cannot continue has
        ``status != 0``, ``t_stop`` and ``reason``; its later states are NaN.

    V, tau, rho, y0, the model's parameters and the adhesion coefficients are traced: ``jit``,
    ``vmap`` and ``grad`` work over them without recompiling. ``dt`` and ``t_final`` set the
    mesh's shape and must be Python numbers. Input is checked before compilation.
    """
    if dt is not None:
        refuse_with_dt(dt, rtol=rtol, atol=atol, ts=ts, dtmin=dtmin)
        n_steps = check_mesh(dt, t_final)
        solver = checked_solver(solver, rho)
        ode, y0 = _prepare(model, V, tau, y0, truncation)
        return _run_alpha(ode, solver, y0, jnp.asarray(t_final, float), n_steps, checkpoint_every)
    if checkpoint_every is not None:
        raise ValueError(
            "checkpoint_every applies to the uniform mesh (dt given); error control checkpoints its loop itself"
        )
    rtol, atol = check_error_control(t_final, rtol, atol, dtmin, max_steps)
    if adjoint not in ("reverse", "forward"):
        raise ValueError(f"adjoint must be 'reverse' or 'forward', got {adjoint!r}")
    ts = None if ts is None else check_output_times(ts, t_final)
    solver = checked_solver(solver, rho)
    ode, y0 = _prepare(model, V, tau, y0, truncation)
    controller = _controller(rtol, atol)
    t_final = float_array(t_final)
    dtmin = 1e-12 * t_final if dtmin is None else float_array(dtmin)
    return _run_adaptive(ode, solver, y0, t_final, controller, ts, dtmin, max_steps, adjoint)


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
) -> Solution:
    """The same problem with diffrax (Kvaerno5 by default), output on the α-method's grid.

    ``dt`` sets only the output grid (N = round(t_final/dt) intervals), or ``ts`` (with
    ``dt=None``) gives the output times; the steps are adaptive with a PID controller at
    ``rtol``/``atol``. A collapsing step (< ``dtmin``, default
    1e-12·t_final) stops the run with status ``STALLED``.
    """
    if (ts is None) == (dt is None):
        raise ValueError("simulate_reference: give the output grid either as dt or as ts (with dt=None)")
    if ts is None:
        n_steps = check_mesh(dt, t_final)
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
    ode, y0 = _prepare(model, V, tau, y0, truncation)
    solver = diffrax.Kvaerno5() if solver is None else solver
    dtmin = 1e-12 * float(t_final) if dtmin is None else dtmin
    return _run_reference(ode, y0, ts, solver, jnp.asarray(rtol), jnp.asarray(atol), jnp.asarray(dtmin), max_steps)
