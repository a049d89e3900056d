"""From the user's options to an integrator, checked before anything compiles.

:func:`integrator_for` is the one place where ``solver``, ``dt``, ``rtol``, ``atol``,
``dtmin``, ``max_steps`` and ``adjoint`` of :func:`peeljax.simulate`, :func:`peeljax.sweep`,
:func:`peeljax.least_tau` and :func:`peeljax.fit_adhesion` become an integrator
(:mod:`peeljax.integrators.base`):

==============================  ==========  ==========================================
``solver``                      ``dt``      integrator
==============================  ==========  ==========================================
None or an :class:`AlphaMethod`  a number    :class:`UniformMesh` (the paper's mesh)
None or an :class:`AlphaMethod`  None        :class:`ErrorControl` (rtol, atol)
a ``diffrax.AbstractSolver``     None        :class:`DiffraxIntegrator` (rtol, atol)
==============================  ==========  ==========================================

``fold`` says what happens at a fold of φ (:mod:`peeljax.integrators.events`): ``"jump"``
(the default under error control: v jumps to the other stable branch and the run goes on),
``"stop"`` (the paper's behaviour; the default, and the only choice, on the uniform mesh and
with a diffrax solver, which cannot yet cut a step at an event) or ``"follow"`` (τ > 0 only).
``dae=True`` (τ = 0: the DAE itself, :class:`~peeljax.ConstrainedDAE`) needs error control
with the α-method, which then carries v as it is (v = 0 on a fully stuck tape).
"""

from __future__ import annotations

import dataclasses
import functools

import diffrax
import numpy as np
from jaxtyping import ArrayLike

from .._validation import (
    check_adjoint,
    check_max_steps,
    check_mesh,
    check_positive,
    check_rho,
    check_tolerance,
    is_concrete,
)
from .adaptive import ErrorControl
from .alpha import AlphaMethod, UniformMesh
from .base import AbstractIntegrator
from .controller import PIController
from .events import FoldEvents, check_fold, check_max_jumps
from .reference import DiffraxIntegrator

__all__ = [
    "DEFAULT_ATOL",
    "DEFAULT_MAX_JUMPS",
    "DEFAULT_MAX_STEPS",
    "DEFAULT_RTOL",
    "check_error_control",
    "checked_solver",
    "integrator_for",
    "refuse_with_dt",
    "resolve_fold",
]

DEFAULT_RTOL, DEFAULT_ATOL = 1e-6, 1e-9
DEFAULT_MAX_STEPS = 100_000
DEFAULT_MAX_JUMPS = 10_000


@functools.lru_cache(maxsize=64)
def _default_solver(rho: float) -> AlphaMethod:
    return AlphaMethod(rho=rho)


def checked_solver(solver: AlphaMethod | diffrax.AbstractSolver | None, rho: ArrayLike = 0.0):
    """``solver``, or ``AlphaMethod(rho=rho)`` when it is None, with ρ checked (before compiling)."""
    if solver is None:
        check_rho(rho)
        # Modules are immutable: one per ρ serves every call, instead of one built per call.
        return _default_solver(float(rho)) if type(rho) in (float, int) else AlphaMethod(rho=rho)
    if isinstance(solver, AlphaMethod):
        check_rho(solver.rho)
        return solver
    if isinstance(solver, diffrax.AbstractSolver):
        return solver
    raise TypeError(f"solver must be an AlphaMethod or a diffrax.AbstractSolver, got {type(solver).__name__}")


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
def _error_control(rho, rtol, atol, dtmin, max_steps, adjoint, fold, max_jumps, dae) -> ErrorControl:
    # The default method's integrator, built once per setting rather than on every call.
    return _with_events(ErrorControl(_default_solver(rho), _controller(rtol, atol), dtmin, max_steps, adjoint), fold, max_jumps, dae)


def _with_events(integrator: ErrorControl, fold: str, max_jumps: int, dae: bool) -> ErrorControl:
    method = dataclasses.replace(integrator.method, log_components=()) if dae else integrator.method
    return dataclasses.replace(integrator, method=method, events=FoldEvents(fold, max_jumps))


def resolve_fold(fold: str | None, *, dt=None, solver=None, dae: bool = False) -> str:
    """``fold`` checked against the integrator it will run on; None → its default (module docstring)."""
    diffrax_solver = isinstance(solver, diffrax.AbstractSolver)
    if dae and (dt is not None or diffrax_solver):
        what = f"dt={dt!r} (a uniform mesh)" if dt is not None else f"a diffrax solver ({type(solver).__name__})"
        raise ValueError(
            f"tau=0 (the DAE with jumps at the folds of phi) runs on the error-controlled α-method, not on {what}"
        )
    if fold is None:
        return "stop" if dt is not None or diffrax_solver else "jump"
    check_fold(fold)
    if fold != "stop" and (dt is not None or diffrax_solver):
        what = f"dt={dt!r} (a uniform mesh)" if dt is not None else f"a diffrax solver ({type(solver).__name__})"
        raise ValueError(
            f"fold={fold!r} needs the error-controlled α-method, which cuts a step at a fold; {what} "
            "can only stop there: give fold='stop', or drop dt/solver"
        )
    if fold == "follow" and dae:
        raise ValueError("fold='follow' applies to tau > 0 (the homogenized ODE's singular passages); with tau=0 use 'jump' or 'stop'")
    return fold


def integrator_for(
    solver: AlphaMethod | diffrax.AbstractSolver | None = None,
    *,
    rho: ArrayLike = 0.0,
    dt: float | None = None,
    t_final: float = 3.0,
    rtol: float | None = None,
    atol: float | None = None,
    dtmin: float | None = None,
    max_steps: int = DEFAULT_MAX_STEPS,
    adjoint: str = "reverse",
    checkpoint_every: int | str | None = None,
    fold: str | None = None,
    max_jumps: int = DEFAULT_MAX_JUMPS,
    dae: bool = False,
) -> AbstractIntegrator:
    """The integrator the options describe (module docstring), every option checked.

    Raises ``ValueError``/``TypeError`` naming the option and its allowed values; nothing is
    compiled. ``rho`` is used only when ``solver`` is None.
    """
    check_adjoint(adjoint)
    check_max_jumps(max_jumps)
    fold = resolve_fold(fold, dt=dt, solver=solver, dae=dae)
    method = checked_solver(solver, rho)
    if dt is not None:
        refuse_with_dt(dt, rtol=rtol, atol=atol, dtmin=dtmin)
        if not isinstance(method, AlphaMethod):
            raise ValueError(
                f"dt (a uniform mesh) is the α-method's; a diffrax solver ({type(method).__name__}) runs with "
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
    if isinstance(method, diffrax.AbstractSolver):
        return DiffraxIntegrator(method, rtol, atol, dtmin, None, max_steps, adjoint)
    if solver is None and type(rho) in (float, int):
        return _error_control(float(rho), rtol, atol, dtmin, max_steps, adjoint, fold, max_jumps, dae)
    return _with_events(ErrorControl(method, _controller(rtol, atol), dtmin, max_steps, adjoint), fold, max_jumps, dae)
