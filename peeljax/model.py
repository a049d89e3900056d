"""The peeling DAE (eqs. ``defL``–``sac``): spool, tape and the shear-adhesion constraint.

Differential states x = (α, ω, u) (peel-front angle, spool angular velocity, tape stretch),
algebraic state v (peeling velocity), pull velocity V:

    α̇ = ω − v/R                                          (av)
    ω̇ = −R·l·sinα/(I·L(α)) · F(u, α)                     (tb)
    u̇ = R·l·sinα/L(α) · (1 + u/L(α)) · (ω − v/R) + V − v  (str)
    0 = (1 + l·sinα/L(α)) · F(u, α) − φ(v, V)             (sac)

with L(α) = √(R² + l² − 2Rl·cosα) (defL) and F(u, α) = k·u/(L(α) − u) (defF).

Two geometries:

* ``"paper"`` (default): the approximations of the paper's numerical example,
  L ≈ l, u ≪ l, l ≫ R, i.e. F = (k/l)·u, l·sinα/L → sinα, R·l·sinα/L → R·sinα,
  (1 + u/L) → 1. Only k/l enters.
* ``"full"``: every term as written above.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._arrays import float_array
from .adhesion import AdhesionLaw, as_adhesion

__all__ = ["PeelingModel", "GEOMETRIES", "PAPER_V0_FACTOR", "PAPER_ALPHA0"]

GEOMETRIES = ("paper", "full")
PAPER_V0_FACTOR = 1e-10  # v0 = 1e-10·V
PAPER_ALPHA0 = 0.25 * jnp.pi * 1e-8  # α0 = (π/4)·1e-8


def _parameter():
    return eqx.field(converter=float_array)


class PeelingModel(eqx.Module):
    """Spool and tape parameters (SI units) with the adhesion law φ.

    Attributes:
        R: spool radius [m] (default 0.1).
        I: spool moment of inertia [kg·m²] (default 1e-2).
        k: tape stiffness E·a [N] (default 1000).
        l: distance from the spool centre to where the tape meets the horizontal [m]
            (default 1; in the ``"paper"`` geometry only k/l = 1000 N/m enters).
        adhesion: φ(v, V), an :class:`AdhesionLaw` (default: the paper's) or any callable.
        geometry: ``"paper"`` or ``"full"`` (static: switching recompiles).

    R, I, k, l and the adhesion coefficients are traced array leaves.
    """

    R: Float[Array, ""] = _parameter()
    I: Float[Array, ""] = _parameter()  # noqa: E741 - the paper's name
    k: Float[Array, ""] = _parameter()
    l: Float[Array, ""] = _parameter()  # noqa: E741 - the paper's name
    adhesion: AdhesionLaw | Callable
    geometry: str = eqx.field(static=True)

    def __init__(self, R=0.1, I=1e-2, k=1000.0, l=1.0, adhesion=None, geometry: str = "paper"):  # noqa: E741
        if geometry not in GEOMETRIES:
            raise ValueError(f"geometry must be one of {GEOMETRIES}, got {geometry!r}")
        self.R, self.I, self.k, self.l = R, I, k, l
        self.adhesion = as_adhesion(adhesion)
        self.geometry = geometry

    # ------------------------------------------------------------------ geometry
    def free_length(self, alpha: ArrayLike) -> Array:
        """L(α) (eq. ``defL``); ``l`` in the paper geometry."""
        if self.geometry == "paper":
            return jnp.broadcast_to(self.l, jnp.shape(alpha))
        return jnp.sqrt(self.R**2 + self.l**2 - 2.0 * self.R * self.l * jnp.cos(alpha))

    def tension(self, u: ArrayLike, alpha: ArrayLike) -> Array:
        """F(u, α) (eq. ``defF``); (k/l)·u in the paper geometry."""
        if self.geometry == "paper":
            return (self.k / self.l) * u
        return self.k * u / (self.free_length(alpha) - u)

    def _lever(self, alpha):
        """l·sinα/L(α), → sinα in the paper geometry."""
        if self.geometry == "paper":
            return jnp.sin(alpha)
        return self.l * jnp.sin(alpha) / self.free_length(alpha)

    # ------------------------------------------------------------------ DAE
    def f(self, x: Float[Array, "3"], v: ArrayLike, V: ArrayLike) -> Float[Array, "3"]:
        """Right-hand side f(x, v) of (av), (tb), (str)."""
        alpha, omega, u = x[0], x[1], x[2]
        lever = self._lever(alpha)
        F = self.tension(u, alpha)
        slip = omega - v / self.R
        if self.geometry == "paper":
            stretch_factor = 1.0
        else:
            stretch_factor = 1.0 + u / self.free_length(alpha)
        return jnp.stack(
            [
                slip,
                -self.R * lever * F / self.I,
                self.R * lever * stretch_factor * slip + V - v,
            ]
        )

    def shear_force(self, x: Float[Array, "3"]) -> Array:
        """(1 + l·sinα/L(α))·F(u, α), the left side of the constraint (sac)."""
        alpha, u = x[0], x[2]
        return (1.0 + self._lever(alpha)) * self.tension(u, alpha)

    def phi(self, v: ArrayLike, V: ArrayLike) -> Array:
        """The adhesion law φ(v, V)."""
        return self.adhesion(v, V)

    def constraint(self, x: Float[Array, "3"], v: ArrayLike, V: ArrayLike) -> Array:
        """Residual of (sac): (1 + l·sinα/L)·F − φ(v, V); zero on the DAE's solutions."""
        return self.shear_force(x) - self.phi(v, V)

    # ------------------------------------------------------------------ initial data
    def stretch_for_force(self, alpha: ArrayLike, force: ArrayLike) -> Array:
        """The u solving (1 + l·sinα/L)·F(u, α) = force (closed form in both geometries)."""
        scaled = force / (1.0 + self._lever(alpha))  # = F(u, α)
        if self.geometry == "paper":
            return scaled * self.l / self.k
        c = scaled / self.k  # u/(L − u) = c
        return c * self.free_length(alpha) / (1.0 + c)

    def consistent_state(self, V: ArrayLike, alpha: ArrayLike, omega: ArrayLike, v: ArrayLike) -> Float[Array, "4"]:
        """y = (α, ω, u, v) with u solved from the constraint (sac)."""
        u = self.stretch_for_force(alpha, self.phi(v, V))
        return jnp.stack([jnp.asarray(alpha, float), jnp.asarray(omega, float), u, jnp.asarray(v, float)])

    def initial_state(self, V: ArrayLike) -> Float[Array, "4"]:
        """The paper's consistent initial data: v0 = 1e-10·V, ω0 = v0/R, α0 = (π/4)·1e-8, u0 from (sac)."""
        v0 = PAPER_V0_FACTOR * jnp.asarray(V, float)
        return self.consistent_state(V, PAPER_ALPHA0, v0 / self.R, v0)
