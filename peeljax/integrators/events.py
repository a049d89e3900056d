"""Fold events inside the compiled loop: locate where G(x) reaches a fold of φ, then jump.

The error-controlled loop (:func:`peeljax.integrators.adaptive.adaptive_loop`) asks the ODE
(a :class:`~peeljax.homogenized.FoldingODE`) for its fold event g(y) after every step: g < 0
before the current branch's fold, g = 0 at it.

* A step whose end has g ≥ 0 crossed the fold: the event time is the root of g on the
  step's interpolant — the stepper's own dense output: the α-method's cubic Hermite one, a
  diffrax solver's (:func:`locate_fold`, bisection to round-off) — the step is
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

Derivatives: the choice of branch, the number of jumps and the step sizes are held fixed;
the motion of every jump is differentiated. A crossing's time is the root of g on the step's
interpolant, differentiated by the implicit function theorem on g (:func:`locate_fold`). The
homogenized ODE's event J_t = 0 is differentiated from a state before it whose tangents the
run resolves (the steps at the event do not resolve them: v̇ ~ 1/J_t at an impasse, and past a
singular passage the step's end has none): an impasse along the flow parametrized by v
(:func:`impasse_path`), a singular passage (F̃·f vanishing with J_t) on the flow linearized at
the crossing step's start (:func:`crossing_path`); v* by the implicit function theorem on
J_t(x*, v*) = 0 (:func:`schur_event`). The state after the jump is differentiated by the
implicit function theorem on G(x) = φ(v, V) at the new branch
(:func:`peeljax.branches.branch_velocity`), and the α-method restarts from it with a = dψ/dt
differentiated too. Together these are the saltation of the state at the jump, as diffrax's
``Event`` differentiates its event time and state.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._arrays import float_array
from .._validation import check_choice
from ..solution import JumpRecord
from .cycle_accumulator import CycleAccumulator

__all__ = [
    "FOLD_MODES", "FoldEvents", "FoldHit", "crossing_path", "event_rate", "find_fold", "fold_event", "fold_fraction",
    "impasse_path", "locate_fold", "schur_event",
]

FOLD_MODES = ("jump", "stop", "follow")
_BISECTIONS = 60


class FoldEvents(eqx.Module):
    """What a run does at a fold of φ (module docstring), and what it keeps of its jumps.

    Attributes:
        mode: ``"jump"``, ``"stop"`` or ``"follow"`` (static).
        max_jumps: the jump record's size (static). A plain record (default): one more jump
            stops the run at that fold, before the jump (``MAX_JUMPS``, the state there),
            keeping what it computed. A ring buffer (``ring``): the last ``max_jumps`` jumps are
            kept and the run goes on.
        time_tol: an impasse predicted closer than this [s] is taken as reached.
        ring: the record is a ring buffer (static; :class:`~peeljax.JumpRecord`): a run never
            stops for a full record. Sweeps and stick-slip maps use it.
        statistics: cycle statistics accumulated at every jump over a window
            (:class:`~peeljax.integrators.cycle_accumulator.CycleAccumulator`, as made by its
            ``over``); the record carries them (``JumpRecord.statistics``). None: none.
        folds_at_first_jump: search φ's folds at the run's first jump rather than before the
            run (static), where the fold event is J_t (τ > 0: the folds serve the jumps only), so
            that a run without a jump skips the search (~17 µs of P1's ~0.6 ms). For a run
            that is not batched only: under ``vmap`` the loop's ``lax.cond`` runs both branches,
            and the search would run at every step. :func:`peeljax.simulate` sets it for a run
            on concrete inputs.
    """

    mode: str = eqx.field(static=True, default="jump")
    max_jumps: int = eqx.field(static=True, default=10_000)
    time_tol: Array = eqx.field(converter=float_array, default=1e-10)
    ring: bool = eqx.field(static=True, default=False)
    statistics: CycleAccumulator | None = None
    folds_at_first_jump: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        check_fold(self.mode)
        check_max_jumps(self.max_jumps)
        for name in ("ring", "folds_at_first_jump"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")

    def empty_record(self) -> JumpRecord:
        """The record a run starts with: ``max_jumps`` empty slots (a ring buffer if ``ring``)."""
        return JumpRecord.empty(self.max_jumps, ring=self.ring, statistics=self.statistics)

    def settings(self) -> dict:
        settings = {"fold": self.mode, "max_jumps": self.max_jumps, "event_time_tol": float(self.time_tol)}
        if self.ring:  # (a plain record's settings stay as they were: saved runs compare them)
            settings["jump_record"] = "ring"
        return settings


def check_fold(fold) -> None:
    check_choice("fold", fold, FOLD_MODES)


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


def event_rate(ode, y) -> Array:
    """ġ = ∇g(y)·ψ(y): how fast the fold event changes along the flow (autodiff of the model)."""
    return jax.jvp(ode.fold_event, (y,), (ode.evaluate(y).psi,))[1]


def locate_fold(ode, t0, h, interpolant, reference=None, reference_g=None) -> Array:
    """θ ∈ [0, 1] with g(y(t0 + θh)) = 0 on the step's interpolant y(·), given g < 0 at t0 ≤ g at t0 + h.

    The root θ* is found by bisection to round-off with nothing differentiated; what is
    returned equals θ* in value and carries the implicit function theorem's derivative
    through the interpolant (its end points and, for a Runge–Kutta solver, its stages) and
    the ODE's parameters (φ's coefficients, V, the model), as diffrax differentiates an
    ``Event``'s time; ``h`` is held fixed (the controller's step sizes are constants of the
    derivative):

    * a transversal crossing (ġ > 0 at the root): dθ = −(∂g at fixed θ)/g'(θ*);
    * a tangential one, ġ at the root below half the mean rate since the step's start: the
      run reaches the fold with ġ → 0, through a folded singularity of the DAE (ġ = 0 and
      ∂φ/∂v = 0 together; the first slip from the paper's slow creep does, see
      ``docs/fitting.md``). There g ≈ −a·(t* − t)², its root moves like the square root of the
      state's error, and ∂g/∂p and ġ both vanish at it; their ratio does not, and is taken at
      a reference state of the same branch a little before the fold, where both are
      resolved: dt* = −(∂g/∂p)/ġ there. The reference is the point of this step's
      interpolant where g = ``reference_g`` (the loop passes −1e-5·|g| at the branch's
      start: ~0.35 ms before the paper's first slip), or ``reference`` (the latest accepted
      state with g below it) where the step starts above that level. The depth is a measured
      balance: closer to the fold ∂g/∂p is a small difference of O(1) tangents, swamped by
      the step's error (1e-8: Tsit5's derivative 0.6 % off at rtol 1e-8 and 70 % off at
      1e-7); farther, the ratio drifts (the step's start, ~1 ms before the fold with Tsit5:
      off by up to 2×). At 1e-5 the paper's first slip's dt*/dc1 is within 0.01 % of its
      converged value at rtol 1e-9, 0.2 % at 1e-7 and 0.7 % at 1e-6, for Tsit5 and the
      α-method alike (``tests/test_steppers.py``).
    """
    h = jax.lax.stop_gradient(h)

    def g(ode, t0, interpolant, theta):
        return ode.fold_event(interpolant.evaluate((t0 + theta * h)[None])[0])

    frozen = _stop((ode, t0, interpolant))

    def bisect_for(level):
        def bisect(_, bracket):
            lo, hi = bracket
            mid = 0.5 * (lo + hi)
            past = g(*frozen, mid) >= level
            return jnp.where(past, lo, mid), jnp.where(past, mid, hi)

        return bisect

    _, root = jax.lax.fori_loop(0, _BISECTIONS, bisect_for(0.0), (jnp.zeros(()), jnp.ones(())))
    root = jax.lax.stop_gradient(root)
    _, slope = jax.jvp(lambda theta: g(*frozen, theta), (root,), (jnp.ones(()),))
    residual = g(ode, t0, interpolant, root)
    transversal = root - (residual - jax.lax.stop_gradient(residual)) / jnp.where(slope > 0, slope, 1.0)
    if reference is None:
        return transversal
    g_start = g(*frozen, jnp.zeros(()))
    mean_rate = -g_start / jnp.maximum(root * h, jnp.finfo(float).tiny)
    frozen_ode = frozen[0]
    tangential = event_rate(frozen_ode, frozen[2].evaluate((frozen[1] + root * h)[None])[0]) < 0.5 * mean_rate
    level = jnp.zeros(()) if reference_g is None else jax.lax.stop_gradient(reference_g)
    inside = (reference_g is not None) & (g_start < level)
    _, theta_ref = jax.lax.fori_loop(0, _BISECTIONS, bisect_for(level), (jnp.zeros(()), root))
    theta_ref = jax.lax.stop_gradient(theta_ref)
    # the reference with its derivative: on this step's interpolant at fixed θ_ref, or the state kept
    y_ref = jnp.where(inside, interpolant.evaluate((t0 + theta_ref * h)[None])[0], reference)
    g_ref = ode.fold_event(y_ref)
    rate_ref = jax.lax.stop_gradient(event_rate(frozen_ode, jax.lax.stop_gradient(y_ref)))
    rate_ref = jnp.where(rate_ref > 0, rate_ref, 1.0)
    # dθ = −(∂g/∂p)/(ġ·h) at the reference (zero in value)
    tangent = root - (g_ref - jax.lax.stop_gradient(g_ref)) / (rate_ref * h)
    return jnp.where(jax.lax.stop_gradient(tangential), tangent, transversal)


def fold_fraction(ode, t0, h, interpolant) -> Array:
    """θ* ∈ [0, 1] of :func:`locate_fold` in value only (a step-size decision: nothing differentiated)."""
    return jax.lax.stop_gradient(locate_fold(_stop(ode), _stop(t0), h, _stop(interpolant)))


# The homogenized ODE's v: the component whose rate blows up at an impasse (carried as log v
# by the α-method), the independent variable of the path from the reference to the impasse.
_V = 3
# Steps of the path in v (Heun's third-order method: its stages never reach the impasse itself).
# Only a differentiated run takes them. Measured (τ = 1e-3, V = 1.1, d/dc1 of y(0.3 s) and the
# first 6 jump times at rtol 1e-9 against Richardson-extrapolated central differences of
# rtol-1e-11 runs): worst 1.7e-4 with 32 steps, 4.9e-5 with 64, 3.4e-5 with 128 (the rest is
# not the path's). Each step is one more stage in the checkpointed loop's pullback: 64.
_PATH_STEPS = 64


def impasse_path(ode, t_ref, y_ref, v_star) -> tuple[Array, Array]:
    """(t, x) at the impasse v = ``v_star`` reached from the reference state (t_ref, y_ref) along
    the flow parametrized by v: dt/dv = 1/ψ_v, dx/dv = ψ_x/ψ_v.

    In time the impasse is singular (ψ_v ~ 1/J_t → ∞, v ~ v* − c·√(t* − t)); in v the path is
    smooth and passes it regularly, with dt/dv = dx/dv = 0 there. So the impasse's time and x
    move with the parameters as the path's end at a fixed v* (the shift of v* is of second
    order: an envelope)."""
    x_ref, w_ref = y_ref[:_V], y_ref[_V]
    dw = (v_star - w_ref) / _PATH_STEPS

    def rate(w, z):  # z = (t, x)
        psi = ode.evaluate(jnp.concatenate([z[1:], w[None]])).psi
        dt_dw = 1.0 / psi[_V]
        return jnp.concatenate([dt_dw[None], psi[:_V] * dt_dw])

    def heun3(i, z):
        w = w_ref + i * dw
        k1 = rate(w, z)
        k2 = rate(w + dw / 3, z + dw / 3 * k1)
        k3 = rate(w + 2 * dw / 3, z + 2 * dw / 3 * k2)
        return z + dw * (0.25 * k1 + 0.75 * k3)

    z = jax.lax.fori_loop(0, _PATH_STEPS, heun3, jnp.concatenate([jnp.reshape(t_ref, (1,)), x_ref]))
    return z[0], z[1:]


def crossing_path(ode, t_ref, y_ref, v_star) -> tuple[Array, Array]:
    """(t, x) where J_t reaches 0 on the flow linearized at (t_ref, y_ref), the start of the step
    over it (``v_star`` unused: the signature of :func:`impasse_path`): t = t_ref + δ, x = x_ref + f·δ, δ = −J_t/J̇_t. J_t crosses zero transversally (a
    singular passage: F̃·f vanishes with it, ψ stays finite), and the start's tangents are
    resolved where the step's end, past the singular point, has no resolved tangents."""
    evaluation = ode.evaluate(y_ref)
    J_dot = jax.jvp(lambda y: ode.evaluate(y).J, (y_ref,), (evaluation.psi,))[1]
    delta = -evaluation.J / jnp.where(J_dot != 0, J_dot, 1.0)
    return t_ref + delta, y_ref[:_V] + evaluation.psi[:_V] * delta


def _schur_along_v(ode, x, w) -> tuple[Array, Array]:
    """(J_t, ∂J_t/∂v) at (x, v = w), v in the ODE's carried coordinate."""
    return jax.jvp(lambda w: ode.evaluate(jnp.concatenate([x, w[None]])).J, (w,), (jnp.ones_like(w),))


def _impasse_velocity(ode, y, iterations: int = 3) -> Array:
    """v* with J_t(x, v*) = 0 at y's x, by Newton's method from y's v (values only)."""
    x = y[:_V]

    def newton(_, w):
        J, J_v = _schur_along_v(ode, x, w)
        return jnp.where((J_v != 0) & jnp.isfinite(J), w - J / jnp.where(J_v != 0, J_v, 1.0), w)

    return jax.lax.fori_loop(0, iterations, newton, y[_V])


@eqx.filter_custom_jvp
def schur_event(ode, t_ref, y_ref, t_event, y_event, *, path):
    """The homogenized ODE's fold event (J_t = 0) at (t_event, y_event) in value; its derivatives
    those of ``path`` (:func:`impasse_path` or :func:`crossing_path`) from a state where the
    steps' tangents are resolved, and v* by the implicit function theorem on J_t(x*, v*) = 0.
    Computed only where the run is differentiated."""
    return t_event, y_event


@schur_event.def_jvp
def _schur_event_jvp(primals, tangents, *, path):
    ode, t_ref, y_ref, t_event, y_event = primals
    v_star = jax.lax.stop_gradient(_impasse_velocity(_stop(ode), _stop(y_event)))

    def moved(ode, t_ref, y_ref):
        t, x = path(ode, t_ref, y_ref, v_star)
        J, J_v = _schur_along_v(ode, x, v_star)
        v = v_star - J / jax.lax.stop_gradient(J_v)  # v* in value; dv* = −dJ_t/(∂J_t/∂v)
        return t, jnp.concatenate([x, v[None]])

    zero = lambda p, t: jnp.zeros_like(p) if t is None else t  # noqa: E731
    tangents = (tangents[0], zero(t_ref, tangents[1]), zero(y_ref, tangents[2]))
    _, (dt, dy) = eqx.filter_jvp(moved, (ode, t_ref, y_ref), tangents)
    return (t_event, y_event), (dt, dy)


def find_fold(
    events: FoldEvents, ode, t0, h, state, new, interpolant, accept, g0, g1, reference=None, reference_g=None,
    impasse_reference=None,
) -> FoldHit:
    """Did the accepted step from ``state`` (at t0) to ``new`` (at t0 + h) reach a fold?

    ``g0``, ``g1``: the fold event at both ends (values); ``interpolant``: the step's dense
    output; ``reference``, ``reference_g``: see :func:`locate_fold`; ``impasse_reference``: (t, y)
    of the homogenized ODE's reference state (its fold event J_t = 0 is then differentiated by
    :func:`schur_event`). A crossing (g1 ≥ 0) is located on the step's interpolant; an impasse of the homogenized ODE is predicted from g² (module docstring).
    In ``"follow"`` mode a crossing where F̃·f changes sign too (a singular passage) is none.
    """
    crossed = accept & (g0 < 0) & (g1 >= 0)
    if events.mode == "follow":
        crossed = crossed & (state.drive * new.drive > 0)
    closing = accept & (g0 < 0) & (g1 < 0) & (g1 * g1 < g0 * g0)
    delta = jnp.where(closing, g1 * g1 * h / jnp.where(closing, g0 * g0 - g1 * g1, 1.0), jnp.inf)
    # Only the homogenized ODE's impasse is predicted (the DAE's g crosses zero: located).
    predicted = ~crossed & (delta < events.time_tol) & getattr(ode, "fold_event_is_schur", False)
    at_impasse = impasse_reference is not None and getattr(ode, "fold_event_is_schur", False)

    def on_crossing():
        if not at_impasse:
            theta = locate_fold(ode, t0, h, interpolant, reference, reference_g)
            return t0 + theta * h, interpolant.evaluate((t0 + theta * h)[None])[0]
        # The homogenized ODE's J_t crossing zero: located on the interpolant in value only (its
        # end, past the singular point, has no resolved tangents; reverse mode would carry their
        # NaN even times a zero cotangent). Where F̃·f changes sign too, a singular passage:
        # differentiated from the step's start. Where it keeps its sign, an impasse the step
        # passed rather than approached (whether it is predicted or crossed is decided by
        # round-off: a run in forward mode and the same run in reverse mode differ there):
        # differentiated as a predicted one, along the path from the reference state.
        t = jax.lax.stop_gradient(t0 + fold_fraction(ode, t0, h, interpolant) * h)
        y = jax.lax.stop_gradient(interpolant.evaluate(t[None])[0])
        passage = jax.lax.stop_gradient(state.drive * new.drive <= 0)
        return jax.lax.cond(
            passage,
            lambda: schur_event(ode, t0, state.y, t, y, path=crossing_path),
            lambda: schur_event(ode, *impasse_reference, t, y, path=impasse_path),
        )

    def otherwise():
        t_end = t0 + h + jnp.where(predicted, delta, 0.0)
        if not at_impasse:
            return t_end, new.y
        # A predicted impasse: its derivatives from the reference state (impasse_path), not from
        # the steps at the singularity, whose sensitivities the error control does not resolve.
        at_event = lambda: schur_event(  # noqa: E731
            ode, *impasse_reference, jax.lax.stop_gradient(t_end), jax.lax.stop_gradient(new.y), path=impasse_path
        )
        return jax.lax.cond(predicted, at_event, lambda: (t_end, new.y))

    t_event, y_event = jax.lax.cond(crossed, on_crossing, otherwise)
    return FoldHit(hit=crossed | predicted, t=t_event, y=y_event)
