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
"""

from __future__ import annotations

from typing import ClassVar, Protocol, runtime_checkable

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._arrays import float_array
from .branches import Folds, branch_of, jump_velocity, phi_folds
from .model import PAPER_V0_FACTOR, PeelingModel
from .structure import jacobians, schur_complement, truncated_schur_complement

__all__ = ["ODE", "Evaluation", "HomogenizedODE", "Jump"]


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

    def with_folds(self) -> FoldingODE: ...

    def fold_event(self, y: Float[Array, " n"]) -> Array: ...

    def jump(self, y: Float[Array, " n"]) -> Jump: ...

    def complete(self, y: Float[Array, " n"]) -> Float[Array, " n"]: ...


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
        jac = jacobians(self.model, x, v, self.V)
        if self.truncation is None:
            J = schur_complement(jac, self.tau)
        else:
            J = truncated_schur_complement(jac, self.tau, self.truncation)
        drive = jnp.dot(jac.F_tilde, jac.f)
        psi = jnp.concatenate([jac.f, (-drive / J)[None]])
        return Evaluation(psi=psi, J=J, drive=drive)

    def __call__(self, y: Float[Array, "4"]) -> Float[Array, "4"]:
        """ψ(y) (eq. ``hv``)."""
        return self.evaluate(y).psi

    # ------------------------------------------------------------------ folds (fold="jump")
    def with_folds(self) -> HomogenizedODE:
        """This ODE with φ's folds (:func:`peeljax.branches.phi_folds`) computed."""
        return _with_folds(self)

    def fold_event(self, y: Float[Array, "4"]) -> Array:
        """J_t(τ) at y: negative on a stable branch, zero where the homogenized solution ends
        (an impasse, F̃·f ≠ 0) or passes a singular point (F̃·f = 0 too)."""
        return self.evaluate(y).J

    def jump(self, y: Float[Array, "4"]) -> Jump:
        """v⁺ on the other stable branch of G(x) = φ(v, V), x unchanged.

        The homogenized ODE carries log v, so a landing on the fully stuck tape (v⁺ = 0) is
        at the paper's starting velocity 1e-10·V instead, from which the ODE sticks as it does
        at t = 0.
        """
        return _jump(self.model, self.V, self.folds, y, floor=PAPER_V0_FACTOR * self.V)

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


def _with_folds(ode):
    """``ode`` (with ``model``, ``V`` and ``folds`` fields) with φ's folds at its V computed, once."""
    if ode.folds is not None:
        return ode
    return eqx.tree_at(lambda o: o.folds, ode, phi_folds(ode.model, ode.V), is_leaf=lambda x: x is None)
