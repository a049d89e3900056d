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
``adjoint`` (:func:`peeljax.simulate` chooses per derivative: :mod:`.adjoint`). Step sizes and accept/reject decisions are held constant in the derivative
(``stop_gradient`` on the controller, as diffrax does).
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar, Literal

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._arrays import optional_float_array
from .._cotangents import skip_zero_cotangents
from .._validation import check_adjoint, check_max_steps
from ..branches import Folds
from ..homogenized import ODE
from ..solution import JumpRecord, JumpSides, Solution, StepDiagnostics, StopReason
from ..structure import local_index
from ..desingularized import tangential_fold
from .alpha import AlphaMethod, _stop_gradient
from .log_variables import from_log, log_mask, to_log
from .base import AbstractIntegrator, ObservedRun
from .controller import PIController
from .dense import PhysicalTimeInterpolant
from .events import FoldEvents, FoldHit, find_fold, fold_event, fold_fraction
from .observers import AcceptedStep, DenseOutput, Observer, StepPoints, _GridWithJumps, _Output, observer_keeps_jumps
from .steppers import AbstractStepper, AlphaStepper, StepperState, alpha_attempt, as_stepper, error_constant, physical

__all__ = [
    "ErrorControl",
    "adaptive_loop",
    "alpha_attempt",
    "error_constant",
    "integrate_adaptive",
    "integrate_alpha_adaptive",
]


class _Misses(eqx.Module):
    # The fold's closest miss (τ = 0: the fold distance G − φ at the fold, N): a local maximum
    # below the fold at a step end, as a fraction of g_scale, and its time; the highest value
    # since the branch began or the last miss, and its time.
    miss: Array
    miss_t: Array
    peak: Array
    peak_t: Array
    grazed_t: Array  # the first near miss within _GRAZING·rtol of the fold (NaN: none)


class _Carry(eqx.Module):
    t: Array
    h: Array  # the step the controller proposes next
    state: StepperState
    prev_norm: Array
    attempts: Array
    accepted: Array
    rejected: Array
    newton_iterations: Array
    max_newton_iterations: Array
    h_min: Array
    h_max: Array
    record: object  # the observer's
    g: Array  # the fold event at the state (0 without events)
    jumps: JumpRecord | None  # None without events
    # The latest state of the current branch with g ≤ −_REFERENCE_DEPTH·g_scale, g_scale = |g|
    # where the branch began: where a tangential fold's time is differentiated (events module).
    reference: Array
    reference_t: Array  # its time
    reference_far: Array | None  # τ = 0 in pseudo-time (else None): the latest _FAR_REFERENCE × deeper
    reference_drive: Array  # its F̃·f (the homogenized ODE's impasse reference)
    g_scale: Array
    cut_steps: Array  # rejected attempts over a fold whose retry was cut at the fold
    misses: _Misses
    passed_t: Array  # the first singular passage followed (fold="follow"; NaN: none)
    folds: Folds | None  # φ's folds, searched at the first jump (FoldEvents.folds_at_first_jump); else None


_REFERENCE_DEPTH = 1e-5
# A near miss of a fold closer than this × rtol (of the fold event's scale) is a grazing within
# the run's own error: whether the tape jumped there is not decided by the run, and the
# derivatives of what follows do not exist (``stats["grazed_at"]``).
_GRAZING = 10.0
# The homogenized ODE's impasse (τ > 0, fold event J_t): its derivatives are carried along v from
# the latest state with J_t ≤ −this × |J_t| at the branch's start and F̃·f of the same sign since
# (events.impasse_path): v is monotone from there to the impasse, and the steps' sensitivities
# are still resolved there (closer to the impasse they are not: v̇ ~ 1/J_t).
_IMPASSE_REFERENCE_DEPTH = 0.1
# A tangential fold in pseudo-time takes its derivatives from two reference states, the latest
# with g ≤ −depth·max(|g₀|, |φ at the folds|) (g₀ where the branch began) and the latest 16×
# deeper (desingularized.tangential_fold), depth = max(1e-7, 0.1·rtol). Closer to the fold the
# steps no longer resolve the tangent of v; farther, the linearization errs (in proportion to the
# time to the fold: the two estimates are extrapolated to zero). Measured in
# tests/test_jump_gradients.py and CHANGELOG [Unreleased] "Fixed" (V = 4.9: from 1e-3·rtol deep, d/dc1 of
# a jump time 5.7e7 off at rtol 1e-6, 0.22 at 1e-8).
_PSEUDO_TIME_REFERENCE_DEPTH = 1e-7
_PSEUDO_TIME_REFERENCE_DEPTH_PER_RTOL = 0.1
_FAR_REFERENCE = 16.0
# A retry cut at a fold ends this fraction of the step past the fold (the located root is
# that of a rejected, inexact step): the accepted step then crosses it, and the fold is
# located on that step's interpolant.
_CUT_PAST = 1e-3


def _near_miss(misses: _Misses, event, t, advance, restarted, g_scale, rtol) -> _Misses:
    """The fold's closest miss after an accepted step whose end has fold distance ``event`` (< 0
    below the fold) at time t: the event came closest at ``peak`` and has since fallen away by
    more than that distance (and than the run's error): a jump that appears or vanishes under a
    small perturbation (a grazing)."""
    miss, miss_t, peak, peak_t, grazed_t = misses.miss, misses.miss_t, misses.peak, misses.peak_t, misses.grazed_t
    fell = peak - jnp.maximum(-peak, rtol * g_scale)
    turned_back = advance & (peak < 0) & (event < fell) & jnp.isfinite(peak)
    margin = jnp.where(turned_back, -peak / jnp.maximum(g_scale, 1e-300), jnp.inf)
    closer = margin < miss
    grazed = jnp.isnan(grazed_t) & (margin < _GRAZING * rtol)
    higher = (advance | restarted) & (restarted | turned_back | (event > peak))
    return _Misses(
        jnp.where(closer, margin, miss),
        jnp.where(closer, peak_t, miss_t),
        jnp.where(higher, event, peak),
        jnp.where(higher, t, peak_t),
        jnp.where(grazed, peak_t, grazed_t),
    )


def _initial_step(stepper: AbstractStepper, controller: PIController, ode, y, is_log, span):
    """The first step from y (at t0 and after a jump), in the error norm's weights, from
    d0 = ‖y‖, d1 = ‖ψ‖ and d2 = ‖dψ/dt‖ (by autodiff):

    * the α-method (q = 3): h = 0.01·min(1/d1, 1/√d2), the guess its controller was tuned
      with (clipped below at dtmin, it starts small and grows ×10 a step);
    * a Runge–Kutta solver of error order q: Hairer's (Hairer, Nørsett & Wanner I, II.4),
      h0 = 0.01·d0/d1, h1 = (0.01/max(d1, d2))^(1/q), h = min(100·h0, h1).
    """
    psi = ode.evaluate(y).psi
    a = jax.jvp(lambda z: ode.evaluate(z).psi, (y,), (psi,))[1]
    d0 = controller.error_norm(y, y, y, is_log)
    d1 = controller.error_norm(psi, y, y, is_log)
    d2 = controller.error_norm(jnp.where(jnp.isfinite(a), a, 0.0), y, y, is_log)
    if isinstance(stepper, AlphaStepper):
        h1 = jnp.where(d1 > 0, 0.01 / jnp.where(d1 > 0, d1, 1.0), span)
        h2 = jnp.where(d2 > 0, 0.01 / jnp.sqrt(jnp.where(d2 > 0, d2, 1.0)), span)
        return jnp.minimum(jnp.minimum(h1, h2), span)
    h0 = jnp.where((d0 < 1e-5) | (d1 < 1e-5), 1e-6 * span, 0.01 * d0 / jnp.where(d1 > 0, d1, 1.0))
    top = jnp.maximum(d1, d2)
    h1 = jnp.where(
        top <= 1e-15, jnp.maximum(1e-6 * span, h0 * 1e-3), (0.01 / jnp.where(top > 0, top, 1.0)) ** (1.0 / stepper.order)
    )
    return jnp.minimum(jnp.minimum(100.0 * h0, h1), span)


def _at_fold(
    events: FoldEvents, ode, stepper: AbstractStepper, fold: FoldHit, new: StepperState, t_new, g_new, jumps, clock,
    folds: Folds | None = None,
):
    """The step's outcome at a fold: the state to go on from, its time and event value, the
    jump record, a stop status (0, ``FOLD`` or ``MAX_JUMPS``), the cut step's end
    (y, J) for the observer and φ's folds (``folds``: those carried where they are searched at
    the first jump, searched there if not yet; None: ``ode`` has them). Without a fold hit, the
    step as it was."""

    nan = jnp.full((), jnp.nan)
    no_jump = (jnp.asarray(False), nan, jnp.asarray(False), nan, nan, nan, nan)  # (write, t, up, v⁻, v⁺, G, F)
    keeps_state = jumps.statistics is not None  # the cycle statistics keep the state at slips
    if keeps_state:
        no_jump = (*no_jump, jnp.full(physical(stepper, fold.y).shape, jnp.nan))

    def at_fold():
        y_fold = ode.complete(fold.y) if getattr(ode, "completes_state", False) else fold.y
        event = ode.evaluate(y_fold)
        end = (y_fold, event.J)
        if events.mode == "stop":
            stopped = eqx.tree_at(lambda s: (s.y, s.psi, s.J, s.drive), new, (y_fold, event.psi, event.J, event.drive))
            return stopped, fold_event(ode, y_fold), no_jump, jnp.asarray(StopReason.FOLD, jnp.int32), end, folds
        found, folded = folds, ode
        if folds is not None:
            found = jax.lax.cond(folds.searched, lambda: folds, lambda: ode.with_folds().folds)
            folded = ode.with_folds(found)
        full = jumps.full  # (a ring buffer never is)
        jump = folded.jump(y_fold)
        y = jnp.where(full, y_fold, jump.y)
        restarted = stepper.restart(ode, fold.t, y, new)
        entry = (~full, clock(fold.t, y_fold), jump.up, jump.v_before, jump.v_after, jump.G, jump.F)
        if keeps_state:
            entry = (*entry, physical(stepper, y_fold))
        status = jnp.where(full, StopReason.MAX_JUMPS, 0).astype(jnp.int32)
        return restarted, fold_event(ode, y), entry, status, end, found

    def no_fold():
        return new, g_new, no_jump, jnp.asarray(0, jnp.int32), (new.y, new.J), folds

    # The record is written outside the cond: carried through it, its buffers were copied at
    # every step (measured: +7.5 µs per Tsit5 step at τ > 0, P1 2.4 ms against 0.8 with fold="follow").
    state, g, entry, status, end, folds = jax.lax.cond(fold.hit, at_fold, no_fold)
    record = jumps.record(fold.hit & entry[0], *entry[1:])
    return state, jnp.where(fold.hit, fold.t, t_new), g, record, status, end, folds


def _events_for(events: FoldEvents | None, ode) -> FoldEvents | None:
    """None where nothing is to be located: an ODE without folds (no ``fold_event``), or
    ``fold="stop"`` on an ODE whose own stop test is the paper's (``stops_at_impasse``)."""
    if events is None or not hasattr(ode, "fold_event"):
        return None
    if events.mode == "stop" and getattr(ode, "stops_at_impasse", False):
        return None
    return events


def _not_before(y: Array, start: Array, time_index: int) -> Array:
    """``y`` with its time component no earlier than ``start``'s, in value (its derivative is y's).

    Physical time never goes back (dt/ds ≥ 0 on a stable branch of the DAE in pseudo-time), but a
    step's t can: near a fold dt/ds falls to 0 within the step, Tsit5 has a negative weight, and the
    interpolant that locates the fold dips below the step's start. Measured up to 2.4e-7 s back,
    within rtol·t, in 32–35 of 80 runs at τ = 0, V in 0.6–4.5 m/s (rtol 1e-6 to 1e-8), in the
    rows of the steps and of the jumps. The value is projected on the true solution's invariant
    (as u is on the constraint); its derivative is the step's."""
    t = y[time_index]
    return y.at[time_index].set(t + jax.lax.stop_gradient(jnp.maximum(t, start[time_index]) - t))


def adaptive_loop(
    ode: ODE,
    stepper: AbstractStepper | AlphaMethod,
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
    """The one error-controlled loop; returns (the ODE in carried coordinates, final carry).

    Shared by :func:`integrate_adaptive` (one trajectory's output) and the sweep engine
    (per-lane summaries), so that a lane of a sweep takes exactly the steps of a single run.
    ``stepper``: the method's step (:mod:`peeljax.integrators.steppers`; an
    :class:`AlphaMethod` is taken as its :class:`AlphaStepper`). ``events``: what to do at
    the folds of φ (:mod:`peeljax.integrators.events`; the ODE must then be a
    :class:`~peeljax.homogenized.FoldingODE`); None: the paper's stops (an impasse).
    """
    stepper = as_stepper(stepper).for_loop(controller, kind)
    t0 = jnp.asarray(t0, float)
    t_final = jnp.asarray(t_final, float)
    span = t_final - t0
    dtmin = jnp.minimum(1e-12 * span, 3e-12) if dtmin is None else jnp.asarray(dtmin, float)  # not ∝ a long span
    events = _events_for(events, ode)
    # Where the fold event is J_t, the folds serve the jumps only: searched at the first one.
    schur_event = getattr(ode, "fold_event_is_schur", False)
    folds_later = events is not None and events.folds_at_first_jump and schur_event
    if events is not None and not folds_later:
        ode = ode.with_folds()
    ode, state0 = stepper.start(ode, t0, jnp.asarray(y0, float))
    # An ODE in pseudo-time s (DesingularizedDAE) carries t as a component: the loop steps in s.
    time_index = getattr(ode, "time_index", None)
    timed = time_index is not None

    def clock(s, y):
        """Physical time at the loop's independent variable s and state y."""
        return y[time_index] if timed else s

    n = state0.y.shape[0]
    is_log = log_mask(n, stepper.carried_log)
    if timed:
        # The reference state of a tangential fold is tracked on the DAE-in-time's event
        # G − φ(v̂), in the physical coordinates of the DesingularizedDAE.
        base = getattr(ode, "ode", ode)

        def reference_event(y):
            return jax.lax.stop_gradient(_stop_gradient(base).fold_distance(jax.lax.stop_gradient(from_log(y, stepper.carried_log))))

        def tangential(y_fold, y_ref, y_far):
            to = functools.partial(from_log, log_components=stepper.carried_log)
            is_tangential, y = tangential_fold(base, to(y_fold), to(y_ref), to(y_far))
            return jnp.where(jax.lax.stop_gradient(is_tangential), to_log(y, stepper.carried_log), y_fold)

        reference_depth = jnp.maximum(_PSEUDO_TIME_REFERENCE_DEPTH, _PSEUDO_TIME_REFERENCE_DEPTH_PER_RTOL * controller.rtol)
        # A branch that begins close to its fold (|g| ≪ φ) would put the reference where the
        # pseudo-time tangents are no longer resolved: the depth is measured against φ at the folds too.
        folds = jax.lax.stop_gradient(base.folds)
        depth_floor = 0.0 if folds is None else jnp.nan_to_num(jnp.maximum(jnp.abs(folds.phi_max), jnp.abs(folds.phi_min)))
    else:

        def reference_event(y):
            return fold_event(ode, y)

        reference_depth = _REFERENCE_DEPTH
        depth_floor = 0.0
    increment_mask = log_mask(n, (time_index,)) if timed else None
    if dt0 is None:
        h0 = _initial_step(stepper, controller, _stop_gradient(ode), jax.lax.stop_gradient(state0.y), is_log, span)
    else:
        h0 = jnp.asarray(dt0, float)
    h0 = jax.lax.stop_gradient(jnp.clip(jnp.where(jnp.isfinite(h0), h0, dtmin), dtmin, span))
    zero = jnp.asarray(0, jnp.int32)
    completes = getattr(ode, "completes_state", False)
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
        record=observer.init(t0, state0.y, state0.J, state0.status == 0),
        g=jnp.zeros(()) if events is None else fold_event(ode, state0.y),
        jumps=None if events is None else events.empty_record(),
        reference=state0.y,
        reference_t=t0,
        reference_far=state0.y if timed else None,
        reference_drive=state0.drive,
        g_scale=jnp.zeros(()) if events is None else jnp.abs(reference_event(state0.y)),
        cut_steps=zero,
        misses=_Misses(
            miss=jnp.asarray(jnp.inf),
            miss_t=jnp.asarray(jnp.nan),
            peak=jnp.zeros(()) if events is None or schur_event else jax.lax.stop_gradient(reference_event(state0.y)),
            peak_t=t0 if not timed else jax.lax.stop_gradient(state0.y[time_index]),
            grazed_t=jnp.asarray(jnp.nan),
        ),
        passed_t=jnp.asarray(jnp.nan),
        folds=Folds.not_searched() if folds_later else None,
    )

    def running(c: _Carry):
        return (c.state.status == 0) & (clock(c.t, c.state.y) < t_final)

    # Reverse mode: a rejected attempt gets a zero cotangent, and its pullback, where the attempt
    # overflowed on its way to a rejected result, 0·inf = NaN; skip that pullback instead.
    attempt_step = type(stepper).attempt
    if kind == "checkpointed":
        attempt_step = skip_zero_cotangents(attempt_step)

    def body(c: _Carry) -> _Carry:
        state = c.state
        if timed:  # the last step is found by its end's time, then cut (below)
            last = jnp.asarray(False)
            h = c.h
        else:
            remaining = t_final - c.t
            last = c.h >= remaining
            h = jnp.where(last, remaining, c.h)
        y_n = jax.lax.stop_gradient(state.y)
        attempt = attempt_step(stepper, ode, c.t, h, state, controller.scale(y_n, y_n, is_log))
        new, solved = attempt.candidate, attempt.solved
        norm = jax.lax.stop_gradient(controller.error_norm(attempt.error, state.y, new.y, is_log, increment_mask))
        norm = jnp.where(solved, norm, jnp.inf)
        accept = solved & (norm <= 1.0)
        t_new = jnp.where(last, t_final, c.t + h)  # exactly t_final at the end
        factor = stepper.step_factor(controller, state, norm, c.prev_norm, accept, solved | attempt.retry)
        factor = jnp.where(attempt.retry, 1.0, factor)
        h_next = jax.lax.stop_gradient(jnp.minimum(h * factor, span))
        if timed:
            new = eqx.tree_at(lambda s: s.y, new, _not_before(new.y, state.y, time_index))
            # In pseudo-time the step whose end passes t_final ends at t_final: cut where t(s) = t_final
            # on its interpolant (the state there carries the implicit function theorem's derivative).
            reach = accept & (new.y[time_index] >= t_final)
            in_time = PhysicalTimeInterpolant(attempt.interpolant, c.t, c.t + h, time_index)
            s_end, y_end = jax.lax.cond(reach, lambda: in_time.at(t_final), lambda: (c.t + h, new.y))
            y_end = jnp.where(reach, y_end.at[time_index].set(t_final), y_end)
            new = eqx.tree_at(lambda s: s.y, new, y_end)
            h = jnp.where(reach, s_end - c.t, h)
            t_new = c.t + h
            last = reach
        cut = jnp.asarray(False)
        passed_t = c.passed_t
        if events is None:
            impasse = accept & (state.J * new.J < 0) & (state.drive * new.drive > 0)
            fold_status, g, jumps, restarted, g_scale, folds = 0, c.g, None, jnp.asarray(False), c.g_scale, c.folds
            step_end = (new.y, new.J)
        else:
            impasse = jnp.asarray(False)
            if completes:  # the DAE's v, solved anew at the step's end
                completed = eqx.tree_at(lambda s: s.y, new, jnp.where(accept, ode.complete(new.y), new.y))
                if hasattr(ode, "switch"):  # a switch of mode (the tape released or fully stuck): a new field
                    parts = lambda s: (s.y, s.psi, s.J, s.drive, s.inner)  # noqa: E731 (small: the cond copies them)
                    switched = jax.lax.cond(
                        accept & ode.switches(new.y),
                        lambda: parts(stepper.restart(ode, t_new, ode.switch(new.y), new)),
                        lambda: parts(completed),
                    )
                    completed = eqx.tree_at(parts, completed, switched)
                new = completed
            g_new = jax.lax.stop_gradient(new.J) if schur_event else fold_event(ode, new.y)
            if stepper.cuts_at_folds and not schur_event and not timed:
                # A rejected attempt over the fold: its error holds the kink of v clamped past the
                # fold, not the accuracy the controller needs before it. Retry up to just past
                # the fold located on its interpolant, rather than with the controller's shrunk h.
                over = solved & ~accept & (c.g < 0) & (g_new >= 0)
                theta = jax.lax.cond(
                    over, lambda: fold_fraction(ode, c.t, h, attempt.interpolant), lambda: jnp.ones(())
                )
                h_cut = jax.lax.stop_gradient(theta * h * (1.0 + _CUT_PAST))
                cut = over & (h_cut < 0.9 * h) & (h_cut > h_next)
                h_next = jnp.where(cut, h_cut, h_next)
            # In pseudo-time the fold is a transversal zero whose time t(s*) does not move with s* to
            # first order: no reference state for tangential folds is needed.
            fold = find_fold(
                events, ode, c.t, h, state, new, attempt.interpolant, accept, c.g, g_new,
                None if timed else c.reference, -reference_depth * c.g_scale,
                (c.reference_t, c.reference) if schur_event else None,
            )  # fmt: skip
            if timed:  # a tangential fold's derivatives from the reference state (tangential_fold)
                fold = eqx.tree_at(
                    lambda f: f.y, fold, jax.lax.cond(fold.hit, lambda: tangential(fold.y, c.reference, c.reference_far), lambda: fold.y)
                )
                fold = eqx.tree_at(lambda f: f.y, fold, _not_before(fold.y, state.y, time_index))
            new, t_new, g, jumps, fold_status, step_end, folds = _at_fold(
                events, ode, stepper, fold, new, t_new, g_new, c.jumps, clock, c.folds
            )
            restarted = fold.hit & (fold_status == 0)
            if events.mode == "follow" and schur_event:  # a singular passage followed, not a fold hit
                passage = accept & ~fold.hit & (c.g < 0) & (g_new >= 0) & (state.drive * new.drive <= 0)
                passed_t = jnp.where(passage & jnp.isnan(c.passed_t), jax.lax.stop_gradient(t_new), c.passed_t)
            g_scale = jnp.where(restarted, jnp.abs(reference_event(new.y)), c.g_scale)
            # After a jump the motion changes scale: restart the step size as at t0.
            h_next = jax.lax.cond(
                restarted,
                lambda: jnp.maximum(
                    _initial_step(stepper, controller, _stop_gradient(ode), jax.lax.stop_gradient(new.y), is_log, span),
                    dtmin,
                ),
                lambda: h_next,
            )
            h_next = jax.lax.stop_gradient(jnp.minimum(jnp.where(jnp.isfinite(h_next), h_next, dtmin), span))
            last = last & ~fold.hit
        advance = accept & ~impasse
        if timed:  # observers see physical time
            step_t0, step_t1 = clock(c.t, state.y), clock(t_new, step_end[0])
            seen = PhysicalTimeInterpolant(attempt.interpolant, c.t, t_new, time_index)
        else:
            step_t0, step_t1, seen = c.t, t_new, attempt.interpolant
        step = AcceptedStep(
            t0=step_t0, t1=step_t1, h=step_t1 - step_t0, y0=state.y, y1=step_end[0], J1=step_end[1],
            iterations=attempt.iterations, advance=advance, interpolant=seen,
            jumped=restarted, y_after=new.y, J_after=new.J,  # the state just after a jump at t1
        )  # fmt: skip
        record = observer.update(c.record, step, kind)

        done = advance & last
        collapsed = ~done & ~impasse & (h_next < dtmin) & (fold_status == 0)
        status = jnp.where(impasse, StopReason.IMPASSE, jnp.where(collapsed, StopReason.STALLED, 0))
        status = jnp.where(accept & (fold_status != 0), fold_status, status)
        attempts = c.attempts + 1
        status = jnp.where((status == 0) & ~done & (attempts >= max_steps), StopReason.MAX_STEPS, status)
        kept = jax.tree_util.tree_map(lambda a, b: jnp.where(advance, a, b), new, attempt.retained)
        kept = eqx.tree_at(lambda s: s.status, kept, status.astype(jnp.int32))
        h_taken = jax.lax.stop_gradient(h)
        misses = c.misses
        deeper_far = jnp.asarray(False)
        if events is None:
            deeper = jnp.asarray(False)
        else:
            # (kept.J is the Schur event: no evaluation more)
            event = jax.lax.stop_gradient(kept.J if schur_event else reference_event(kept.y))
            if schur_event:  # (no near misses: J_t has no scale to measure one against, ~1e10 from rest)
                turned = kept.drive * c.reference_drive <= 0
                deeper = advance & ((event <= -_IMPASSE_REFERENCE_DEPTH * g_scale) | turned)
            else:
                depth = reference_depth * jnp.maximum(g_scale, depth_floor)
                deeper = advance & (event <= -depth)
                if timed:
                    deeper_far = advance & (event <= -_FAR_REFERENCE * depth)
                t_kept = jax.lax.stop_gradient(clock(t_new, kept.y))
                misses = _near_miss(misses, event, t_kept, advance & ~restarted, restarted, g_scale, controller.rtol)
        return _Carry(
            t=jnp.where(advance, t_new, c.t),
            h=h_next,
            state=kept,
            prev_norm=jnp.where(restarted, 1.0, jnp.where(accept, jnp.maximum(norm, 1e-10), c.prev_norm)),
            attempts=attempts,
            accepted=c.accepted + advance,
            rejected=c.rejected + ~accept,
            newton_iterations=c.newton_iterations + attempt.iterations,
            max_newton_iterations=jnp.maximum(c.max_newton_iterations, attempt.iterations),
            h_min=jnp.where(advance, jnp.minimum(c.h_min, h_taken), c.h_min),
            h_max=jnp.where(advance, jnp.maximum(c.h_max, h_taken), c.h_max),
            record=record,
            g=jnp.where(advance, g, c.g),
            jumps=jumps,
            reference=c.reference if events is None else jnp.where(deeper, kept.y, c.reference),
            reference_t=jnp.where(deeper, jnp.where(advance, t_new, c.t), c.reference_t),
            reference_far=jnp.where(deeper_far, kept.y, c.reference_far) if timed else None,
            reference_drive=jnp.where(deeper, kept.drive, c.reference_drive),
            g_scale=g_scale,
            cut_steps=c.cut_steps + cut,
            misses=misses,
            passed_t=passed_t,
            folds=folds,
        )

    def buffers(c: _Carry) -> tuple:  # written in place, never read in the loop (static choices only)
        return (*observer.buffers(c.record), *(() if events is None else c.jumps.buffers()))

    checkpoints = None if kind != "checkpointed" else reverse_checkpoints(init, buffers, max_steps)
    return ode, eqxi.while_loop(
        running, body, init, max_steps=max_steps, kind=kind, buffers=buffers, checkpoints=checkpoints
    )


# Reverse mode: the checkpointed loop keeps this many bytes of carries at most (its buffers, the
# jump record, are not copied). Equinox's default, O(√max_steps) checkpoints, kept 4471 copies of
# a dense output with 2·10⁴ jump rows: 10.7 GB for one jax.grad at τ = 0.1 (measured).
CHECKPOINT_BYTES = 256 * 2**20


def reverse_checkpoints(init, buffers, max_steps: int, budget: int = CHECKPOINT_BYTES) -> int:
    """Checkpoints of the reverse-mode loop: equinox's default, O(√max_steps), or fewer where
    that many copies of the carry (less its buffers) would exceed ``budget`` bytes. Fewer
    checkpoints recompute more steps in the backward pass (online treeverse), same values."""
    in_buffers = {id(leaf) for leaf in jax.tree_util.tree_leaves(buffers(init))} if buffers else set()
    carry = sum(
        math.prod(leaf.shape) * jnp.dtype(leaf.dtype).itemsize
        for leaf in jax.tree_util.tree_leaves(init)
        if hasattr(leaf, "shape") and id(leaf) not in in_buffers
    )
    default = 1 if max_steps == 1 else math.floor(-1.5 + math.sqrt(2 * max_steps + 0.25)) + 1
    return int(max(16, min(default, budget // max(carry, 1))))


def integrate_adaptive(
    ode: ODE,
    stepper: AbstractStepper | AlphaMethod,
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
    save_jumps: bool = True,
    merge_jump_rows: bool = True,
) -> Solution:
    """Integrate y' = ψ(y) from t0 to t_final with error control, any stepper.

    Args:
        ode: the ODE: a :class:`~peeljax.HomogenizedODE`, a :class:`~peeljax.ConstrainedDAE`,
            or anything that meets the :class:`~peeljax.ODE` contract (``evaluate(y)``
            returning ψ, J and F̃·f; ``tau``).
        stepper: the method's step (:mod:`peeljax.integrators.steppers`): an
            :class:`AlphaMethod` (the α-method), or a :class:`~peeljax.integrators.RungeKutta`
            around a diffrax Runge–Kutta solver.
        y0: initial state (physical coordinates).
        controller: tolerances and step-size update (default ``PIController()``).
        ts: output times in [t0, t_final], increasing (static shape); None: the accepted
            step points, ``max_steps + 1`` rows NaN-padded (``valid`` marks the rows).
        dt0: first step (default: Hairer's estimate from ψ0 and dψ/dt, :func:`_initial_step`).
        dtmin: a proposed step below this stops the run (``STALLED``; default
            1e-12·(t_final − t0), at most 3e-12: the first steps from the paper's start and after
            a jump are ~1e-11 s however long the run, so a dtmin ∝ t_final would stop a long one).
        max_steps: most step attempts, accepted or rejected (static).
        adjoint: "reverse" or "checkpointed" (checkpointed while loop: ``jax.grad``) or
            "forward" (``jax.jvp``).
        events: what happens at the folds of φ (:class:`~peeljax.integrators.events.FoldEvents`:
            jump, stop or follow; the ODE must be a :class:`~peeljax.homogenized.FoldingODE`);
            None: the paper's stop at an impasse point.
        save_jumps: keep both sides of every jump in the output (two rows at its time, the
            second marked in ``Solution.after_jump``; :class:`~peeljax.integrators.observers.DenseOutput`).
        merge_jump_rows: with output times ``ts``, insert the jumps' rows among them here (the
            static ``len(ts) + 2·max_jumps`` rows); False: keep them apart in
            ``Solution.jump_sides`` for the host to merge (:meth:`Solution.without_padding`).

    Returns:
        A :class:`Solution`; ``stats`` holds ``accepted_steps``, ``rejected_steps``,
        ``newton_iterations`` and the smallest, mean and largest accepted step.
    """
    check_adjoint(adjoint)
    stepper = as_stepper(stepper)
    controller = PIController() if controller is None else controller
    step_points = ts is None
    jumps = _events_for(events, ode)
    jump_rows = jumps.max_jumps if save_jumps and jumps is not None and jumps.mode != "stop" else 0
    if step_points:
        observer = StepPoints(max_steps + 1, jump_rows)
    else:

        def row_values(y, J):  # a jump's rows as the output has them (_rows does the others)
            return physical(stepper, y), local_index(J, ode.tau)

        observer = DenseOutput(jnp.asarray(ts, float), jump_rows, row_values)
    kind = "lax" if adjoint == "forward" else "checkpointed"
    ode, final = adaptive_loop(
        ode, stepper, y0, t0, t_final, observer,
        controller=controller, dt0=dt0, dtmin=dtmin, max_steps=max_steps, kind=kind, events=events,
    )  # fmt: skip
    return _solution(
        ode, stepper, final, step_points, jnp.asarray(t0, float), final.jumps is not None, kind, merge_jump_rows
    )


def _time_of(ode, final: _Carry) -> Array:
    """The physical time the loop ended at (s itself, or the t component in pseudo-time)."""
    index = getattr(ode, "time_index", None)
    return final.t if index is None else final.state.y[index]


def integrate_alpha_adaptive(ode: ODE, solver: AlphaMethod, y0, t0, t_final, **options) -> Solution:
    """:func:`integrate_adaptive` with the α-method (its name before other steppers joined the loop)."""
    return integrate_adaptive(ode, solver, y0, t0, t_final, **options)


# Rows of a run's output evaluated together after the loop (J_t, the DAE's v): the output keeps
# room for every jump (2·max_jumps rows beside the output times) or every step, and most of it
# stays empty, so the rows are taken a block at a time up to the last one in use.
ROW_BLOCK = 256


def map_rows_in_use(fn, rows: Float[Array, "m n"], count, kind: Literal["checkpointed", "lax"], block: int = ROW_BLOCK):
    """``jax.vmap(fn)(rows)`` on ``rows[:count]``, at most ``block`` rows at a time; the rows after repeat the last.

    (A dense output's rows after those in use repeat the last, the padding of
    :class:`~peeljax.integrators.observers.DenseOutput`; a step-point output's are invalid.)
    With 2·10⁴ rows kept for jumps and 301 output times, evaluating every row took 5 ms of a
    6 ms run (J_t at τ > 0). ``kind``: the loop's kind (equinox's checkpointed while loop
    where the run is differentiated in reverse mode).
    """
    n = rows.shape[0]
    if n <= block:
        return jax.vmap(fn)(rows)
    blocks = -(-n // block)
    block = -(-n // blocks)  # blocks of equal size: 320 rows as 2 × 160, not 2 × 256 (J_t at 512 rows: 85 µs, at 320: 61)
    shapes = jax.eval_shape(jax.vmap(fn), rows)
    zeros = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

    def body(carry):
        i, out = carry
        start = jnp.minimum(i * block, n - block)  # the last block ends at the last row
        values = jax.vmap(fn)(jax.lax.dynamic_slice_in_dim(rows, start, block))
        return i + 1, jax.tree_util.tree_map(
            lambda o, v: jax.lax.dynamic_update_slice_in_dim(o, v, start, 0), out, values
        )

    _, out = eqxi.while_loop(
        lambda carry: carry[0] * block < count, body, (jnp.asarray(0), zeros), max_steps=blocks, kind=kind,
        checkpoints=blocks if kind == "checkpointed" else None,
    )  # fmt: skip
    in_use = jnp.arange(n) < count
    last = jnp.clip(count - 1, 0, n - 1)

    def repeat_last(o):
        return jnp.where(in_use.reshape((n,) + (1,) * (o.ndim - 1)), o, jax.lax.dynamic_index_in_dim(o, last, 0))

    return jax.tree_util.tree_map(repeat_last, out)


def _rows(ode, stepper: AbstractStepper, final: _Carry, out: _Output, step_points: bool, folding: bool, kind):
    """``(ts, ys, valid, after_jump, diagnostics)`` of a record's rows ``out``: physical states,
    J_t and the local index, computed on the rows up to the last valid one only (a record's
    rows after it, most of those kept for jumps, are masked: NaN, index 0)."""
    valid = out.valid
    in_use = jnp.max(jnp.where(valid, jnp.arange(1, valid.shape[0] + 1), 0))
    completes = folding and getattr(ode, "completes_state", False)
    loop_J = step_points and isinstance(stepper, AlphaStepper)  # the α-method's J_t at its own steps

    def row(y_carried, J):
        if completes:  # an interpolated state's algebraic part (the DAE's v) is solved anew at it
            y_carried = ode.complete(y_carried)
        J = J if loop_J else ode.evaluate(y_carried).J
        return physical(stepper, y_carried), J, local_index(J, ode.tau)

    safe = jnp.where(valid[:, None], out.y, final.state.y)  # (the rows not in use are not evaluated)
    ys, Js, index = map_rows_in_use(lambda r: row(r[:-1], r[-1]), jnp.column_stack([safe, out.J]), in_use, kind)
    diagnostics = StepDiagnostics(
        newton_iterations=jnp.where(valid, out.iterations, 0),
        newton_correction=jnp.full(valid.shape, jnp.nan),
        schur=jnp.where(valid, Js, jnp.nan),
        local_index=jnp.where(valid, index, 0),
        condition=jnp.full(valid.shape, jnp.nan),
    )
    return out.t, jnp.where(valid[:, None], ys, jnp.nan), valid, out.after_jump, diagnostics


def _solution(
    ode, stepper: AbstractStepper, final: _Carry, step_points: bool, t0, folding: bool = False, kind="checkpointed",
    merge_jump_rows: bool = True,
) -> Solution:
    record = final.record
    sides = None
    if isinstance(record, _GridWithJumps):  # dense output with both sides of each jump
        ts, ys, valid, after_jump, diagnostics = _rows(ode, stepper, final, record.grid, step_points, folding, kind)
        sides = JumpSides(record.pairs, record.pair_counts, record.written)  # written finished by the loop (DenseOutput.row_values)
    else:
        ts, ys, valid, after_jump, diagnostics = _rows(ode, stepper, final, record, step_points, folding, kind)
        after_jump = after_jump if observer_keeps_jumps(record) else None
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
        **stepper.statistics(final.state),
    }
    if final.jumps is not None:
        stats["jumps"] = final.jumps.count
        stats["steps_cut_at_folds"] = final.cut_steps
        stats["fold_closest_miss"] = final.misses.miss
        stats["fold_closest_miss_t"] = final.misses.miss_t
        stats["grazed_at"] = final.misses.grazed_t
        stats["singular_passage_at"] = final.passed_t
    solution = Solution(
        ts=ts,
        ys=ys,
        valid=valid,
        status=final.state.status,
        t_stop=_time_of(ode, final),
        stats=stats,
        diagnostics=diagnostics,
        method=stepper.name,
        jumps=final.jumps,
        after_jump=after_jump,
        jump_sides=sides,
    )
    return solution if sides is None or not merge_jump_rows else sides.merge(solution)


class ErrorControl(AbstractIntegrator):
    """The one error-controlled loop with a stepper, as an integrator (:mod:`peeljax.integrators.base`).

    :meth:`integrate` is :func:`integrate_adaptive`; :meth:`observe` runs the same loop
    (:func:`adaptive_loop`) with a sweep lane's observer, so a lane takes exactly the steps of
    a single run.

    Attributes:
        method: the step: an :class:`AlphaMethod` (ρ, Newton's settings, log components) or a
            stepper (:class:`~peeljax.integrators.RungeKutta`: a diffrax Runge–Kutta solver).
        controller: the :class:`PIController` (rtol, atol, step-size update).
        dtmin: a proposed step below it stops the run (``STALLED``); None: 1e-12·(t_final − t0), at most 3e-12.
        max_steps: most step attempts, accepted or rejected (static).
        adjoint: ``"reverse"`` (``simulate``: tangents of a few perturbed numbers or the
            checkpointed loop, :mod:`.adjoint`; called directly, the checkpointed loop),
            ``"checkpointed"`` (the checkpointed while loop, for ``jax.grad``) or ``"forward"``
            (a plain while loop: ``jax.jvp``, and the fastest run when nothing is differentiated).
        events: what happens at the folds of φ (None: the paper's impasse stop).
    """

    dense_output: ClassVar[bool] = True
    method: AlphaMethod | AbstractStepper = AlphaMethod()
    controller: PIController = PIController()
    dtmin: Float[Array, ""] | None = eqx.field(converter=optional_float_array, default=None)
    max_steps: int = eqx.field(static=True, default=100_000)
    adjoint: str = eqx.field(static=True, default="reverse")
    events: FoldEvents | None = None
    save_jumps: bool = eqx.field(static=True, default=True)  # both sides of every jump in the output
    # False: the jumps' rows come back apart, merged on the host (simulate, outside jit)
    merge_jump_rows: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        check_adjoint(self.adjoint)
        check_max_steps(self.max_steps)
        as_stepper(self.method)

    @property
    def stepper(self) -> AbstractStepper:
        return as_stepper(self.method)

    @property
    def carried_log(self) -> tuple[int, ...]:
        return self.stepper.carried_log

    def integrate(self, ode, y0, t0, t_final, ts=None) -> Solution:
        return integrate_adaptive(
            ode, self.stepper, y0, t0, t_final, controller=self.controller, ts=ts, dtmin=self.dtmin,
            max_steps=self.max_steps, adjoint=self.adjoint, events=self.events, save_jumps=self.save_jumps,
            merge_jump_rows=self.merge_jump_rows,
        )  # fmt: skip

    def observe(self, ode, y0, t0, t_final, observer) -> ObservedRun:
        stepper = self.stepper
        carried_ode, final = adaptive_loop(
            ode, stepper, y0, t0, t_final, observer, controller=self.controller, dt0=None, dtmin=self.dtmin,
            max_steps=self.max_steps, kind="lax" if self.adjoint == "forward" else "checkpointed",
            events=self.events,
        )  # fmt: skip
        start_failed = (final.attempts == 0) & (final.state.status != 0)
        return ObservedRun(
            record=final.record,
            status=final.state.status,
            t_stop=_time_of(carried_ode, final),
            y_final=jnp.where(start_failed, jnp.nan, physical(stepper, final.state.y)),
            accepted_steps=final.accepted,
            rejected_steps=final.rejected,
            newton_iterations=final.newton_iterations,
            subdivided_steps=jnp.asarray(0, jnp.int32),
            max_subdivision_level=jnp.asarray(0, jnp.int32),
            jumps=final.jumps,
        )

    def settings(self) -> dict:
        stepper = self.stepper
        return {
            "method": stepper.name,
            "rtol": float(self.controller.rtol),
            "atol": float(self.controller.atol),
            "dtmin": None if self.dtmin is None else float(self.dtmin),
            "max_steps": self.max_steps,
            "solver": stepper.settings(),
            **({} if self.events is None else self.events.settings()),
        }
