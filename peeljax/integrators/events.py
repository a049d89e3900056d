"""Fold events inside the compiled loop: locate where G(x) reaches a fold of φ, then jump.

The error-controlled loop (:func:`peeljax.integrators.adaptive.adaptive_loop`) asks the ODE
(a :class:`~peeljax.homogenized.FoldingODE`) for its fold event g(y) after every step: g < 0
before the current branch's fold, g = 0 at it.

* A step whose end has g ≥ 0 crossed the fold: the event time is the root of g on the
  step's cubic Hermite interpolant (:func:`locate_fold`, bisection to round-off), the step is
  cut there (the observer sees the cut step) and the jump applies at the root — as diffrax's
  ``Event`` locates a root on its dense output. The DAE (τ = 0,
  :class:`~peeljax.ConstrainedDAE`) always crosses this way: its v is clamped past the fold,
  so the step over it is an ordinary one, and g = G(x) − φ(v̂, V) is smooth.
* The homogenized ODE (τ > 0) cannot step past an impasse point, where J_t → 0 while F̃·f
  stays finite and v̇ blows up: there J_t² falls linearly in t, so its secant over the last
  step predicts the time left, δ = J_t²·h/(J_t,prev² − J_t²); the event fires at t + δ once
  δ < ``time_tol`` (the steps up to there are the controller's own).

What follows is the user's choice, :class:`FoldEvents` ``mode``:

* ``"jump"`` (default): v jumps to the other stable branch at fixed x (the ODE's
  ``jump``), the jump is recorded (:class:`~peeljax.JumpRecord`), and the α-method restarts
  from the new state (ψ, a = dψ/dt and the Newton matrix anew; the first step from the
  initial-step heuristic), as after diffrax's events;
* ``"stop"``: the run ends at the fold (status ``FOLD``), the paper's behaviour;
* ``"follow"`` (τ > 0): jump at impasses only; where F̃·f changes sign with J_t (a singular
  passage) the homogenized solution is followed through it — another solution of the
  non-unique DAE there (the paper's theorem ``ithm``).

Derivatives: event times and the choice of branch are held fixed (``stop_gradient``);
gradients through a run with jumps are finite but do not yet include the motion of the
jump times (that is the implicit function theorem on g, a separate piece of work).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._arrays import float_array
from .dense import hermite

__all__ = ["FOLD_MODES", "FoldEvents", "FoldHit", "find_fold", "fold_event", "locate_fold"]

FOLD_MODES = ("jump", "stop", "follow")
_BISECTIONS = 60


class FoldEvents(eqx.Module):
    """What a run does at a fold of φ (module docstring).

    Attributes:
        mode: ``"jump"``, ``"stop"`` or ``"follow"`` (static).
        max_jumps: the jump record's size (static); one more jump stops the run with
            ``MAX_JUMPS``, keeping what it computed.
        time_tol: an impasse predicted closer than this [s] is taken as reached.
    """

    mode: str = eqx.field(static=True, default="jump")
    max_jumps: int = eqx.field(static=True, default=10_000)
    time_tol: Array = eqx.field(converter=float_array, default=1e-10)

    def __check_init__(self):
        check_fold(self.mode)
        check_max_jumps(self.max_jumps)

    def settings(self) -> dict:
        return {"fold": self.mode, "max_jumps": self.max_jumps, "event_time_tol": float(self.time_tol)}


def check_fold(fold) -> None:
    if fold not in FOLD_MODES:
        raise ValueError(f"fold must be one of {FOLD_MODES}, got {fold!r}")


def check_max_jumps(max_jumps) -> None:
    if isinstance(max_jumps, bool) or not isinstance(max_jumps, int) or max_jumps < 1:
        raise ValueError(f"max_jumps must be a positive integer, got {max_jumps!r}")


class FoldHit(eqx.Module):
    """Whether a step reached a fold, and where: the event time and state (before the jump)."""

    hit: Array
    t: Array
    y: Array


def fold_event(ode, y) -> Array:
    """The ODE's fold event g(y), for decisions only: no derivative flows through it (so a
    reverse pass stores nothing of it)."""
    return _stop(ode).fold_event(_stop(y))


def _stop(tree):
    """``lax.stop_gradient`` on a pytree's inexact arrays."""
    return jax.tree_util.tree_map(lambda a: jax.lax.stop_gradient(a) if eqx.is_inexact_array(a) else a, tree)


def locate_fold(ode, t0, h, y0, psi0, y1, psi1) -> Array:
    """θ ∈ [0, 1] with g(hermite(t0 + θh)) = 0, given g(y0) < 0 ≤ g(y1) (bisection to round-off).

    Nothing is differentiated here (θ is held fixed: see the module docstring).
    """
    ode, t0, h, y0, psi0, y1, psi1 = _stop((ode, t0, h, y0, psi0, y1, psi1))

    def g(theta):
        return ode.fold_event(hermite(t0, h, y0, psi0, y1, psi1, (t0 + theta * h)[None])[0])

    def bisect(_, bracket):
        lo, hi = bracket
        mid = 0.5 * (lo + hi)
        past = g(mid) >= 0
        return jnp.where(past, lo, mid), jnp.where(past, mid, hi)

    _, hi = jax.lax.fori_loop(0, _BISECTIONS, bisect, (jnp.zeros(()), jnp.ones(())))
    return jax.lax.stop_gradient(hi)


def find_fold(events: FoldEvents, ode, t0, h, state, new, accept, g0, g1) -> FoldHit:
    """Did the accepted step from ``state`` (at t0) to ``new`` (at t0 + h) reach a fold?

    ``g0``, ``g1``: the fold event at both ends. A crossing (g1 ≥ 0) is located on the step's
    interpolant; an impasse of the homogenized ODE is predicted from g² (module docstring).
    In ``"follow"`` mode a crossing where F̃·f changes sign too (a singular passage) is none.
    """
    crossed = accept & (g0 < 0) & (g1 >= 0)
    if events.mode == "follow":
        crossed = crossed & (state.drive * new.drive > 0)
    closing = accept & (g0 < 0) & (g1 < 0) & (g1 * g1 < g0 * g0)
    delta = jnp.where(closing, g1 * g1 * h / jnp.where(closing, g0 * g0 - g1 * g1, 1.0), jnp.inf)
    predicted = ~crossed & (delta < events.time_tol)

    def on_crossing():
        theta = locate_fold(ode, t0, h, state.y, state.psi, new.y, new.psi)
        return t0 + theta * h, hermite(t0, h, state.y, state.psi, new.y, new.psi, (t0 + theta * h)[None])[0]

    def otherwise():
        return t0 + h + jnp.where(predicted, delta, 0.0), new.y

    t_event, y_event = jax.lax.cond(crossed, on_crossing, otherwise)
    return FoldHit(hit=crossed | predicted, t=jax.lax.stop_gradient(t_event), y=y_event)
