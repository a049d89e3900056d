"""Steppers: one step of a method, as a part of the one error-controlled loop.

The loop (:func:`peeljax.integrators.adaptive.adaptive_loop`) owns the step-size control,
the fold events, the jumps, the observers and the stops; a stepper owns what one step of its
method is:

* :meth:`AbstractStepper.start`: the ODE in the stepper's carried coordinates (log v for the
  homogenized ODE) and the state at t0;
* :meth:`AbstractStepper.attempt`: one step of size h → the candidate state, its local error
  estimate, the step's dense output (an interpolant over [t, t + h]) and whether it solved;
* :meth:`AbstractStepper.restart`: the state to go on from after a jump of v (a new start);
* ``order``: the order q of the local error estimate (err ∝ h^q), the controller's exponent.

Two steppers:

* :class:`AlphaStepper`: the paper's α-method (:class:`~peeljax.AlphaMethod`), second order,
  implicit; error estimate C·h²·(a_{n+1} − a_n) (q = 3); cubic Hermite dense output; Newton
  with a kept matrix (a chord iteration, refreshed on failure and every ``jacobian_max_age``
  steps).
* :class:`RungeKutta`: any diffrax Runge–Kutta solver through diffrax's public solver
  interface (``init``, ``step`` → y₁, error estimate, dense info; ``interpolation_cls``):
  explicit (``Tsit5``, ``Dopri5``, ``Dopri8``) or implicit ESDIRK (``Kvaerno3/4/5``), with the
  fold events located on that solver's own interpolant.

:func:`stepper_named` maps the names of :data:`STEPPER_NAMES` to steppers.
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from diffrax._root_finder import use_stepsize_tol  # diffrax's marker: "the controller's tolerances"
from jaxtyping import Array, Float

from .._arrays import optional_float_array
from ..solution import StopReason
from .alpha import AlphaMethod, AlphaState, _stop_gradient, alpha_start
from .log_variables import LogTransformedODE, from_log, log_mask, to_log
from .dense import HermiteInterpolant, SolverInterpolant

__all__ = [
    "STEPPER_NAMES",
    "AbstractStepper",
    "AlphaStepper",
    "Attempt",
    "RungeKutta",
    "StepperState",
    "alpha_attempt",
    "as_stepper",
    "error_constant",
    "stepper_named",
]

# The Runge–Kutta methods of diffrax a user can name (CLI --method, solver="tsit5").
_DIFFRAX_METHODS = {
    "tsit5": diffrax.Tsit5,
    "dopri5": diffrax.Dopri5,
    "dopri8": diffrax.Dopri8,
    "kvaerno3": diffrax.Kvaerno3,
    "kvaerno4": diffrax.Kvaerno4,
    "kvaerno5": diffrax.Kvaerno5,
}
STEPPER_NAMES: tuple[str, ...] = ("alpha", *_DIFFRAX_METHODS)


class StepperState(eqx.Module):
    """A stepper's state between steps (carried coordinates).

    Attributes:
        y: the state; psi: ψ(y) where the stepper has it (the α-method), else zeros.
        J, drive: J_t and F̃·f at y where the ODE needs them (its stop test or fold event is
            J_t: the homogenized ODE), else NaN.
        status: 0, or ``NONFINITE`` for a start that is not finite.
        inner: the method's own (the α-method's a and Newton matrix; diffrax's solver state).
    """

    y: Array
    psi: Array
    J: Array
    drive: Array
    status: Array
    inner: Any


class Attempt(eqx.Module):
    """One step attempt: ``candidate`` is kept where the loop accepts it, ``retained`` (the
    incoming state, with the method's bookkeeping of this attempt) where it does not.

    ``retry``: the attempt failed in a way the same h may cure (the α-method's Newton with a
    kept matrix): retry at the same h. ``interpolant``: the step's dense output on [t, t + h].
    """

    candidate: StepperState
    retained: StepperState
    error: Array
    solved: Array
    retry: Array
    iterations: Array
    interpolant: Any


class AbstractStepper(eqx.Module):
    """One step of a method, for the error-controlled loop (module docstring).

    ``cuts_at_folds``: after an attempt rejected over a fold of the DAE, the loop retries
    up to just past the fold located on that attempt's interpolant (measured on P6: fewer
    attempts per fold for Tsit5; no change for the α-method, which keeps its controller's h).
    """

    cuts_at_folds: ClassVar[bool] = False

    @property
    @abc.abstractmethod
    def order(self) -> int:
        """q of the local error estimate ∝ h^q (static)."""

    @property
    @abc.abstractmethod
    def carried_log(self) -> tuple[int, ...]:
        """Components carried as their logarithm (log v)."""

    @property
    @abc.abstractmethod
    def name(self) -> str:
        """``Solution.method`` of a run with this stepper."""

    @abc.abstractmethod
    def start(self, ode, t0, y0) -> tuple[Any, StepperState]:
        """(The ODE in carried coordinates, the state at t0.)"""

    @abc.abstractmethod
    def attempt(self, ode, t, h, state: StepperState, weights) -> Attempt:
        """One step of size h from ``state`` at t; ``weights``: the error norm's scale."""

    @abc.abstractmethod
    def restart(self, ode, t, y, state: StepperState) -> StepperState:
        """The state to go on from at (t, y) after a jump (carried coordinates)."""

    def step_factor(self, controller, state: StepperState, norm, prev_norm, accept, solved) -> Array:
        """h_next/h after an attempt from ``state`` (:meth:`PIController.factor` with this
        stepper's error order; a switching stepper's order depends on ``state``)."""
        return controller.factor(norm, prev_norm, accept, solved, self.order)

    def for_loop(self, controller, kind: str) -> "AbstractStepper":
        """The stepper as the loop runs it, with the controller's tolerances and the loop's kind."""
        return self

    def statistics(self, state: StepperState) -> dict[str, Array]:
        """Method-specific counts for ``Solution.stats``."""
        return {}

    @abc.abstractmethod
    def settings(self) -> dict:
        """JSON-able settings (recorded with a sweep's results)."""


def _carried(ode, log_components: tuple[int, ...]):
    return LogTransformedODE(ode, log_components) if log_components else ode


def _needs_schur(ode) -> bool:
    """Whether the loop reads J_t and F̃·f at every step end: the homogenized ODE's impasse
    test and fold event are J_t (static)."""
    return bool(getattr(ode, "fold_event_is_schur", False) or getattr(ode, "stops_at_impasse", False))


# --------------------------------------------------------------------------- the α-method
def error_constant(rho) -> Array:
    """C = b/2 + (1/2 − b)(1/2 − γ) − 1/6 of the α-method's local error C·h³·y‴ (1/3 at ρ = 0)."""
    rho = jnp.asarray(rho, float)
    gamma = 2.0 / (rho + 1.0) - 0.5
    b = (1.0 / (rho + 1.0) ** 2) / gamma
    return b / 2 + (0.5 - b) * (0.5 - gamma) - 1.0 / 6.0


def alpha_attempt(ode, solver: AlphaMethod, state: AlphaState, h, chord=None) -> tuple[AlphaState, Array, Array, Array]:
    """One α-method step of size h from ``state`` (carried coordinates) and its error estimate.

    The step is :meth:`AlphaMethod.solve_step`, the one the uniform mesh takes. Returns
    (candidate state, error estimate e = C·h²·(a_{n+1} − a_n), solved, Newton iterations).
    ``solved`` is False when Newton did not converge or the result is not finite; the
    candidate then keeps the incoming ψ, a, J and F̃·f (finite, never used). The candidate's
    status is 0; the stop tests are the loop's. ``chord``: see :meth:`AlphaMethod.solve_step`
    (None: full Newton with a fresh Jacobian every iteration).
    """
    z, evaluation, a_new, iterations, _, converged, _ = solver.solve_step(ode, state, h, chord=chord)
    finite = jnp.all(jnp.isfinite(evaluation.psi)) & jnp.all(jnp.isfinite(a_new)) & jnp.isfinite(evaluation.J)
    solved = converged & finite
    new = AlphaState(
        y=solver._to_state(z),
        psi=jnp.where(solved, evaluation.psi, state.psi),
        a=jnp.where(solved, a_new, state.a),
        J=jnp.where(solved, evaluation.J, state.J),
        drive=jnp.where(solved, evaluation.drive, state.drive),
        status=jnp.zeros((), jnp.int32),
    )
    error = error_constant(solver.rho) * h**2 * (new.a - state.a)
    return new, error, solved, iterations


class _AlphaInner(eqx.Module):
    a: Array
    parts: tuple[Array, Array]  # (∂y/∂z, ∂ψ/∂z) of the kept Newton matrix
    parts_fresh: Array  # computed at the current state
    refresh: Array  # recompute them before the next attempt
    parts_age: Array  # accepted steps since they were computed
    jacobian_evaluations: Array


class AlphaStepper(AbstractStepper):
    """The α-method's step (:meth:`AlphaMethod.solve_step`) with its error estimate
    C·h²·(a_{n+1} − a_n) (q = 3, :func:`peeljax.integrators.adaptive.error_constant`) and the
    cubic Hermite interpolant of the step as its dense output."""

    method: AlphaMethod = AlphaMethod()

    @property
    def order(self) -> int:
        return 3

    @property
    def carried_log(self) -> tuple[int, ...]:
        return self.method.carried_log

    @property
    def name(self) -> str:
        return "alpha-adaptive"

    def _inner(self, n, a, refresh=True):
        zero = jnp.asarray(0, jnp.int32)
        return _AlphaInner(
            a=a, parts=(jnp.eye(n), jnp.zeros((n, n))), parts_fresh=jnp.asarray(False), refresh=jnp.asarray(refresh),
            parts_age=zero, jacobian_evaluations=zero,
        )  # fmt: skip

    def start(self, ode, t0, y0):
        ode, s = alpha_start(ode, self.method, y0)
        return ode, StepperState(s.y, s.psi, s.J, s.drive, s.status, self._inner(s.y.shape[0], s.a))

    def attempt(self, ode, t, h, state, weights):
        solver, inner = self.method, state.inner
        z_n = jax.lax.stop_gradient(solver._to_unknown(state.y))
        parts = jax.lax.cond(inner.refresh, lambda: solver.linearize(_stop_gradient(ode), z_n), lambda: inner.parts)
        fresh = inner.refresh | inner.parts_fresh
        age = jnp.where(inner.refresh, 0, inner.parts_age)
        chord = (parts, weights, solver.newton_kappa, solver.chord_iterations)
        alpha_state = AlphaState(state.y, state.psi, inner.a, state.J, state.drive, state.status)
        new, error, solved, iterations = alpha_attempt(ode, solver, alpha_state, h, chord)
        retry = ~solved & ~fresh  # a Newton failure with a kept matrix: the same h with a fresh one
        evaluations = inner.jacobian_evaluations + inner.refresh
        candidate = StepperState(
            new.y, new.psi, new.J, new.drive, new.status,
            _AlphaInner(new.a, parts, jnp.asarray(False), age + 1 >= solver.jacobian_max_age, age + 1, evaluations),
        )  # fmt: skip
        retained = eqx.tree_at(
            lambda s: s.inner, state, _AlphaInner(inner.a, parts, fresh, retry, age, evaluations)
        )
        interpolant = HermiteInterpolant(t, h, state.y, state.psi, new.y, new.psi)
        return Attempt(candidate, retained, error, solved, retry, iterations, interpolant)

    def restart(self, ode, t, y, state):
        after = ode.evaluate(y)
        # a restarts as dψ/dt at the new state, differentiated like the rest of the jump.
        a = self.method.initial_acceleration(ode, y, after.psi)
        inner = self._inner(y.shape[0], jnp.where(jnp.isfinite(a), a, 0.0))
        inner = eqx.tree_at(lambda i: i.jacobian_evaluations, inner, state.inner.jacobian_evaluations)
        return StepperState(y, after.psi, after.J, after.drive, state.status, inner)

    def statistics(self, state):
        return {"jacobian_evaluations": state.inner.jacobian_evaluations}

    def settings(self) -> dict:
        return self.method.settings()


# --------------------------------------------------------------------------- diffrax's Runge–Kutta methods
def _vector_field(t, y, ode):
    return ode.evaluate(y).psi


_TERM = diffrax.ODETerm(_vector_field)


class RungeKutta(AbstractStepper):
    """A diffrax Runge–Kutta solver's step (``solver.step``), its embedded error estimate and
    its own interpolant (``solver.interpolation_cls``), for the one loop.

    Attributes:
        solver: a ``diffrax.AbstractRungeKutta`` (explicit, e.g. ``Tsit5()``, or ESDIRK,
            e.g. ``Kvaerno5()``).
        log_components: components carried as their logarithm (default v: the homogenized
            ODE from the paper's start, v0 = 1e-10·V, is smooth in log v only); ``()`` for
            the DAE in time, whose v is solved from the constraint, never integrated.
        time_scale: None, or ε [s]: the DAE (a :class:`~peeljax.ConstrainedDAE`) is integrated
            in pseudo-time (:class:`~peeljax.DesingularizedDAE`, its folds regular points, t a
            fifth carried component), with log v carried (``log_components`` (3,)).
    """

    cuts_at_folds: ClassVar[bool] = True
    solver: diffrax.AbstractSolver = diffrax.Tsit5()
    log_components: tuple[int, ...] = eqx.field(static=True, default=(3,))
    time_scale: Float[Array, ""] | None = eqx.field(converter=optional_float_array, default=None)

    def __check_init__(self):
        if not isinstance(self.solver, diffrax.AbstractRungeKutta):
            raise TypeError(
                f"solver must be a diffrax Runge-Kutta solver (Tsit5, Dopri5, Dopri8, Kvaerno3/4/5, ...), "
                f"got {type(self.solver).__name__}"
            )

    @property
    def order(self) -> int:
        return int(self.solver.order(_TERM))

    @property
    def carried_log(self) -> tuple[int, ...]:
        return self.log_components

    @property
    def name(self) -> str:
        return f"diffrax-{type(self.solver).__name__}"

    def with_tolerances(self, rtol, atol) -> "RungeKutta":
        """An implicit solver's Newton tolerances left to the step-size controller's (diffrax's
        ``use_stepsize_tol``), filled in as ``diffeqsolve`` does; other solvers unchanged."""
        if not isinstance(self.solver, diffrax.AbstractImplicitSolver):
            return self
        finder = self.solver.root_finder
        values = {"rtol": jnp.asarray(rtol), "atol": jnp.asarray(atol), "norm": optx.rms_norm}
        names = [name for name in values if getattr(finder, name, None) is use_stepsize_tol]
        if not names:
            return self
        return eqx.tree_at(
            lambda r: tuple(getattr(r.solver.root_finder, name) for name in names),
            self,
            tuple(values[name] for name in names),
            is_leaf=lambda x: x is use_stepsize_tol,
        )

    def with_loop_kind(self, kind: str) -> "RungeKutta":
        """The solver's loop over its stages to match the step loop: a plain ``lax`` loop
        under a forward-only run (diffrax's default, a checkpointed loop, costs ~2× per step
        here), ``"bounded"`` (reverse-differentiable) under the checkpointed one."""
        if self.solver.scan_kind is not None:
            return self
        return eqx.tree_at(
            lambda r: r.solver.scan_kind, self, "lax" if kind == "lax" else "bounded", is_leaf=lambda x: x is None
        )

    def for_loop(self, controller, kind: str) -> "RungeKutta":
        return self.with_tolerances(controller.rtol, controller.atol).with_loop_kind(kind)

    def _ends(self, ode, y):
        """(ψ, J, F̃·f) at a step's end where the ODE's tests read J_t; placeholders otherwise."""
        if _needs_schur(ode):
            evaluation = ode.evaluate(y)
            return jnp.zeros_like(y), evaluation.J, evaluation.drive
        nan = jnp.full((), jnp.nan, y.dtype)
        return jnp.zeros_like(y), nan, nan

    def start(self, ode, t0, y0):
        y0 = jnp.asarray(y0, float)
        if self.time_scale is not None:
            if not hasattr(ode, "in_pseudo_time"):
                raise TypeError(f"time_scale: pseudo-time needs the DAE (ConstrainedDAE), got {type(ode).__name__}")
            if getattr(ode, "folds", None) is not None:
                y0 = ode.complete(y0)  # v on its stable branch, as the DAE in time starts
            ode = ode.in_pseudo_time(self.time_scale)
            y0 = ode.extend(y0, t0)
        positive = jnp.all(jnp.where(log_mask(y0.shape[0], self.log_components), y0 > 0, True))
        ode = _carried(ode, self.log_components)
        z0 = to_log(y0, self.log_components) if self.log_components else y0
        psi = ode.evaluate(z0).psi
        _, J, drive = self._ends(ode, z0)
        ok = positive & jnp.all(jnp.isfinite(psi)) & jnp.all(jnp.isfinite(z0))
        status = jnp.where(ok, 0, StopReason.NONFINITE).astype(jnp.int32)
        inner = self.solver.init(_TERM, t0, t0 + 1.0, z0, ode)
        return ode, StepperState(z0, psi, J, drive, status, inner)

    def attempt(self, ode, t, h, state, weights):
        y1, error, dense, inner, result = self.solver.step(_TERM, t, t + h, state.y, ode, state.inner, False)
        solved = (result == diffrax.RESULTS.successful) & jnp.all(jnp.isfinite(y1)) & jnp.all(jnp.isfinite(error))
        y1 = jnp.where(solved, y1, state.y)  # finite values and derivatives where the step failed
        psi, J, drive = self._ends(ode, y1)
        candidate = StepperState(y1, psi, J, drive, state.status, inner)
        interpolant = SolverInterpolant(self.solver.interpolation_cls(t0=t, t1=t + h, **dense))
        zero = jnp.asarray(0, jnp.int32)
        return Attempt(candidate, state, error, solved, jnp.asarray(False), zero, interpolant)

    def restart(self, ode, t, y, state):
        _, J, drive = self._ends(ode, y)
        inner = self.solver.init(_TERM, t, t + 1.0, y, ode)  # FSAL: the first stage is evaluated anew
        return StepperState(y, jnp.zeros_like(y), J, drive, state.status, inner)

    def settings(self) -> dict:
        settings = {"name": type(self.solver).__name__, "log_components": list(self.log_components)}
        if self.time_scale is not None:
            settings["pseudo_time_scale"] = float(self.time_scale)
        return settings


def stepper_named(name: str, *, dae: bool = False) -> AbstractStepper:
    """The stepper of a name in :data:`STEPPER_NAMES` (``dae``: v is not carried in log form)."""
    if name not in STEPPER_NAMES:
        raise ValueError(f"solver must be one of {STEPPER_NAMES} (or a solver object), got {name!r}")
    if name == "alpha":
        return AlphaStepper(AlphaMethod(log_components=() if dae else (3,)))
    return RungeKutta(_DIFFRAX_METHODS[name](), () if dae else (3,))


def as_stepper(method) -> AbstractStepper:
    """An :class:`AlphaMethod` as its :class:`AlphaStepper`; a stepper as it is."""
    if isinstance(method, AbstractStepper):
        return method
    if isinstance(method, AlphaMethod):
        return AlphaStepper(method)
    raise TypeError(f"expected an AlphaMethod or a stepper, got {type(method).__name__}")


def physical(stepper: AbstractStepper, y: Float[Array, "... n"]) -> Float[Array, "... m"]:
    """Carried states (log v; the time of a run in pseudo-time) back to y = (α, ω, u, v)."""
    y = from_log(y, stepper.carried_log) if stepper.carried_log else y
    return y[..., :-1] if getattr(stepper, "time_scale", None) is not None else y
