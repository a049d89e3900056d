"""From the user's options to an integrator, checked before anything compiles.

:func:`integrator_for` is the one place where ``solver``, ``dt``, ``rtol``, ``atol``,
``dtmin``, ``max_steps`` and ``adjoint`` of :func:`peeljax.simulate`, :func:`peeljax.sweep`,
:func:`peeljax.least_tau` and :func:`peeljax.fit_adhesion` become an integrator
(:mod:`peeljax.integrators.base`):

===========================================  ==========  ==============================================
``solver``                                   ``dt``      integrator
===========================================  ==========  ==============================================
None, ``"alpha"`` or an :class:`AlphaMethod`  a number    :class:`UniformMesh` (the paper's mesh)
None or a name of ``SOLVER_NAMES``           None        :class:`ErrorControl` with that stepper
an :class:`AlphaMethod`                      None        :class:`ErrorControl` (the α-method)
a diffrax Runge–Kutta solver (``Tsit5()``)   None        :class:`ErrorControl` (:class:`RungeKutta`)
another ``diffrax.AbstractSolver``           None        :class:`DiffraxIntegrator` (diffrax's own loop)
===========================================  ==========  ==============================================

Every stepper of the one error-controlled loop goes through the folds of φ: ``fold`` says
what happens there (:mod:`peeljax.integrators.events`): ``"jump"`` (the default under error
control: v jumps to the other stable branch and the run goes on), ``"stop"`` (the paper's
behaviour; the default, and the only choice, on the uniform mesh and with a diffrax solver
that is not a Runge–Kutta method, whose steps diffrax's own loop takes) or ``"follow"``
(τ > 0 only). ``dae=True`` (τ = 0: the DAE itself, :class:`~peeljax.ConstrainedDAE`) needs
error control; the stepper then carries v as it is (v = 0 on a fully stuck tape).

The default stepper (``solver=None``, ρ = 0) is measured per problem (docs/theory.md,
"Choosing the stepper"): τ = 0 Tsit5 in pseudo-time; τ > 0 ``"auto"``, Tsit5 switching to the
α-method where the homogenized ODE turns stiff (:mod:`.switching`). A ρ ≠ 0 is the α-method's.
"""

from __future__ import annotations

import dataclasses
import functools

import diffrax
import numpy as np
from jaxtyping import ArrayLike

from .._validation import (
    TAU_MAX,
    check_adjoint,
    check_max_steps,
    check_mesh,
    check_positive,
    check_rho,
    check_tolerance,
    is_concrete,
)
from .adaptive import ErrorControl
from .alpha import AlphaMethod
from .uniform_mesh import UniformMesh
from .base import AbstractIntegrator
from .controller import PIController
from .events import FoldEvents, check_fold, check_max_jumps
from .reference import DiffraxIntegrator
from ..desingularized import DEFAULT_TIME_SCALE
from .steppers import STEPPER_NAMES, AbstractStepper, RungeKutta, stepper_named
from .switching import SwitchingStepper

__all__ = [
    "DEFAULT_ATOL",
    "DEFAULT_DAE_STEPPER",
    "DEFAULT_ODE_STEPPER",
    "DEFAULT_MAX_JUMPS",
    "DEFAULT_MAX_STEPS",
    "DEFAULT_MAX_STEPS_DENSE",
    "DEFAULT_RTOL",
    "SOLVER_NAMES",
    "STEPPER_NAMES",
    "check_error_control",
    "checked_solver",
    "integrator_for",
    "refuse_with_dt",
    "resolve_fold",
    "resolve_max_steps",
]

DEFAULT_RTOL, DEFAULT_ATOL = 1e-6, 1e-9
DEFAULT_MAX_STEPS = 100_000  # where every accepted step is kept (output at the steps: max_steps + 1 rows)
# Where nothing is kept per step (output at given times, a sweep's lanes) the budget only
# guards against a run that never ends: 10⁷ attempts is ~1 min of Tsit5 on the DAE.
DEFAULT_MAX_STEPS_DENSE = 10_000_000


def resolve_max_steps(max_steps: int | None, keeps_steps: bool) -> int:
    """``max_steps``, or its default: ``DEFAULT_MAX_STEPS`` where the accepted steps are the
    output (memory grows with it), ``DEFAULT_MAX_STEPS_DENSE`` where nothing is kept per step."""
    if max_steps is None:
        return DEFAULT_MAX_STEPS if keeps_steps else DEFAULT_MAX_STEPS_DENSE
    check_max_steps(max_steps)
    return max_steps
# The jump record's size where it cannot grow (traced: under jit, vmap, grad); eagerly
# simulate starts smaller and grows (peeljax.simulate.FIRST_MAX_JUMPS).
DEFAULT_MAX_JUMPS = 10_000
# The default stepper of the DAE (τ = 0) and of the homogenized ODE (τ > 0), chosen by
# measurement (docs/theory.md, "Choosing the stepper"); ρ ≠ 0 (an α-method setting) keeps the α-method.
DEFAULT_DAE_STEPPER = "tsit5"
DEFAULT_ODE_STEPPER = "auto"
# "auto": Tsit5 ↔ the α-method where the homogenized ODE turns stiff (τ > 0, :mod:`.switching`);
# at τ = 0 the DAE's default stepper.
SOLVER_NAMES: tuple[str, ...] = ("auto", *STEPPER_NAMES)


@functools.lru_cache(maxsize=64)
def _default_solver(rho: float) -> AlphaMethod:
    return AlphaMethod(rho=rho)


def checked_solver(solver, rho: ArrayLike = 0.0):
    """``solver`` as a method of the loop (an :class:`AlphaMethod` or a :class:`RungeKutta`),
    or a diffrax solver for diffrax's own loop; ``AlphaMethod(rho=rho)`` when it is None; ρ
    checked (before compiling)."""
    if solver is None or (isinstance(solver, str) and solver == "alpha"):
        check_rho(rho)
        # Modules are immutable: one per ρ serves every call, instead of one built per call.
        return _default_solver(float(rho)) if type(rho) in (float, int) else AlphaMethod(rho=rho)
    if isinstance(solver, str):
        if solver not in SOLVER_NAMES:
            raise ValueError(f"solver must be one of {list(SOLVER_NAMES)} or a solver object, got {solver!r}")
        return _named(solver)
    if isinstance(solver, AlphaMethod):
        check_rho(solver.rho)
        return solver
    if isinstance(solver, AbstractStepper):
        return solver
    if isinstance(solver, diffrax.AbstractRungeKutta):
        return RungeKutta(solver)
    if isinstance(solver, diffrax.AbstractSolver):
        return solver
    raise TypeError(
        f"solver must be one of {list(SOLVER_NAMES)}, an AlphaMethod or a diffrax solver, got {type(solver).__name__}"
    )


@functools.lru_cache(maxsize=16)
def _named(name: str):
    if name == "auto":
        return SwitchingStepper()
    stepper = stepper_named(name)
    return stepper.method if name == "alpha" else stepper


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
        if is_concrete(dtmin) and is_concrete(t_final) and np.ndim(dtmin) == 0 and float(dtmin) >= float(t_final):
            raise ValueError(
                f"dtmin must be < t_final (it is the smallest step, allowed range: (0, {float(t_final):g})), "
                f"got {float(dtmin):g}"
            )
    check_max_steps(max_steps)
    return float(rtol), float(atol)


@functools.lru_cache(maxsize=64)
def _controller(rtol: float, atol: float) -> PIController:
    return PIController(rtol=rtol, atol=atol)


@functools.lru_cache(maxsize=64)
def _error_control(rho, rtol, atol, dtmin, max_steps, adjoint, fold, max_jumps, dae, merge, folds_later) -> ErrorControl:
    # The default method's integrator, built once per setting rather than on every call.
    method = _named(DEFAULT_ODE_STEPPER) if rho == 0.0 and not dae else _default_solver(rho)
    integrator = ErrorControl(method, _controller(rtol, atol), dtmin, max_steps, adjoint)
    return _with_events(integrator, fold, max_jumps, dae, merge=merge, folds_at_first_jump=folds_later)


@functools.lru_cache(maxsize=64)
def _error_control_dae(rtol, atol, dtmin, max_steps, adjoint, fold, max_jumps, merge) -> ErrorControl:
    # τ = 0's default stepper (measured: docs/theory.md, "Choosing the stepper").
    stepper = _named(DEFAULT_DAE_STEPPER)
    integrator = ErrorControl(stepper, _controller(rtol, atol), dtmin, max_steps, adjoint)
    return _with_events(integrator, fold, max_jumps, True, pseudo_time=True, merge=merge)


def _with_events(
    integrator: ErrorControl, fold: str, max_jumps: int, dae: bool, pseudo_time: bool = False, merge: bool = True,
    folds_at_first_jump: bool = False,
) -> ErrorControl:
    """The integrator with its fold events. For the DAE (``dae``) an explicit Runge–Kutta
    stepper runs in pseudo-time where ``pseudo_time`` (it was named, or given as a diffrax
    solver: the default formulation, measured in docs/theory.md) and as given otherwise (a
    :class:`RungeKutta` of the user's). Implicit ones (Kvaerno) run in time: in pseudo-time
    their Newton iteration fails at the paper's first slip, a folded singularity where the
    pseudo-time field's Jacobian is unbounded. In time, v is carried as it is (solved from the
    constraint, never integrated)."""
    method = integrator.method
    explicit = isinstance(method, RungeKutta) and not isinstance(method.solver, diffrax.AbstractImplicitSolver)
    if dae and explicit and method.time_scale is None and pseudo_time:
        method = dataclasses.replace(method, log_components=(3,), time_scale=DEFAULT_TIME_SCALE)
    elif dae and not (isinstance(method, RungeKutta) and method.time_scale is not None):
        method = dataclasses.replace(method, log_components=())
    events = FoldEvents(fold, max_jumps, folds_at_first_jump=folds_at_first_jump)
    return dataclasses.replace(integrator, method=method, events=events, merge_jump_rows=merge)


def _own_loop(solver) -> bool:
    """A diffrax solver that diffrax's own loop runs (not a Runge–Kutta method of the one loop)."""
    return isinstance(solver, diffrax.AbstractSolver) and not isinstance(solver, diffrax.AbstractRungeKutta)


def resolve_fold(fold: str | None, *, dt=None, solver=None, dae: bool = False) -> str:
    """``fold`` checked against the integrator it will run on; None → its default (module docstring)."""
    diffrax_solver = _own_loop(solver)
    if dae and (dt is not None or diffrax_solver):
        what = f"dt={dt!r} (a uniform mesh)" if dt is not None else f"a diffrax solver ({type(solver).__name__})"
        remedy = "drop dt" if dt is not None else "give a Runge-Kutta solver (e.g. 'kvaerno5')"
        raise ValueError(
            f"tau=0 (the DAE with jumps at the folds of phi) runs in the error-controlled loop (the alpha-method or "
            f"a diffrax Runge-Kutta solver), not on {what}: {remedy}, or give tau in (0, {TAU_MAX:g}] (the "
            "homogenized ODE)"
        )
    if fold is None:
        return "stop" if dt is not None or diffrax_solver else "jump"
    check_fold(fold)
    if fold != "stop" and (dt is not None or diffrax_solver):
        what = f"dt={dt!r} (a uniform mesh)" if dt is not None else f"a diffrax solver ({type(solver).__name__})"
        raise ValueError(
            f"fold={fold!r} needs the error-controlled loop (the alpha-method or a diffrax Runge-Kutta solver), "
            f"which cuts a step at a fold; {what} can only stop there: give fold='stop', or drop dt/solver"
        )
    if fold == "follow" and dae:
        raise ValueError("fold='follow' applies to tau > 0 (the homogenized ODE's singular passages); with tau=0 use 'jump' or 'stop'")
    return fold


def integrator_for(
    solver: str | AlphaMethod | RungeKutta | diffrax.AbstractSolver | None = None,
    *,
    rho: ArrayLike = 0.0,
    dt: float | None = None,
    t_final: float = 3.0,
    rtol: float | None = None,
    atol: float | None = None,
    dtmin: float | None = None,
    max_steps: int | None = DEFAULT_MAX_STEPS,
    adjoint: str = "reverse",
    checkpoint_every: int | str | None = None,
    fold: str | None = None,
    max_jumps: int = DEFAULT_MAX_JUMPS,
    dae: bool = False,
    merge_jump_rows: bool = True,
    folds_at_first_jump: bool = False,
) -> AbstractIntegrator:
    """The integrator the options describe (module docstring), every option checked.

    Raises ``ValueError``/``TypeError`` naming the option and its allowed values; nothing is
    compiled. ``rho`` is used only when ``solver`` is None. ``merge_jump_rows=False``: the
    jumps' rows come back apart (``Solution.jump_sides``) for the caller to merge (simulate).
    ``folds_at_first_jump``: for a run that is neither batched nor differentiated
    (:class:`~peeljax.integrators.events.FoldEvents`).
    """
    check_adjoint(adjoint)
    check_max_jumps(max_jumps)
    if isinstance(solver, str) and solver == "auto" and dae:
        solver = None  # τ = 0: the DAE's default stepper
    max_steps = resolve_max_steps(max_steps, keeps_steps=True)
    fold = resolve_fold(fold, dt=dt, solver=solver, dae=dae)
    method = checked_solver(solver, rho)
    if dt is not None:
        refuse_with_dt(dt, rtol=rtol, atol=atol, dtmin=dtmin)
        if not isinstance(method, AlphaMethod):
            raise ValueError(
                f"dt (a uniform mesh) is the α-method's; {type(method).__name__} runs with "
                "error control: give rtol/atol instead of dt"
            )
        n_steps = check_mesh(dt, t_final)
        return UniformMesh(method, n_steps, float(dt), checkpoint_every)
    if checkpoint_every is not None:
        raise ValueError(
            "checkpoint_every applies to the uniform mesh (dt given); error control checkpoints its loop itself"
        )
    rtol, atol = check_error_control(t_final, rtol, atol, dtmin, max_steps)
    dtmin = None if dtmin is None else float(dtmin)
    if _own_loop(method):
        return DiffraxIntegrator(method, rtol, atol, dtmin, None, max_steps, adjoint)
    if dae and isinstance(method, SwitchingStepper):
        raise ValueError(
            "solver: the switching stepper is the homogenized ODE's (tau > 0); with tau=0 give solver='auto' "
            "(the DAE's default stepper) or a stepper's name"
        )
    if solver is None and dae and type(rho) in (float, int) and float(rho) == 0.0:
        return _error_control_dae(rtol, atol, dtmin, max_steps, adjoint, fold, max_jumps, merge_jump_rows)
    if solver is None and type(rho) in (float, int):
        return _error_control(
            float(rho), rtol, atol, dtmin, max_steps, adjoint, fold, max_jumps, dae, merge_jump_rows, folds_at_first_jump
        )
    integrator = ErrorControl(method, _controller(rtol, atol), dtmin, max_steps, adjoint)
    return _with_events(
        integrator, fold, max_jumps, dae, pseudo_time=not isinstance(solver, RungeKutta), merge=merge_jump_rows,
        folds_at_first_jump=folds_at_first_jump,
    )
