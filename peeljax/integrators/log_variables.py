"""Integration in log variables: z = y with chosen components (v) replaced by their logarithms.

From the paper's start v0 = 1e-10·V, ψ_v ∝ v^0.85 is not Lipschitz in v, but d(log v)/dt =
ψ_v/v ∝ e^(−0.15·log v) is smooth in log v: a stepper carrying log v keeps its order there,
and v stays positive through every step and Newton iterate. Every stepper of the loop (the
α-method and the Runge–Kutta solvers) carries its state through :class:`LogTransformedODE`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..homogenized import ODE

__all__ = ["LogTransformedODE", "from_log", "log_mask", "to_log"]

# A log component is evaluated no lower than e^−345 ≈ 1e-150 (y² ≈ 1e-300, still a normal
# double): below ~1e-154 the quotient rule's ψ·dy/y² underflowed to 0/0. A step whose stages
# carry v far below the fully stuck tape's marker (τ = 0, the stick branch running down to
# v = 0) had a NaN tangent there (measured: a window row at 0.5 m/s, log v = −373 in a stage).
# The field below is the floor's.
_LOG_FLOOR = -345.0


def log_mask(n: int, log_components: tuple[int, ...]) -> Array:
    """True at the ``log_components`` of a state of n components."""
    return jnp.zeros(n, bool).at[jnp.asarray(log_components, int)].set(True) if log_components else jnp.zeros(n, bool)


def from_log(z: Float[Array, "... n"], log_components: tuple[int, ...]) -> Float[Array, "... n"]:
    """z with the ``log_components`` exponentiated: carried coordinates (log v) back to y."""
    mask = log_mask(z.shape[-1], log_components)
    return jnp.where(mask, jnp.exp(jnp.where(mask, z, 0.0)), z)


def to_log(y: Float[Array, "... n"], log_components: tuple[int, ...]) -> Float[Array, "... n"]:
    """y with the ``log_components`` replaced by their logarithms (the inverse of :func:`from_log`)."""
    mask = log_mask(y.shape[-1], log_components)
    return jnp.where(mask, jnp.log(jnp.where(mask, y, 1.0)), y)


class LogTransformedODE(eqx.Module):
    """z' = ψ_z(z) for z = y with the ``log_components`` replaced by their logarithms.

    d(log v)/dt = ψ_v/v. From the paper's start v0 = 1e-10·V, ψ_v ∝ v^0.85 is not Lipschitz in
    v, but ψ_v/v ∝ e^(−0.15·log v) is smooth in log v: the α-method keeps its order there.
    """

    ode: ODE
    log_components: tuple[int, ...] = eqx.field(static=True)

    @property
    def tau(self):
        return self.ode.tau

    def evaluate(self, z):
        mask = log_mask(z.shape[-1], self.log_components)
        y = from_log(jnp.where(mask, jnp.maximum(z, _LOG_FLOOR), z), self.log_components)
        evaluation = self.ode.evaluate(y)
        psi = jnp.where(mask, evaluation.psi / jnp.where(mask, y, 1.0), evaluation.psi)  # no 0·∞ in reverse mode
        return eqx.tree_at(lambda e: e.psi, evaluation, psi)

    def __call__(self, z):
        return self.evaluate(z).psi

    # The fold hooks of a FoldingODE, in the carried coordinates.
    @property
    def fold_event_is_schur(self) -> bool:
        return getattr(self.ode, "fold_event_is_schur", False)

    @property
    def stops_at_impasse(self) -> bool:
        return getattr(self.ode, "stops_at_impasse", False)

    @property
    def completes_state(self) -> bool:
        return getattr(self.ode, "completes_state", False)

    @property
    def time_index(self) -> int | None:
        """The component holding the time, for an ODE in pseudo-time (never a log component)."""
        return getattr(self.ode, "time_index", None)

    @property
    def folds(self):
        return self.ode.folds

    def with_folds(self, folds=None):
        return LogTransformedODE(self.ode.with_folds(folds), self.log_components)

    def fold_event(self, z):
        return self.ode.fold_event(from_log(z, self.log_components))

    def jump(self, z):
        jump = self.ode.jump(from_log(z, self.log_components))
        return eqx.tree_at(lambda j: j.y, jump, to_log(jump.y, self.log_components))

    def complete(self, z):
        return to_log(self.ode.complete(from_log(z, self.log_components)), self.log_components)

    def switches(self, z):
        return self.ode.switches(from_log(z, self.log_components))

    def switch(self, z):
        return to_log(self.ode.switch(from_log(z, self.log_components)), self.log_components)
