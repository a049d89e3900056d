"""The Poincaré section of a stick-slip orbit: the stick → slip fold.

Every stick → slip event of the DAE (τ = 0) happens where the shear force reaches φ's
maximum, G(x) = (1 + l·sinα/L)·F(u, α) = φ(v̂, V), with v at the fold v̂ of the stick
branch (:mod:`peeljax.branches`). That surface of x = (α, ω, u) is the section Σ: every
orbit with slips crosses it transversally (the fold event G − φ(v̂) rises through zero at
the rate Ġ > 0; a tangential crossing is a grazing bifurcation), and G(x) = φ̂ is solved for
u in closed form (:meth:`~peeljax.PeelingModel.stretch_for_force`), so the peel angle and
the spool's angular velocity s = (α, ω) are coordinates on it:

    x(s) = (α, ω, U(α, φ̂)),   v = v̂   (on Σ, before the jump),

and the jump at the fold takes v to v⁺ on the slip branch at the same x (eq. ``sac`` at
fixed x). A section in x that the jump leaves unchanged is why the return map's Jacobian
already holds the saltation of the jumps (COCO's ``hspo`` multiplies the segments' transfer
matrices by it explicitly).

Newton works on scaled coordinates z = s / (1 rad, V/R): the angle in radians, the angular
velocity in units of the rate at which the spool turns when it pays out tape at V.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..branches import STICK, Folds, jump_velocity, phi_folds
from ..model import PeelingModel

__all__ = ["SlipSection", "state_after_slip"]


class SlipSection(eqx.Module):
    """The stick → slip section Σ at pull velocity V: G(x) = φ(v̂, V) (module docstring).

    Attributes:
        model: spool, tape and adhesion law.
        V: pull velocity [m/s].
        folds: φ's folds at V (:func:`peeljax.branches.phi_folds`).
    """

    model: PeelingModel
    V: Float[Array, ""]
    folds: Folds

    @classmethod
    def at(cls, model: PeelingModel, V) -> SlipSection:
        V = jnp.asarray(V, float)
        return cls(model, V, phi_folds(model, V))

    @property
    def scale(self) -> Float[Array, "2"]:
        """(1 rad, V/R): the units of the scaled coordinates z = s/scale."""
        return jnp.stack([jnp.ones_like(self.V), self.V / self.model.R])

    def state(self, s: Float[Array, "2"]) -> Float[Array, "4"]:
        """y = (α, ω, u, v̂) on Σ at coordinates s = (α, ω), before the jump."""
        alpha, omega = s[0], s[1]
        u = self.model.stretch_for_force(alpha, self.folds.phi_max)
        return jnp.stack([alpha, omega, u, self.folds.v_max])

    def after_slip(self, s: Float[Array, "2"]) -> Float[Array, "4"]:
        """The state just after the stick → slip jump at s: v⁺ on the slip branch, x unchanged."""
        y = self.state(s)
        return y.at[3].set(jump_velocity(self.model, y[:3], self.V, STICK, self.folds))

    def tension(self, s: Float[Array, "2"]) -> Array:
        """The tape tension F(u, α) at s on Σ [N] (what a load cell reads at the slip)."""
        y = self.state(s)
        return self.model.tension(y[2], y[0])

    def coordinates(self, y: Float[Array, "... 4"]) -> Float[Array, "... 2"]:
        """s = (α, ω) of a state (the state is not checked to lie on Σ)."""
        return jnp.asarray(y)[..., :2]


@eqx.filter_jit
def _after_slip(model: PeelingModel, V, s) -> Array:
    return SlipSection.at(model, V).after_slip(s)


def state_after_slip(model: PeelingModel, V, s) -> np.ndarray:
    """:meth:`SlipSection.after_slip` at (model, V, s) from the host, as a NumPy array: one compiled
    program for every model and V (called eagerly, the root search's loop was compiled afresh at
    each call: 80 ms, 2.5 s of a 15 s table fit)."""
    return np.asarray(_after_slip(model, jnp.asarray(V, float), jnp.asarray(s, float)))
