"""The α-method with error control: a step size per trajectory, dense output, honest stops.

Local error estimate (derivation in ``docs/theory.md``). For y' = ψ(y) the α-method's
auxiliary variable tracks a_n ≈ y'' + (1/2 − γ)·h·y''', and the local error of a step is

    y_{n+1} − y(t_{n+1}) = C·h³·y''' + O(h⁴),   C = b/2 + (1/2 − b)(1/2 − γ) − 1/6,  b = β/γ,

(C = 1/3 at ρ = 0). Since a_{n+1} − a_n ≈ h·y''', the estimate

    e_{n+1} = C·h²·(a_{n+1} − a_n)

costs nothing beyond the step itself. It is measured against the true local error in
``tests/test_adaptive.py`` (within a factor of 2 as h → 0, on y' = λy and on the peeling ODE).

Each attempt is one α-method step of size h from (y_n, ψ_n, a_n), the step the uniform mesh
takes (:meth:`AlphaMethod.solve_step`: Newton's method, differentiated once by the implicit
function theorem). The attempt is accepted when Newton converged
and the weighted RMS norm of e is ≤ 1 (:class:`PIController`); otherwise it is retried with a
smaller h. The auxiliary variable a needs no correction when h changes: with bounded step
ratios the local error stays O(h³) (second order on a variable mesh, measured in the tests).

Stops: an accepted step across which J_t changes sign while F̃·f keeps its sign is an
impasse point (``IMPASSE``); a proposed step below ``dtmin`` stops the run with
``STALLED`` (the step size collapsed); ``max_steps`` attempts end it with ``MAX_STEPS``.

Output: at given times ``ts`` by the cubic Hermite interpolant of each step
(:func:`peeljax.integrators.dense.hermite`) in the carried coordinates (log v), mapped back
to v; or, with ``ts=None``, at the accepted step points, in ``max_steps + 1`` rows padded
with NaN (``valid`` False).

Derivatives: the loop is equinox's checkpointed while loop (reverse mode, as diffrax's
``RecursiveCheckpointAdjoint``) or a plain ``lax.while_loop`` (forward mode), chosen by
``adjoint``. Step sizes and accept/reject decisions are held constant in the derivative
(``stop_gradient`` on the controller, as diffrax does).
"""

from __future__ import annotations

from typing import ClassVar, Literal

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._arrays import optional_float_array
from .._validation import check_adjoint, check_max_steps
from ..homogenized import ODE
from ..solution import JumpRecord, Solution, StepDiagnostics, StopReason
from ..structure import local_index
from .alpha import AlphaMethod, AlphaState, _log_mask, _stop_gradient, alpha_start, to_physical
from .base import AbstractIntegrator, ObservedRun
from .controller import PIController
from .events import FoldEvents, FoldHit, find_fold, fold_event
from .observers import AcceptedStep, DenseOutput, Observer, StepPoints

__all__ = [
    "ErrorControl",
    "adaptive_loop",
    "alpha_attempt",
    "error_constant",
    "integrate_alpha_adaptive",
]


def error_constant(rho: ArrayLike) -> Array:
    """C = b/2 + (1/2 − b)(1/2 − γ) − 1/6 of the local error C·h³·y''' (1/3 at ρ = 0)."""
    rho = jnp.asarray(rho, float)
    gamma = 2.0 / (rho + 1.0) - 0.5
    b = (1.0 / (rho + 1.0) ** 2) / gamma
    return b / 2 + (0.5 - b) * (0.5 - gamma) - 1.0 / 6.0


def alpha_attempt(ode: ODE, solver: AlphaMethod, state: AlphaState, h, chord=None) -> tuple[AlphaState, Array, Array, Array]:
    """One α-method step of size h from ``state`` (carried coordinates) and its error estimate.

    The step is :meth:`AlphaMethod.solve_step`, the one the uniform mesh takes. Returns
    (candidate state, error estimate e = C·h²·(a_{n+1} − a_n), solved, Newton iterations).
    ``solved`` is False when Newton did not converge or the result is not finite; the
    candidate then keeps the incoming ψ, a, J and F̃·f (finite, never used). The candidate's
    status is 0; the stop tests are the driver's. ``chord``: see :meth:`AlphaMethod.solve_step`
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


class _Carry(eqx.Module):
    t: Array
    h: Array  # the step the controller proposes next
    state: AlphaState
    prev_norm: Array
    attempts: Array
    accepted: Array
    rejected: Array
    newton_iterations: Array
    max_newton_iterations: Array
    h_min: Array
    h_max: Array
    parts: tuple[Array, Array]  # (∂y/∂z, ∂ψ/∂z) of the kept Newton matrix
    parts_fresh: Array  # computed at the current state
    refresh: Array  # recompute them before the next attempt
    parts_age: Array  # accepted steps since they were computed
    jacobian_evaluations: Array
    record: object  # the observer's
    g: Array  # the fold event at the state (0 without events)
    jumps: JumpRecord | None  # None without events
    # The latest state of the current branch with g ≤ −_REFERENCE_DEPTH·g_scale, g_scale = |g|
    # where the branch began: where a tangential fold's time is differentiated (events module).
    reference: Array
    g_scale: Array


_REFERENCE_DEPTH = 1e-8


def _initial_step(controller: PIController, state: AlphaState, log_mask, span):
    """h0 = 0.01·min(1/‖ψ0‖, 1/√‖a0‖) in the error norm's weights (Hairer's first guess)."""
    d1 = controller.error_norm(state.psi, state.y, state.y, log_mask)
    d2 = controller.error_norm(state.a, state.y, state.y, log_mask)
    h1 = jnp.where(d1 > 0, 0.01 / jnp.where(d1 > 0, d1, 1.0), span)
    h2 = jnp.where(d2 > 0, 0.01 / jnp.sqrt(jnp.where(d2 > 0, d2, 1.0)), span)
    return jnp.minimum(jnp.minimum(h1, h2), span)


def _at_fold(events: FoldEvents, ode, solver: AlphaMethod, fold: FoldHit, new: AlphaState, t_new, g_new, jumps):
    """The step's outcome at a fold: the state to go on from, its time and event value, the
    jump record, a stop status (0, ``FOLD`` or ``MAX_JUMPS``) and the cut step's end
    (y, ψ, J) for the observer. Without a fold hit, the step as it was."""

    def at_fold():
        y_fold = ode.complete(fold.y) if getattr(ode, "completes_state", False) else fold.y
        event = ode.evaluate(y_fold)
        end = (y_fold, event.psi, event.J)
        if events.mode == "stop":
            stopped = eqx.tree_at(lambda s: (s.y, s.psi, s.J, s.drive), new, (y_fold, event.psi, event.J, event.drive))
            return stopped, fold_event(ode, y_fold), jumps, jnp.asarray(StopReason.FOLD, jnp.int32), end
        full = jumps.count >= events.max_jumps
        jump = ode.jump(y_fold)
        y = jnp.where(full, y_fold, jump.y)
        after = ode.evaluate(y)
        # a restarts as dψ/dt at the new state, differentiated like the rest of the jump.
        a = solver.initial_acceleration(ode, y, after.psi)
        restarted = AlphaState(
            y=y, psi=after.psi, a=jnp.where(jnp.isfinite(a), a, 0.0), J=after.J, drive=after.drive, status=new.status
        )
        record = jumps.record(~full, fold.t, jump.up, jump.v_before, jump.v_after, jump.G, jump.F)
        status = jnp.where(full, StopReason.MAX_JUMPS, 0).astype(jnp.int32)
        return restarted, fold_event(ode, y), record, status, end

    def no_fold():
        return new, g_new, jumps, jnp.asarray(0, jnp.int32), (new.y, new.psi, new.J)

    state, g, record, status, end = jax.lax.cond(fold.hit, at_fold, no_fold)
    return state, jnp.where(fold.hit, fold.t, t_new), g, record, status, end


def _events_for(events: FoldEvents | None, ode) -> FoldEvents | None:
    """None where nothing is to be located: an ODE without folds (no ``fold_event``), or
    ``fold="stop"`` on an ODE whose own stop test is the paper's (``stops_at_impasse``)."""
    if events is None or not hasattr(ode, "fold_event"):
        return None
    if events.mode == "stop" and getattr(ode, "stops_at_impasse", False):
        return None
    return events


def adaptive_loop(
    ode: ODE,
    solver: AlphaMethod,
    y0: Float[Array, " n"],
    t0: ArrayLike,
    t_final: ArrayLike,
    observer: Observer,
    *,
    controller: PIController,
    dt0: ArrayLike | None,
    dtmin: ArrayLike | None,
    max_steps: int,
    kind: Literal["checkpointed", "lax"],
    events: FoldEvents | None = None,
):
    """The error-controlled loop itself; returns (the ODE in carried coordinates, final carry).

    Shared by :func:`integrate_alpha_adaptive` (one trajectory's output) and the sweep engine
    (per-lane summaries), so that a lane of a sweep takes exactly the steps of a single run.
    ``events``: what to do at the folds of φ (:mod:`peeljax.integrators.events`; the ODE must
    then be a :class:`~peeljax.homogenized.FoldingODE`); None: the paper's stops (an impasse).
    """
    t0 = jnp.asarray(t0, float)
    t_final = jnp.asarray(t_final, float)
    span = t_final - t0
    dtmin = jnp.minimum(1e-12 * span, 3e-12) if dtmin is None else jnp.asarray(dtmin, float)  # not ∝ a long span
    events = _events_for(events, ode)
    if events is not None:
        ode = ode.with_folds()
    ode, state0 = alpha_start(ode, solver, jnp.asarray(y0, float))
    n = state0.y.shape[0]
    log_mask = _log_mask(n, solver.carried_log)
    h0 = _initial_step(controller, state0, log_mask, span) if dt0 is None else jnp.asarray(dt0, float)
    h0 = jax.lax.stop_gradient(jnp.clip(h0, dtmin, span))
    zero = jnp.asarray(0, jnp.int32)
    init = _Carry(
        t=t0,
        h=h0,
        state=state0,
        prev_norm=jnp.asarray(1.0),
        attempts=zero,
        accepted=zero,
        rejected=zero,
        newton_iterations=zero,
        max_newton_iterations=zero,
        h_min=jnp.asarray(jnp.inf),
        h_max=jnp.asarray(0.0),
        parts=(jnp.eye(n), jnp.zeros((n, n))),
        parts_fresh=jnp.asarray(False),
        refresh=jnp.asarray(True),
        parts_age=zero,
        jacobian_evaluations=zero,
        record=observer.init(t0, state0.y, state0.J, state0.status == 0),
        g=jnp.zeros(()) if events is None else fold_event(ode, state0.y),
        jumps=None if events is None else JumpRecord.empty(events.max_jumps),
        reference=state0.y,
        g_scale=jnp.zeros(()) if events is None else jnp.abs(fold_event(ode, state0.y)),
    )

    def running(c: _Carry):
        return (c.state.status == 0) & (c.t < t_final)

    def body(c: _Carry) -> _Carry:
        state = c.state
        remaining = t_final - c.t
        last = c.h >= remaining
        h = jnp.where(last, remaining, c.h)
        z_n = jax.lax.stop_gradient(solver._to_unknown(state.y))
        parts = jax.lax.cond(c.refresh, lambda: solver.linearize(_stop_gradient(ode), z_n), lambda: c.parts)
        fresh = c.refresh | c.parts_fresh
        age = jnp.where(c.refresh, 0, c.parts_age)  # accepted steps since the parts were computed
        scale = controller.scale(z_n, z_n, log_mask)
        chord = (parts, scale, solver.newton_kappa, solver.chord_iterations)
        new, error, solved, iterations = alpha_attempt(ode, solver, state, h, chord)
        norm = jax.lax.stop_gradient(controller.error_norm(error, state.y, new.y, log_mask))
        norm = jnp.where(solved, norm, jnp.inf)
        # A Newton failure with a kept matrix is retried at the same h with a fresh one.
        retry_fresh = ~solved & ~fresh
        accept = solved & (norm <= 1.0)
        t_new = jnp.where(last, t_final, c.t + h)  # exactly t_final at the end
        factor = controller.factor(norm, c.prev_norm, accept, solved | retry_fresh)
        factor = jnp.where(retry_fresh, 1.0, factor)
        h_next = jax.lax.stop_gradient(jnp.minimum(h * factor, span))
        if events is None:
            impasse = accept & (state.J * new.J < 0) & (state.drive * new.drive > 0)
            fold_status, g, jumps, restarted, g_scale = 0, c.g, None, jnp.asarray(False), c.g_scale
            step_end = (new.y, new.psi, new.J)
        else:
            impasse = jnp.asarray(False)
            if getattr(ode, "completes_state", False):  # the DAE's v, solved anew at the step's end
                new = eqx.tree_at(lambda s: s.y, new, jnp.where(accept, ode.complete(new.y), new.y))
            g_new = jax.lax.stop_gradient(new.J) if getattr(ode, "fold_event_is_schur", False) else fold_event(ode, new.y)
            fold = find_fold(events, ode, c.t, h, state, new, accept, c.g, g_new, c.reference)
            new, t_new, g, jumps, fold_status, step_end = _at_fold(
                events, ode, solver, fold, new, t_new, g_new, c.jumps
            )
            restarted = fold.hit & (fold_status == 0)
            g_scale = jnp.where(restarted, jnp.abs(g), c.g_scale)
            # After a jump the motion changes scale: restart the step size as at t0.
            h_restart = jnp.clip(_initial_step(controller, new, log_mask, span), dtmin, span)
            h_next = jax.lax.stop_gradient(jnp.where(restarted, h_restart, h_next))
            last = last & ~fold.hit
        advance = accept & ~impasse
        step = AcceptedStep(
            t0=c.t, t1=t_new, h=t_new - c.t, y0=state.y, psi0=state.psi,
            y1=step_end[0], psi1=step_end[1], J1=step_end[2], iterations=iterations, advance=advance,
        )  # fmt: skip
        record = observer.update(c.record, step, kind)

        done = advance & last
        collapsed = ~done & ~impasse & (h_next < dtmin) & (fold_status == 0)
        status = jnp.where(impasse, StopReason.IMPASSE, jnp.where(collapsed, StopReason.STALLED, 0))
        status = jnp.where(accept & (fold_status != 0), fold_status, status)
        attempts = c.attempts + 1
        status = jnp.where((status == 0) & ~done & (attempts >= max_steps), StopReason.MAX_STEPS, status)
        kept = jax.tree_util.tree_map(lambda a, b: jnp.where(advance, a, b), new, state)
        kept = eqx.tree_at(lambda s: s.status, kept, status.astype(jnp.int32))
        h_taken = jax.lax.stop_gradient(h)
        return _Carry(
            t=jnp.where(advance, t_new, c.t),
            h=h_next,
            state=kept,
            prev_norm=jnp.where(restarted, 1.0, jnp.where(accept, jnp.maximum(norm, 1e-10), c.prev_norm)),
            attempts=attempts,
            accepted=c.accepted + advance,
            rejected=c.rejected + ~accept,
            newton_iterations=c.newton_iterations + iterations,
            max_newton_iterations=jnp.maximum(c.max_newton_iterations, iterations),
            h_min=jnp.where(advance, jnp.minimum(c.h_min, h_taken), c.h_min),
            h_max=jnp.where(advance, jnp.maximum(c.h_max, h_taken), c.h_max),
            parts=parts,
            parts_fresh=fresh & ~advance,
            refresh=retry_fresh | restarted | (advance & (age + 1 >= solver.jacobian_max_age)),
            parts_age=age + advance,
            jacobian_evaluations=c.jacobian_evaluations + c.refresh,
            record=record,
            g=jnp.where(advance, g, c.g),
            jumps=jumps,
            reference=jnp.where(advance & (g <= -_REFERENCE_DEPTH * g_scale), kept.y, c.reference),
            g_scale=g_scale,
        )

    buffers = None if events is None else (lambda c: c.jumps.buffers())
    return ode, eqxi.while_loop(running, body, init, max_steps=max_steps, kind=kind, buffers=buffers)


def integrate_alpha_adaptive(
    ode: ODE,
    solver: AlphaMethod,
    y0: Float[Array, " n"],
    t0: ArrayLike,
    t_final: ArrayLike,
    *,
    controller: PIController | None = None,
    ts: Float[Array, " m"] | None = None,
    dt0: ArrayLike | None = None,
    dtmin: ArrayLike | None = None,
    max_steps: int = 100_000,
    adjoint: Literal["reverse", "forward"] = "reverse",
    events: FoldEvents | None = None,
) -> Solution:
    """Integrate y' = ψ(y) from t0 to t_final with the error-controlled α-method.

    Args:
        ode: the ODE: a :class:`~peeljax.HomogenizedODE`, or anything that meets the
            :class:`~peeljax.ODE` contract (``evaluate(y)`` returning ψ, J and F̃·f; ``tau``).
        solver: the :class:`AlphaMethod` (ρ, Newton tolerances, log components).
        y0: initial state (physical coordinates).
        controller: tolerances and step-size update (default ``PIController()``).
        ts: output times in [t0, t_final], increasing (static shape); None: the accepted
            step points, ``max_steps + 1`` rows NaN-padded (``valid`` marks the rows).
        dt0: first step (default: Hairer's estimate from ψ0 and a0, :func:`_initial_step`).
        dtmin: a proposed step below this stops the run (``STALLED``; default
            1e-12·(t_final − t0), at most 3e-12: the first steps from the paper's start and after
            a jump are ~1e-11 s however long the run, so a dtmin ∝ t_final would stop a long one).
        max_steps: most step attempts, accepted or rejected (static).
        adjoint: "reverse" (checkpointed while loop: ``jax.grad``) or "forward" (``jax.jvp``).
        events: what happens at the folds of φ (:class:`~peeljax.integrators.events.FoldEvents`:
            jump, stop or follow; the ODE must be a :class:`~peeljax.homogenized.FoldingODE`);
            None: the paper's stop at an impasse point.

    Returns:
        A :class:`Solution`; ``stats`` holds ``accepted_steps``, ``rejected_steps``,
        ``newton_iterations`` and the smallest, mean and largest accepted step.
    """
    check_adjoint(adjoint)
    controller = PIController() if controller is None else controller
    step_points = ts is None
    observer = StepPoints(max_steps + 1) if step_points else DenseOutput(jnp.asarray(ts, float))
    ode, final = adaptive_loop(
        ode, solver, y0, t0, t_final, observer,
        controller=controller, dt0=dt0, dtmin=dtmin, max_steps=max_steps,
        kind="checkpointed" if adjoint == "reverse" else "lax", events=events,
    )  # fmt: skip
    return _solution(ode, solver, final, step_points, jnp.asarray(t0, float), final.jumps is not None)


def _solution(ode, solver, final: _Carry, step_points: bool, t0, folding: bool = False) -> Solution:
    out = final.record
    valid = out.valid
    ys_carried = out.y
    if folding and getattr(ode, "completes_state", False):
        # An interpolated state's algebraic part (the DAE's v) is solved anew at that state.
        safe = jnp.where(valid[:, None], ys_carried, final.state.y)
        ys_carried = jax.vmap(ode.complete)(safe)
    ys_carried = jnp.where(valid[:, None], ys_carried, jnp.nan)
    ys = to_physical(solver, ys_carried)
    if step_points:
        Js = out.J
    else:
        # J_t at the interpolated states (evaluated at the last state where invalid, then masked).
        safe = jnp.where(valid[:, None], ys_carried, final.state.y)
        Js = jax.vmap(lambda z: ode.evaluate(z).J)(safe)
    Js = jnp.where(valid, Js, jnp.nan)
    diagnostics = StepDiagnostics(
        newton_iterations=jnp.where(valid, out.iterations, 0),
        newton_correction=jnp.full(valid.shape, jnp.nan),
        schur=Js,
        local_index=jnp.where(valid, local_index(jnp.where(valid, Js, 1.0), ode.tau), 0),
        condition=jnp.full(valid.shape, jnp.nan),
    )
    accepted = final.accepted
    stats = {
        "steps": accepted,
        "accepted_steps": accepted,
        "rejected_steps": final.rejected,
        "step_size": jnp.asarray(jnp.nan),
        "step_size_min": jnp.where(accepted > 0, final.h_min, jnp.nan),
        "step_size_mean": jnp.where(accepted > 0, (final.t - t0) / jnp.maximum(accepted, 1), jnp.nan),
        "step_size_max": jnp.where(accepted > 0, final.h_max, jnp.nan),
        "newton_iterations": final.newton_iterations,
        "max_newton_iterations": final.max_newton_iterations,
        "jacobian_evaluations": final.jacobian_evaluations,
    }
    if final.jumps is not None:
        stats["jumps"] = final.jumps.count
    return Solution(
        ts=out.t,
        ys=ys,
        valid=valid,
        status=final.state.status,
        t_stop=final.t,
        stats=stats,
        diagnostics=diagnostics,
        method="alpha-adaptive",
        jumps=final.jumps,
    )


class ErrorControl(AbstractIntegrator):
    """The error-controlled α-method as an integrator (:mod:`peeljax.integrators.base`).

    :meth:`integrate` is :func:`integrate_alpha_adaptive`; :meth:`observe` runs the same loop
    (:func:`adaptive_loop`) with a sweep lane's observer, so a lane takes exactly the steps of
    a single run.

    Attributes:
        method: the :class:`AlphaMethod` (ρ, Newton's settings, log components).
        controller: the :class:`PIController` (rtol, atol, step-size update).
        dtmin: a proposed step below it stops the run (``STALLED``); None: 1e-12·(t_final − t0), at most 3e-12.
        max_steps: most step attempts, accepted or rejected (static).
        adjoint: ``"reverse"`` (a checkpointed while loop, for ``jax.grad``) or ``"forward"``
            (a plain while loop: ``jax.jvp``, and the fastest run when nothing is differentiated).
    """

    dense_output: ClassVar[bool] = True
    method: AlphaMethod = AlphaMethod()
    controller: PIController = PIController()
    dtmin: Float[Array, ""] | None = eqx.field(converter=optional_float_array, default=None)
    max_steps: int = eqx.field(static=True, default=100_000)
    adjoint: str = eqx.field(static=True, default="reverse")
    events: FoldEvents | None = None

    def __check_init__(self):
        check_adjoint(self.adjoint)
        check_max_steps(self.max_steps)

    @property
    def carried_log(self) -> tuple[int, ...]:
        return self.method.carried_log

    def integrate(self, ode, y0, t0, t_final, ts=None) -> Solution:
        return integrate_alpha_adaptive(
            ode, self.method, y0, t0, t_final, controller=self.controller, ts=ts, dtmin=self.dtmin,
            max_steps=self.max_steps, adjoint=self.adjoint, events=self.events,
        )  # fmt: skip

    def observe(self, ode, y0, t0, t_final, observer) -> ObservedRun:
        _, final = adaptive_loop(
            ode, self.method, y0, t0, t_final, observer, controller=self.controller, dt0=None, dtmin=self.dtmin,
            max_steps=self.max_steps, kind="checkpointed" if self.adjoint == "reverse" else "lax",
            events=self.events,
        )  # fmt: skip
        start_failed = (final.attempts == 0) & (final.state.status != 0)
        return ObservedRun(
            record=final.record,
            status=final.state.status,
            t_stop=final.t,
            y_final=jnp.where(start_failed, jnp.nan, to_physical(self.method, final.state.y)),
            accepted_steps=final.accepted,
            rejected_steps=final.rejected,
            newton_iterations=final.newton_iterations,
            subdivided_steps=jnp.asarray(0, jnp.int32),
            max_subdivision_level=jnp.asarray(0, jnp.int32),
            jumps=final.jumps,
        )

    def settings(self) -> dict:
        return {
            "method": "alpha-adaptive",
            "rtol": float(self.controller.rtol),
            "atol": float(self.controller.atol),
            "dtmin": None if self.dtmin is None else float(self.dtmin),
            "max_steps": self.max_steps,
            "solver": self.method.settings(),
            **({} if self.events is None else self.events.settings()),
        }
