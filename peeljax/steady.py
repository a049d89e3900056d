"""Steady peeling and its linear stability at τ = 0, every derivative by autodiff.

Steady peeling is the DAE's equilibrium: v = V, ω = V/R (no slip on the spool), α = 0 (no
torque), and u with G(x) = (1 + l·sinα/L)·F(u, α) = φ(V, V) (sac). Where ∂φ/∂v ≠ 0 the
constraint gives v(x) by the implicit function theorem, ∂v/∂x = F̃/∂φ/∂v, and the DAE is the ODE
x' = f(x, v(x)) with the Jacobian

    J = ∂f/∂x + ∂f/∂v ⊗ F̃ / ∂φ/∂v            (3×3, from :func:`peeljax.structure.jacobians`).

Steady peeling is stable where every eigenvalue of J has a negative real part. It loses
stability either where ∂φ/∂v(V, V) passes through 0 (v = V reaches a fold of φ, where the
DAE's index-1 condition ∂φ/∂v ≠ 0 fails: an eigenvalue passes through infinity) or where a complex pair
crosses the imaginary axis (a Hopf bifurcation). :func:`steady_peeling_ends` locates either to
the root finder's tolerance; the attractor map uses it for the ends of its steady branches,
where runs slow down (close to a fold a run from steady peeling takes ~2·10⁵ steps per
second: the stable eigenvalue is large).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Complex, Float

from ._validation import check_positive
from .model import PeelingModel
from .structure import jacobians

__all__ = ["steady_state", "steady_jacobian", "steady_eigenvalues", "steady_peeling_ends", "FOLD", "HOPF"]

FOLD = "fold"  # ∂φ/∂v(V, V) = 0 there
HOPF = "Hopf"  # a complex pair of J's eigenvalues crosses the imaginary axis there


def steady_state(model: PeelingModel, V: ArrayLike) -> Float[Array, "4"]:
    """y = (α, ω, u, v) = (0, V/R, u, V) with u from the constraint (sac)."""
    V = jnp.asarray(V, float)
    return model.consistent_state(V, 0.0, V / model.R, V)


def steady_jacobian(model: PeelingModel, V: ArrayLike) -> Float[Array, "3 3"]:
    """J = ∂f/∂x + ∂f/∂v ⊗ F̃ / ∂φ/∂v at steady peeling (module docstring): the Jacobian of the
    DAE reduced to x' = f(x, v(x)) (index 1, τ = 0)."""
    y = steady_state(model, V)
    jac = jacobians(model, y[:3], y[3], V)
    return jac.f_x + jnp.outer(jac.f_v, jac.F_tilde) / jac.phi_v


def steady_eigenvalues(model: PeelingModel, V: ArrayLike) -> Complex[Array, "3"]:
    """The eigenvalues of :func:`steady_jacobian`, the largest real part first. Within ~1e-5 m/s
    of a fold the small ones are lost in rounding next to the one ~ −1/∂φ/∂v."""
    lam = jnp.linalg.eigvals(steady_jacobian(model, V))
    return lam[jnp.argsort(-jnp.real(lam))]


@eqx.filter_jit
def _margins(model: PeelingModel, V: Float[Array, " n"]) -> tuple[Array, Array]:
    """(max Re λ, ∂φ/∂v(V, V)) per V."""

    def one(Vi):
        slope = jax.grad(model.phi)(Vi, Vi)
        return jnp.max(jnp.real(jnp.linalg.eigvals(steady_jacobian(model, Vi)))), slope

    return jax.vmap(one)(V)


def steady_peeling_ends(
    model: PeelingModel, V: ArrayLike, *, xtol: float = 1e-10
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """Where steady peeling gains or loses stability between neighbouring values of a grid of V.

    Args:
        model: the model.
        V: an increasing grid of pull velocities [m/s], shape (n,), n ≥ 1.
        xtol: the width of each located bracket [m/s].

    Returns:
        ``stable`` (n,) bool: every eigenvalue of J with a negative real part at V; and for each
        grid interval where ``stable`` changes: ``V_stable``, ``V_unstable`` (the bracket's ends,
        stable / unstable by the eigenvalues, ``|V_stable − V_unstable| ≤ xtol``) and the kind of
        change, :data:`FOLD` where ∂φ/∂v(V, V) changes sign in the bracket, else :data:`HOPF`.
    """
    from scipy.optimize import brentq

    if not isinstance(model, PeelingModel):
        raise TypeError(f"model must be a PeelingModel, got {type(model).__name__}")
    grid = np.atleast_1d(np.asarray(V, float))
    if grid.ndim != 1 or grid.size == 0 or np.any(np.diff(grid) <= 0):
        raise ValueError("V must be an increasing 1-d grid of pull velocities")
    check_positive("V", grid)
    if not xtol > 0:
        raise ValueError(f"xtol must be > 0, got {xtol!r}")

    def margins(points):
        re, slope = _margins(model, jnp.asarray(np.atleast_1d(points), float))
        return np.asarray(re), np.asarray(slope)

    re, slope = margins(grid)
    stable = re < 0
    V_stable, V_unstable, kinds = [], [], []
    for i in np.flatnonzero(stable[:-1] != stable[1:]):
        a, b = grid[i], grid[i + 1]
        fold = np.sign(slope[i]) != np.sign(slope[i + 1])
        # A fold: the root of ∂φ/∂v(V, V), where J's eigenvalue passes through infinity (max Re λ
        # has no root there); a Hopf: the root of max Re λ.
        which = 1 if fold else 0
        root = brentq(lambda x: float(margins(x)[which][0]), a, b, xtol=xtol / 4, rtol=4 * np.finfo(float).eps)
        lo, hi = max(a, root - xtol / 2), min(b, root + xtol / 2)
        # The stable end is on the stable grid point's side. (Close to a fold the eigenvalues of J
        # are not to be trusted: |λ| ~ 1/∂φ/∂v dwarfs the complex pair, whose real part also
        # goes to 0 with ∂φ/∂v; the root of ∂φ/∂v is exact.)
        V_stable.append(lo if stable[i] else hi)
        V_unstable.append(hi if stable[i] else lo)
        kinds.append(FOLD if fold else HOPF)
    return stable, np.asarray(V_stable, float), np.asarray(V_unstable, float), kinds
