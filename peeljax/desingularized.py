"""The DAE (τ = 0) in pseudo-time: the folds of φ become regular points (structure layer).

Between jumps the peeling DAE (``peel``) is of index 1 on a stable branch of φ, but its
solution is not smooth up to a fold: approaching the fold v̂ (or v̌) at a rate Ġ ≠ 0,
v ≈ v̂ − c·√(t* − t), so x = (α, ω, u) has a (t* − t)^{3/2} term that no step in t resolves
without shrinking towards t* (measured with Tsit5 on the paper's V = 1.1: ~25 attempts per
fold approach, half of a run's work), and the fold time moves like the square root of the
state's error.

Here the constraint (sac) is differentiated once (Ġ = F̃·f = ∂φ/∂v·v̇, the index-1 form) and
time is changed to a pseudo-time s in which v moves at a bounded rate through the fold:

    dt/ds = φ_w / N,   dx/ds = f(x, v)·dt/ds,   d(log v)/ds = Ġ / N,
    N = √(φ_w² + (ε·Ġ)²),   φ_w = v·∂φ/∂v  (∂φ/∂(log v)),

so that dv/dt = Ġ/∂φ/∂v, and t = s wherever |v̇/v| ≪ 1/ε (``time_scale`` ε). At a fold
∂φ/∂v = 0: t stops (dt/ds = 0) while log v passes at the rate 1/ε — every component is a
smooth function of s there, and the fold is the zero of ∂φ/∂v along the solution, crossed
transversally. This is the classical blow-up of a fold by a time change (the arclength
continuation of Keller, the "arclength refinement" of ``tests/jump_reference.py``), made
global: the fold needs no graded mesh, its event is a transversal zero of −φ_w, and the jump
time t* = t(s*) is insensitive to the event's position in s to first order (dt/ds = 0 there).

The carried state is y = (α, ω, u, v, t): t is a component (the loop's independent variable
is s, :func:`peeljax.integrators.adaptive.adaptive_loop` reads t from ``time_index``). u is
kept on the constraint: the field takes u = U(α, φ(v)) in closed form (F(u, α) is invertible:
:meth:`PeelingModel.stretch_for_force`), so an evaluation solves nothing — no root of φ is
searched, unlike :class:`~peeljax.ConstrainedDAE`'s v(x) — and ``complete`` projects the
carried u back onto the constraint after every step. The fully stuck tape (v = 0 while
G(x) < φ(0⁺, V): the constraint is then an inequality) is carried at the marker v_low (1e-100·max(V, 1)
m/s) with its own field, dt/ds = 1, ẋ = f(x, 0). Stuck and free are modes switched at a step's
end (:meth:`DesingularizedDAE.switch`: released where G(x) has risen above φ(v_low, V),
stuck where the branch's v has fallen below v_low), differentiated at fixed v (docs/theory.md,
"The tape that stops").

Every derivative is autodiff's (∂φ/∂(log v) and Ġ by ``jax.jvp``).
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._arrays import float_array
from .branches import STICK, Folds, branch_of, branch_velocity, fold_distance, jump_velocity
from .homogenized import Evaluation, Jump, _with_folds
from .model import PeelingModel

__all__ = ["DEFAULT_TIME_SCALE", "DesingularizedDAE", "tangential_fold"]

DEFAULT_TIME_SCALE = 1e-2  # ε [s]: chosen by measurement (docs/theory.md, "The DAE in pseudo-time")
_STUCK_BAND = 1e-9  # relative: v within it of v_low marks the fully stuck tape
_V_FLOOR = 1e-50  # × v_low: φ is evaluated at v no lower (its v-derivatives overflow below)


class DesingularizedDAE(eqx.Module):
    """The DAE (τ = 0) in pseudo-time s (module docstring): y = (α, ω, u, v, t).

    Meets the :class:`~peeljax.ODE` and :class:`~peeljax.homogenized.FoldingODE` contracts in
    pseudo-time (``evaluate(y).psi`` is dy/ds; ``time_index`` names t's component). Built by
    :meth:`peeljax.ConstrainedDAE.in_pseudo_time`; a stepper does that when asked
    (:class:`~peeljax.integrators.RungeKutta` ``time_scale``).

    Attributes:
        model, V, folds: as :class:`~peeljax.ConstrainedDAE`.
        time_scale: ε [s]: t = s where v changes by a factor e in much more than ε.
    """

    model: PeelingModel
    V: Float[Array, ""] = eqx.field(converter=float_array)
    time_scale: Float[Array, ""] = eqx.field(converter=float_array, default=DEFAULT_TIME_SCALE)
    folds: Folds | None = None
    completes_state: ClassVar[bool] = True
    time_index: ClassVar[int] = 4

    @property
    def tau(self) -> Array:
        return jnp.zeros(())

    def with_folds(self, folds: Folds | None = None) -> DesingularizedDAE:
        return _with_folds(self, folds)

    def extend(self, y0: Float[Array, "4"], t0) -> Float[Array, "5"]:
        """The carried state at t0 of a physical state y0 = (α, ω, u, v) (a fully stuck tape,
        v = 0, at v_low)."""
        y0 = jnp.asarray(y0, float)
        y0 = y0.at[3].set(jnp.maximum(y0[3], self._v_low()))
        return jnp.concatenate([y0, jnp.asarray(t0, float)[None]])

    def _v_low(self) -> Array:
        return self.folds.v_low if self.folds is not None else 1e-100 * jnp.maximum(self.V, 1.0)

    def _stuck(self, y) -> Array:
        """The tape is fully stuck: v carried at the marker v_low (within ``_STUCK_BAND``).

        A mode, not a test of G: the stuck field goes on past G = φ(v_low, V) (a continuous
        extension, as v is clamped past a fold) and a v on the branch goes on below v_low, so
        that the steps over either are ordinary ones; :meth:`switch` switches the mode
        at the step's end (:meth:`switches`)."""
        return jnp.abs(y[3] / self._v_low() - 1.0) <= _STUCK_BAND

    def _at_least_floor(self, v):
        """v, no lower than ``_V_FLOOR``·v_low: where φ is evaluated.

        A stage of a step that carries v below v_low to the stuck mode can reach v far below
        it (log v falls at the rate 1/ε: measured 1e-162 on a window row at 0.5 m/s whose
        branch ran down to v = 0); below ~1e-166 φ's second v-derivative (~v^(p−2), p = 0.15
        for the paper's family) overflows and a tangent through the stage is NaN. The field
        below the floor is the floor's, 1e-150 m/s from v = 0."""
        return jnp.maximum(v, _V_FLOOR * self._v_low())

    def _phi_and_slope(self, v):
        """φ(v, V) and φ_w = ∂φ/∂(log v) at v (at the floor below it: :meth:`_at_least_floor`)."""
        w = jnp.log(self._at_least_floor(v))
        return jax.jvp(lambda w: self.model.phi(jnp.exp(w), self.V), (w,), (jnp.ones_like(w),))

    def evaluate(self, y: Float[Array, "5"]) -> Evaluation:
        """dy/ds, J = −∂φ/∂v and Ġ = F̃·f (module docstring)."""
        alpha, omega, v = y[0], y[1], y[3]
        stuck = self._stuck(y)
        phi, phi_w = self._phi_and_slope(v)
        x = jnp.stack([alpha, omega, jnp.where(stuck, y[2], self.model.stretch_for_force(alpha, phi))])
        v_field = jnp.where(stuck, 0.0, v)
        f = self.model.f(x, v_field, self.V)
        G_dot = jax.jvp(self.model.shear_force, (x,), (f,))[1]
        scale = jnp.sqrt(phi_w**2 + (self.time_scale * G_dot) ** 2)
        regular = ~stuck & (scale > 0)
        safe = jnp.where(regular, scale, 1.0)
        dt = jnp.where(regular, phi_w / safe, 1.0)
        dv = jnp.where(regular, v * G_dot / safe, 0.0)
        psi = jnp.concatenate([f * dt, jnp.stack([dv, dt])])
        return Evaluation(psi=psi, J=-phi_w / self._at_least_floor(v), drive=G_dot)

    def __call__(self, y: Float[Array, "5"]) -> Float[Array, "5"]:
        return self.evaluate(y).psi

    def fold_event(self, y: Float[Array, "5"]) -> Array:
        """−∂φ/∂(log v) at v (N): negative on both stable branches, zero at a fold; −inf where
        φ has no fold or the tape is fully stuck."""
        _, phi_w = self._phi_and_slope(y[3])
        return jnp.where(self.folds.exist & ~self._stuck(y), -phi_w, -jnp.inf)

    def fold_distance(self, y: Float[Array, "5"]) -> Array:
        """How far G(x) is from the current branch's fold in N (:func:`peeljax.branches.fold_distance`):
        the DAE-in-time's fold event, whose rate in time is ±Ġ."""
        y = self.complete(y)
        return fold_distance(self.model, y[:3], self.V, branch_of(y[3], self.folds), self.folds)

    def velocity_field(self, y: Float[Array, "5"]) -> Float[Array, "3"]:
        """ẋ = f(x, v) in time at y (v = 0 on a fully stuck tape)."""
        y = self.complete(y)
        return self.model.f(y[:3], jnp.where(self._stuck(y), 0.0, y[3]), self.V)

    def complete(self, y: Float[Array, "5"]) -> Float[Array, "5"]:
        """y with u on the constraint, G(x) = φ(v, V), unless the tape is fully stuck (any
        state; a step's end where the mode switches is :meth:`switch`'s).

        An output inside the step that ends with a release, past G = φ(v_low, V), keeps the
        stuck v: the tape's v there, the root of G(x) = φ(v, V), is at most the v the release
        sets (measured from G = 100 N at V = 1.1: the releasing step ends 4.8 N past φ(0⁺) with
        v = 6.5e-10 m/s at rtol 1e-6, 7.8 N and 1.2e-8 m/s at rtol 1e-8). Solving it here, at
        every output, made the run's program 10 % slower to compile (``benchmarks/guard.py``:
        4.97 against 4.54 for the compile ratio)."""
        return self._on_constraint(y)

    def switches(self, y: Float[Array, "5"]) -> Array:
        """Whether the mode switches at the step's end y (:meth:`switch`): the stuck tape
        released (G(x) above φ(v_low, V)) or the free one fully stuck (v below v_low)."""
        return jax.lax.stop_gradient(self._releases(y) | self._sticks(y))

    def switch(self, y: Float[Array, "5"]) -> Float[Array, "5"]:
        """:meth:`complete` at a step's end where the mode switches (:meth:`switches`): the
        tape released onto the stick branch's root, or fully stuck at v_low, both at the step's
        x and differentiated at fixed v (:meth:`_at_velocity`). The field changes there, so the
        loop restarts the stepper after it (a Runge–Kutta method's first stage, reused from the
        step's end, was the other mode's)."""
        sg = jax.lax.stop_gradient
        released = self._releases(y)
        v_low = self._v_low()
        # its value alone (_at_velocity holds v in derivative), searched only where released
        root = branch_velocity(self.model, sg(y[:3]), sg(self.V), STICK, sg(self.folds), v_low, ~released)
        return self._on_constraint(self._at_velocity(y, jnp.where(released, self._free(root), v_low)))

    def _releases(self, y) -> Array:
        phi_zero = self.folds.phi_zero if self.folds is not None else self.model.phi(self._v_low(), self.V)
        return self._stuck(y) & (self.model.shear_force(y[:3]) > phi_zero)

    def _sticks(self, y) -> Array:
        return ~self._stuck(y) & (y[3] < self._v_low())

    def _free(self, v):
        """v set free: above the stuck mode's marker band."""
        return jnp.maximum(v, self._v_low() * (1.0 + 1e3 * _STUCK_BAND))

    def _on_constraint(self, y):
        """u on the constraint unless the tape is fully stuck."""
        u = self.model.stretch_for_force(y[0], self.model.phi(self._at_least_floor(y[3]), self.V))
        return y.at[2].set(jnp.where(self._stuck(y), y[2], u))

    def _at_velocity(self, y: Float[Array, "5"], v) -> Float[Array, "5"]:
        """The mode switched at the step's x: v set to ``v`` (near 0: the release's root, or the
        marker v_low), nothing else changed in value.

        v leaves or reaches 0 like |t − t*|^(1/p), p the smallest power of v in φ, so x moved
        with v = 0 or with the branch's v to the step's end differs by ∫v dt from the solution:
        for the paper's family (p = 0.15) v is 6.5e-10 m/s at the end of the releasing step at
        rtol 1e-6, 1.2e-8 at rtol 1e-8 (from G = 100 N at V = 1.1; :meth:`complete`).

        The derivative is that of the state where the perturbed run reaches the same v, not
        that at fixed pseudo-time: d(log v)/dG = 1/φ_w is ~1e14 near v = 0, so a tangent at
        fixed s carries a shift along the climb of log v that the output at fixed t cancels
        again (measured: Jacobians of the run 2e-4 to 75 % off, and periodic orbits through a
        stuck phase that Newton's method did not converge). With v held, the time moves by
        dτ = −(dG − ∂φ/∂θ·dθ)/Ġ (the implicit function theorem on G(x(t)) = φ(v, V)) and x by
        f(x, 0)·dτ.
        """
        sg = jax.lax.stop_gradient
        x = y[:3]
        flow = sg(self.model.f(x, 0.0, self.V))
        G_dot = sg(jax.jvp(self.model.shear_force, (sg(x),), (flow,))[1])
        v = sg(v)
        residual = self.model.shear_force(x) - self.model.phi(v, self.V)
        shift = -_tangent(residual) / jnp.where(G_dot != 0, G_dot, 1.0)
        return jnp.concatenate([x + flow * shift, jnp.stack([v, y[4] + shift])])

    def jump(self, y: Float[Array, "5"]) -> Jump:
        """v⁺ on the other branch at fixed x (the tape landing fully stuck: v_low, recorded as 0)."""
        y = self.complete(y)
        x, v = y[:3], y[3]
        branch = branch_of(v, self.folds)
        v_after = jump_velocity(self.model, x, self.V, branch, self.folds)
        carried = jnp.maximum(v_after, self._v_low())
        return Jump(
            y=y.at[3].set(carried), up=branch == 0, v_before=v, v_after=v_after,
            G=self.model.shear_force(x), F=self.model.tension(x[2], x[0]),
        )  # fmt: skip

    def constraint(self, y) -> Array:
        """Residual of (sac) at y (zero to round-off at the step ends: ``complete``)."""
        y = jnp.asarray(y)
        return self.model.constraint(y[..., :3].T if y.ndim > 1 else y[:3], y[..., 3], self.V)


def _tangent(a: Array) -> Array:
    """Zero in value, ``a``'s derivative in derivative."""
    return a - jax.lax.stop_gradient(a)


def tangential_fold(
    ode: DesingularizedDAE, y_fold: Float[Array, "5"], y_ref: Float[Array, "5"], y_far: Float[Array, "5"]
):
    """(Whether the fold at ``y_fold`` is reached tangentially, ``y_fold`` with the derivatives
    of a tangential fold taken from the reference states ``y_ref`` and ``y_far``.)

    At a tangential fold (G reaches φ's extremum with Ġ → 0: a folded singularity, the paper's
    first slip from its slow creep) the pseudo-time field (Ġ, ∂φ/∂v)/N is a ratio of two
    vanishing quantities, and the derivative of t(s) accumulated through its last stretch is
    not the solution's: measured on the paper's first slip, dt*/dc1 off by 5× (the values are
    right). There, as for the DAE in time (:func:`peeljax.integrators.events.locate_fold`), the
    fold's time is differentiated at a reference state of the branch before it, where g =
    G − φ(v̂) (:meth:`DesingularizedDAE.fold_distance`) and Ġ are resolved:
    dt* = dt_ref − dg_ref/ġ_ref (the tangents of y_ref are in pseudo-time: dg at fixed t is
    dg − ġ·dt); x at the fold gets dx_ref at fixed t (dx − f·dt) plus f·dt*, and v the
    derivative of the fold velocity v̂ (or v̌). The values of ``y_fold`` are unchanged.

    That estimate errs both ways: close to the fold the tangent of v is not resolved (u is
    kept on the constraint, so v's tangent carries the x-tangents' error over ∂φ/∂v → 0), and
    farther away the linearization errs in proportion to the time σ from the reference to the
    fold. With ``y_far``, a reference farther out, the two estimates are extrapolated linearly
    in σ to σ = 0 (where the far one is at least twice as far), so that both references can
    stay where v's tangent is resolved. Measured against central differences in
    ``tests/test_jump_gradients.py`` (V = 4.9: a 123 ms slip ending tangentially at v̌).

    Tangential: ġ at the fold below half the mean rate since the reference.
    """
    sg = jax.lax.stop_gradient
    index = ode.time_index
    slip = branch_of(sg(y_fold[3]), ode.folds) == 1
    sign = jnp.where(slip, -1.0, 1.0)
    rate_fold = sg(sign * ode.evaluate(y_fold).drive)
    f_fold = ode.velocity_field(sg(y_fold))

    def from_reference(y_ref):  # (tangential, dt*, dx* (both tangents only), σ)
        ref = ode.complete(y_ref)
        g_ref = ode.fold_distance(ref)
        rate_ref = sg(sign * ode.evaluate(ref).drive)
        sigma = sg(y_fold[index] - ref[index])
        mean_rate = sg(-g_ref) / jnp.where(sigma > 0, sigma, 1.0)
        tangential = (sigma > 0) & (rate_ref > 0) & (rate_fold < 0.5 * mean_rate)
        dt_star = _tangent(ref[index]) - _tangent(g_ref) / jnp.where(rate_ref > 0, rate_ref, 1.0)
        dx_ref = _tangent(ref[:3]) - ode.velocity_field(sg(ref)) * _tangent(ref[index])
        return tangential, dt_star, dx_ref + f_fold * dt_star, sigma

    # (one trace for both references: the loop's program compiles as with one)
    tangential, dt_star, dx_star, sigma = jax.vmap(from_reference)(jnp.stack([y_ref, y_far]))
    apart = tangential[0] & tangential[1] & (sigma[0] > 0) & (sigma[1] > 2.0 * sigma[0])
    weight = sigma[0] / jnp.where(apart, sigma[1] - sigma[0], 1.0)
    dt_star = jnp.where(apart, dt_star[0] + weight * (dt_star[0] - dt_star[1]), dt_star[0])
    dx_star = jnp.where(apart, dx_star[0] + weight * (dx_star[0] - dx_star[1]), dx_star[0])
    tangential = tangential[0]
    v_fold = jnp.where(slip, ode.folds.v_min, ode.folds.v_max)
    x = sg(y_fold[:3]) + dx_star
    v = sg(y_fold[3]) + _tangent(v_fold)
    t = sg(y_fold[index]) + dt_star
    return tangential, jnp.concatenate([x, jnp.stack([v, t])])
