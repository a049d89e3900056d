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

from typing import Protocol, runtime_checkable

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._arrays import float_array
from .model import PeelingModel
from .structure import jacobians, schur_complement, truncated_schur_complement

__all__ = ["ODE", "Evaluation", "HomogenizedODE"]


class Evaluation(eqx.Module):
    """ψ(y) with the quantities it is made of (used for diagnostics and stop tests)."""

    psi: Float[Array, "4"]
    J: Float[Array, ""]  # the (possibly truncated) Schur complement
    drive: Float[Array, ""]  # F̃·f, the rate of change of the shear force


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


class HomogenizedODE(eqx.Module):
    """ψ(y; τ) of eq. ``hv`` for a model at pull velocity V.

    ``V`` and ``tau`` are traced arrays (no recompilation when they change; ``vmap`` and
    ``grad`` work over them); ``truncation`` is static.
    """

    model: PeelingModel
    V: Float[Array, ""] = eqx.field(converter=float_array)
    tau: Float[Array, ""] = eqx.field(converter=float_array)
    truncation: int | None = eqx.field(static=True, default=None)

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

    def schur_complement(self, y: Float[Array, "4"]) -> Array:
        """J_t(τ) at y (or its truncation)."""
        return self.evaluate(y).J

    def constraint(self, y: ArrayLike) -> Array:
        """Residual of (sac) at y: how far the homogenized state is from the DAE's manifold."""
        y = jnp.asarray(y)
        return self.model.constraint(y[..., :3].T if y.ndim > 1 else y[:3], y[..., 3], self.V)
