"""The homogenized ODE (eq. ``hv``) that replaces the constraint (sac).

For y = (α, ω, u, v):

    ψ(y; τ) = ( f(x, v),  −J_t(τ)⁻¹·F̃·f(x, v) )                    (hv)

Variants, chosen by ``truncation``:

* ``None`` (default): the exact Schur complement J_t(τ) of Lemma 1;
* ``m ≥ 1``: its m-term Neumann truncation, eq. ``hvex`` (converges only for τ·ρ(∂f/∂x) < 1);
* ``0``: the τ → 0 limit J_t = −∂φ/∂v, i.e. the index-1 ODE v̇ = F̃·f/(∂φ/∂v) obtained by
  differentiating (sac) once.

Along the exact flow, d/dt[G(x) − φ] = F̃·f·τ·c/J_t with c = F̃(𝐈 − τ∂f/∂x)⁻¹∂f/∂v: the
constraint is kept exactly only in the index-1 limit; τ > 0 relaxes it and smooths v.

The fully stuck tape. Below φ(0⁺, V) the stick branch has no root: the DAE (τ = 0) holds v = 0
until G(x) rises back above φ(0⁺, V) (:mod:`peeljax.branches`). Eq. ``hv`` with φ itself would
instead drive v to 0 in finite time: near v = 0, φ ≈ φ(0⁺) + c₂·v^p₂ (p₂ = 0.15), so
d(log v)/dt ≈ F̃·f/(p₂·c₂·v^p₂) → −∞ while G falls, and the step size collapses (issue 30:
V = 1.1, τ = 3.3e-3 stopped at t = 0.388 s with v = 5e-54). Below the floor v_s = 1e-12·V (under the
paper's starting velocity 1e-10·V, so that its start is on φ itself) ψ therefore uses φ's C¹ continuation linear in log v,

    Φ(v, V) = φ(v_s, V) + K·log(v/v_s)  (v < v_s),   K = ∂φ/∂(log v) at v_s,

and φ itself for v ≥ v_s. Then d(log v)/dt ≈ F̃·f/K stays bounded: while G falls below φ(v_s),
log v falls with it (v < 1e-12·V: x moves as with v = 0, the stuck tape to O(v_s)); once G is
back at φ(v_s), v is back at v_s and goes on up the stick branch as the DAE's does — the depth
log(v/v_s) records how far G went below φ(v_s). ψ is continuous across v_s (Φ is C¹ there): the
error control passes the floor without a switch, and autodiff differentiates through a stuck
phase as through any smooth flow (the time the tape leaves needs no event). A run that stays
above the floor is unchanged. A jump landing below φ(v_s) lands on Φ (:meth:`HomogenizedODE.jump`),
as the DAE's lands on v = 0; a fully stuck start is given at
v = :meth:`HomogenizedODE.stuck_velocity`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar, Protocol, runtime_checkable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._arrays import float_array
from .branches import SLIP, STICK, Folds, branch_of, jump_velocity, phi_folds
from .model import PeelingModel
from .structure import jacobians, schur_complement, truncated_schur_complement

__all__ = ["ODE", "STUCK_FLOOR_FACTOR", "ContinuedAdhesion", "Evaluation", "HomogenizedODE", "Jump", "floor_of"]


class Evaluation(eqx.Module):
    """ψ(y) with the quantities it is made of (used for diagnostics and stop tests)."""

    psi: Float[Array, "4"]
    J: Float[Array, ""]  # the (possibly truncated) Schur complement
    drive: Float[Array, ""]  # F̃·f, the rate of change of the shear force


class Jump(eqx.Module):
    """A jump of v at a fold, x unchanged: the state after it and what a :class:`~peeljax.JumpRecord` keeps."""

    y: Float[Array, "4"]  # the state after the jump
    up: Array  # stick → slip
    v_before: Array
    v_after: Array
    G: Array
    F: Array  # the tension (k/l)·u, unchanged by the jump


@runtime_checkable
class ODE(Protocol):
    """What peeljax's α-method integrators take: y' = ψ(y) with the quantities of its stop tests.

    ``evaluate(y)`` returns an :class:`Evaluation`: ψ(y), J_t (a run stops at an impasse point,
    where J_t changes sign while ``drive`` = F̃·f does not) and F̃·f; ``tau`` is the
    homogenization time scale (for the local index in the diagnostics). It must be a pytree
    (an ``eqx.Module``) of traced arrays and static fields, differentiable by JAX.
    :class:`HomogenizedODE` is the peeling problem; ``tests/conftest.py`` has a linear one
    (J_t = −1, F̃·f = 0: never an impasse).
    """

    tau: Array

    def evaluate(self, y: Float[Array, " n"]) -> Evaluation: ...


class FoldingODE(ODE, Protocol):
    """An :class:`ODE` that a run can carry through the folds of φ (``fold="jump"``).

    ``with_folds()`` returns the ODE with φ's folds computed (once per run, inside the
    compiled loop); ``fold_event(y)`` is negative before the current branch's fold and
    crosses zero at it; ``jump(y)`` is the jump there (:class:`Jump`); ``complete(y)`` maps an
    integrator's state (for instance an interpolated one) to the output state, and the
    integrator calls it on every accepted and output state where ``completes_state`` is True.
    """

    def with_folds(self, folds: Folds | None = None) -> FoldingODE: ...

    def fold_event(self, y: Float[Array, " n"]) -> Array: ...

    def jump(self, y: Float[Array, " n"]) -> Jump: ...

    def complete(self, y: Float[Array, " n"]) -> Float[Array, " n"]: ...


# K ≥ this × |φ(v_s, V)|, for a law nearly flat at v_s (not the paper's: K = 0.53 N against
# 0.26 N at V = 1.1): with G ≥ 0 a stuck phase then stays within 500 e-folds of the floor
# (v ≥ 1e-227·V), where exp(log v) does not underflow.
_SLOPE_FLOOR = 2e-3

# v_s / V. Below the paper's start v0 = 1e-10·V, so that start lies on φ itself: a start on the
# floor would sit where ∂²Φ/∂v² jumps, and the start's a_0 = ψ'(y_0)·ψ(y_0) would be one-sided
# in V (measured: d/dV of a run from a fixed y0, 4.7 by autodiff against −97 by differences).
STUCK_FLOOR_FACTOR = 1e-12


def floor_of(law: Callable, V: ArrayLike) -> tuple[Array, Array, Array]:
    """(v_s, φ(v_s, V), K): the floor v_s = 1e-12·V below which ψ continues φ linearly in log v
    (module docstring), φ there and the slope K = ∂φ/∂(log v) at v_s (at least 2e-3·|φ(v_s, V)|)."""
    v_s = STUCK_FLOOR_FACTOR * jnp.asarray(V, float)
    phi_s, slope = jax.jvp(lambda v: law(v, V), (v_s,), (v_s,))  # v·∂φ/∂v = ∂φ/∂(log v)
    return v_s, phi_s, jnp.maximum(slope, _SLOPE_FLOOR * jnp.abs(phi_s))


class ContinuedAdhesion(eqx.Module):
    """Φ(v, V): the adhesion law ``law`` for v ≥ v_s = 1e-12·V, φ(v_s) + K·log(v/v_s) below
    (module docstring, :func:`floor_of`); C¹ at v_s, increasing, unbounded below as v → 0."""

    law: Callable

    def __call__(self, v: ArrayLike, V: ArrayLike) -> Array:
        v = jnp.asarray(v, float)
        v_s, phi_s, slope = floor_of(self.law, V)
        above = v >= v_s
        # Double wheres: neither branch sees the other's arguments (no log of v ≤ 0, no φ'' at v → 0).
        phi = self.law(jnp.where(above, v, v_s), V)
        depth = jnp.log(jnp.where(above, v_s, jnp.maximum(v, jnp.finfo(float).tiny)) / v_s)
        return jnp.where(above, phi, phi_s + slope * depth)


class HomogenizedODE(eqx.Module):
    """ψ(y; τ) of eq. ``hv`` for a model at pull velocity V.

    ``V`` and ``tau`` are traced arrays (no recompilation when they change; ``vmap`` and
    ``grad`` work over them); ``truncation`` is static.
    """

    model: PeelingModel
    V: Float[Array, ""] = eqx.field(converter=float_array)
    tau: Float[Array, ""] = eqx.field(converter=float_array)
    truncation: int | None = eqx.field(static=True, default=None)
    folds: Folds | None = None
    # fold="stop" keeps the paper's stop test (an impasse point) rather than a fold event.
    stops_at_impasse: ClassVar[bool] = True
    # The fold event is J_t, which every step computes already (the loop reuses it).
    fold_event_is_schur: ClassVar[bool] = True

    def evaluate(self, y: Float[Array, "4"]) -> Evaluation:
        """ψ(y) together with J_t and F̃·f (the stop tests and diagnostics need them)."""
        x, v = y[:3], y[3]
        jac = jacobians(self.continued_model, x, v, self.V)
        if self.truncation is None:
            J = schur_complement(jac, self.tau)
        else:
            J = truncated_schur_complement(jac, self.tau, self.truncation)
        drive = jnp.dot(jac.F_tilde, jac.f)
        psi = jnp.concatenate([jac.f, (-drive / J)[None]])
        # Below the floor J_t ≈ −K/v grows as v falls: reported as J_t·v/v_s (its value at the
        # floor, same sign), so that the impasse predictor's secant of J_t² (events module) does
        # not read a stuck tape's departure, J_t² falling by e² per e-fold of v, as an impasse.
        floor = STUCK_FLOOR_FACTOR * self.V
        J = jnp.where(v >= floor, J, J * (v / floor))
        return Evaluation(psi=psi, J=J, drive=drive)

    def __call__(self, y: Float[Array, "4"]) -> Float[Array, "4"]:
        """ψ(y) (eq. ``hv``)."""
        return self.evaluate(y).psi

    @property
    def continued_model(self) -> PeelingModel:
        """The model with φ continued below the floor v_s (:class:`ContinuedAdhesion`): what ψ uses."""
        return eqx.tree_at(lambda m: m.adhesion, self.model, ContinuedAdhesion(self.model.adhesion))

    def stuck_velocity(self, x: Float[Array, "3"]) -> Array:
        """v of the fully stuck tape at x: the root of G(x) = Φ(v, V) below the floor,
        v_s·exp((G(x) − φ(v_s, V))/K) (v_s where G(x) is above φ(v_s, V)).

        The state (x, stuck_velocity(x)) is a fully stuck start: the tape leaves when G rises
        to φ(v_s, V), as the DAE's leaves v = 0 at φ(0⁺, V) ≈ φ(v_s, V) − 3.7 N (V = 1.1).
        """
        _, phi_s, slope = floor_of(self.model.adhesion, self.V)
        v_s = STUCK_FLOOR_FACTOR * self.V
        return v_s * jnp.exp(jnp.minimum(self.model.shear_force(x) - phi_s, 0.0) / slope)

    # ------------------------------------------------------------------ folds (fold="jump")
    def with_folds(self, folds: Folds | None = None) -> HomogenizedODE:
        """This ODE with φ's folds: ``folds`` where given, else computed (:func:`peeljax.branches.phi_folds`)."""
        return _with_folds(self, folds)

    def fold_event(self, y: Float[Array, "4"]) -> Array:
        """J_t(τ) at y: negative on a stable branch, zero where the homogenized solution ends
        (an impasse, F̃·f ≠ 0) or passes a singular point (F̃·f = 0 too)."""
        return self.evaluate(y).J

    def jump(self, y: Float[Array, "4"]) -> Jump:
        """v⁺ on the other stable branch of G(x) = φ(v, V), x unchanged.

        A landing below the floor (G(x) < φ(v_s, V): the DAE's v⁺ is below 1e-12·V, or 0 where
        the tape lands fully stuck) is on ψ's continuation Φ, at :meth:`stuck_velocity`; the
        record keeps the DAE's v⁺ (0: fully stuck), as at τ = 0.
        """
        x, v = y[:3], y[3]
        branch = branch_of(v, self.folds)
        v_after = jump_velocity(self.model, x, self.V, branch, self.folds)
        G = self.model.shear_force(x)
        _, phi_s, _ = floor_of(self.model.adhesion, self.V)
        carried = jnp.where((branch == SLIP) & (G < phi_s), self.stuck_velocity(x), v_after)
        return Jump(
            y=y.at[3].set(carried), up=branch == STICK, v_before=v, v_after=v_after, G=G,
            F=self.model.tension(x[2], x[0]),
        )  # fmt: skip

    def complete(self, y: Float[Array, "4"]) -> Float[Array, "4"]:
        """y itself: the homogenized state is the output state (the integrator need not call it)."""
        return y

    def schur_complement(self, y: Float[Array, "4"]) -> Array:
        """J_t(τ) at y (or its truncation)."""
        return self.evaluate(y).J

    def constraint(self, y: ArrayLike) -> Array:
        """Residual of (sac) at y: how far the homogenized state is from the DAE's manifold."""
        y = jnp.asarray(y)
        return self.model.constraint(y[..., :3].T if y.ndim > 1 else y[:3], y[..., 3], self.V)


def _jump(model: PeelingModel, V, folds: Folds, y, floor=0.0) -> Jump:
    """The jump at a fold from state y: v to the other branch at fixed x (no floor: v⁺ may be 0)."""
    x, v = y[:3], y[3]
    branch = branch_of(v, folds)
    v_after = jnp.maximum(jump_velocity(model, x, V, branch, folds), floor)
    return Jump(
        y=y.at[3].set(v_after), up=branch == 0, v_before=v, v_after=v_after, G=model.shear_force(x),
        F=model.tension(x[2], x[0]),
    )  # fmt: skip


def _with_folds(ode, folds: Folds | None = None):
    """``ode`` (with ``model``, ``V`` and ``folds`` fields) with ``folds``, or with φ's folds at
    its V computed, once."""
    if folds is None and ode.folds is not None:
        return ode
    folds = phi_folds(ode.model, ode.V) if folds is None else folds
    return eqx.tree_at(lambda o: o.folds, ode, folds, is_leaf=lambda x: x is None)
