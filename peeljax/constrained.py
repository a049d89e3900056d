"""The DAE itself (τ = 0) on φ's stable branches, as an ODE in x with v from the constraint.

Between jumps the peeling DAE (``peel``) is of index 1 on a stable branch of φ: v is the
root of G(x) = φ(v, V) there (:func:`peeljax.branches.branch_velocity`) and

    ẋ = f(x, v(x)),   x = (α, ω, u).

The state carried is y = (α, ω, u, v), with ψ_v = 0: v is not integrated but solved from the
constraint at every evaluation, so G(x) − φ(v, V) = 0 holds to the root finder's precision
along the whole run (the index-1 ODE v̇ = F̃·f/∂φ/∂v, which is the homogenized ODE with
``truncation=0``, lets it drift; and its v̇ blows up like an inverse square root at a fold,
where x stays smooth). y's v holds the last solved value, which tells the branch and starts
the next root search; :meth:`ConstrainedDAE.complete` solves it anew at any state, for
instance an interpolated one. The error is controlled on x alone (ψ_v = 0 gives v no error
estimate), as DAE codes do for algebraic variables.

The fold event is :func:`peeljax.branches.fold_distance`, G(x) reaching the current
branch's extreme value; past it v is clamped at the fold velocity (a continuous extension),
so the step that crosses the fold is an ordinary one and the event is located inside it.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._arrays import float_array
from .branches import Folds, branch_of, branch_velocity, fold_distance
from .desingularized import DesingularizedDAE
from .homogenized import Evaluation, Jump, _jump, _with_folds
from .model import PeelingModel
from .structure import jacobians

__all__ = ["ConstrainedDAE"]


class ConstrainedDAE(eqx.Module):
    """ẋ = f(x, v(x)) with v on the current stable branch of G(x) = φ(v, V) (τ = 0).

    Meets the :class:`~peeljax.ODE` contract (``evaluate`` → ψ, J = −∂φ/∂v, F̃·f) and the
    :class:`~peeljax.homogenized.FoldingODE` one (fold event, jump, output state). ``tau`` is
    0: the index-1 limit of the homogenized ODE (eq. ``hv``).
    """

    model: PeelingModel
    V: Float[Array, ""] = eqx.field(converter=float_array)
    folds: Folds | None = None
    # The integrator solves v anew (``complete``) at every accepted and every output state.
    completes_state: ClassVar[bool] = True

    @property
    def tau(self) -> Array:
        return jnp.zeros(())

    def _branch(self, y):
        return branch_of(y[3], self.folds)

    def velocity(self, y: Float[Array, "4"]) -> Array:
        """v solved from the constraint on the branch y's v lies on."""
        return branch_velocity(self.model, y[:3], self.V, self._branch(y), self.folds, guess=y[3])

    def evaluate(self, y: Float[Array, "4"]) -> Evaluation:
        """ψ = (f(x, v(x)), 0), J = −∂φ/∂v and F̃·f at v(x)."""
        x = y[:3]
        jac = jacobians(self.model, x, self.velocity(y), self.V)
        psi = jnp.concatenate([jac.f, jnp.zeros(1)])
        return Evaluation(psi=psi, J=-jac.phi_v, drive=jnp.dot(jac.F_tilde, jac.f))

    def __call__(self, y: Float[Array, "4"]) -> Float[Array, "4"]:
        return self.evaluate(y).psi

    def with_folds(self, folds: Folds | None = None) -> ConstrainedDAE:
        """This ODE with φ's folds, given or computed (needed by every other method)."""
        return _with_folds(self, folds)

    def fold_event(self, y: Float[Array, "4"]) -> Array:
        """G(x) − φ(v̂, V) on the stick branch, φ(v̌, V) − G(x) on the slip branch (N)."""
        return fold_distance(self.model, y[:3], self.V, self._branch(y), self.folds)

    def jump(self, y: Float[Array, "4"]) -> Jump:
        """v⁺ on the other branch at fixed x (0 when the tape lands fully stuck)."""
        return _jump(self.model, self.V, self.folds, y.at[3].set(self.velocity(y)))

    def complete(self, y: Float[Array, "4"]) -> Float[Array, "4"]:
        """y with v solved from the constraint on its branch."""
        return y.at[3].set(self.velocity(y))

    def in_pseudo_time(self, time_scale) -> DesingularizedDAE:
        """The same DAE in pseudo-time (:class:`~peeljax.DesingularizedDAE`): the folds regular,
        no root of φ solved per evaluation, t carried as a fifth component."""
        return DesingularizedDAE(self.model, self.V, time_scale, self.folds)

    def constraint(self, y) -> Array:
        """Residual of (sac) at y (zero to the root finder's precision along a run)."""
        y = jnp.asarray(y)
        return self.model.constraint(y[..., :3].T if y.ndim > 1 else y[:3], y[..., 3], self.V)
