"""The DAE's structure near the maximum of φ (Lemmas 1–3), every derivative by autodiff.

For the DAE (``peel``) with x = (α, ω, u) and constraint G(x) = φ(v, V), G = (1 + l·sinα/L)·F:

* ∂f/∂x (3×3), ∂f/∂v (3), F̃ = ∂G/∂x (1×3) and ∂φ/∂v, by ``jax.jacfwd`` / ``jax.grad``;
* the Schur complement of the Jacobian 𝒟_t of Lemma 1,
      J_t(τ) = −∂φ/∂v + τ·F̃·(𝐈 − τ·∂f/∂x)⁻¹·∂f/∂v;
* its Neumann expansion (Lemma 2, eq. ``hvex``), J_t = −∂φ/∂v + Σ_{p≥1} τ^p·F̃·(∂f/∂x)^{p−1}·∂f/∂v,
  which converges only for τ·ρ(∂f/∂x) < 1 (ρ the spectral radius);
* the local differential index of Lemma 2, ⌈log_τ|J_t|⌉ + 1, and the slow/fast scale;
* the extrema of φ(·, V) (∂φ/∂v = 0): at its maximum v̂ the stick phase ends and, for small τ,
  J_t ≈ τ·F̃·(…)·∂f/∂v is smallest (Lemma ``hi``).

Conventions (measured, see ``docs/theory.md``): the index formula compares |J_t| (units
N·s/m) with powers of τ (s), so it is not unit-invariant; it is meaningful for 0 < τ < 1.
Where |J_t| ≥ 1, log_τ|J_t| ≤ 0 and the formula would give ≤ 1: we report 1 (index-1
regime, the *slow scale*). Where |J_t| < 1 the index is ≥ 2 (the *fast scale*). For
τ ≥ 1 we report 1. The estimate is capped at ``MAX_INDEX`` (J_t = 0 gives the cap).
"""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ._linalg import solve_3x3
from .model import PeelingModel

__all__ = [
    "Jacobians",
    "jacobians",
    "schur_complement",
    "local_index",
    "neumann_terms",
    "truncated_schur_complement",
    "neumann_radius",
    "is_fast_scale",
    "phi_extremum",
    "phi_max_and_min",
    "MAX_INDEX",
]

MAX_INDEX = 99


class Jacobians(eqx.Module):
    """The derivatives of the DAE at one point (x, v), all by autodiff."""

    f: Float[Array, "3"]  # f(x, v)
    f_x: Float[Array, "3 3"]  # ∂f/∂x
    f_v: Float[Array, "3"]  # ∂f/∂v
    F_tilde: Float[Array, "3"]  # F̃ = ∂[(1 + l·sinα/L)·F]/∂x
    phi_v: Float[Array, ""]  # ∂φ/∂v


def jacobians(model: PeelingModel, x: Float[Array, "3"], v: ArrayLike, V: ArrayLike) -> Jacobians:
    """f, ∂f/∂x, ∂f/∂v, F̃ and ∂φ/∂v at (x, v) by forward-mode autodiff.

    One ``jax.jacfwd`` of the stacked map y ↦ (f, G, φ) over y = (x, v): four tangents in
    all, pure forward mode, so that the Newton Jacobian of the α-method (a
    ``jacfwd`` over ψ, which contains these derivatives) is forward-over-forward, which
    XLA fuses far better than forward-over-reverse.
    """
    v = jnp.asarray(v, float)
    y = jnp.concatenate([x, v[None]])

    def stacked(y):
        x, v = y[:3], y[3]
        return jnp.concatenate([model.f(x, v, V), model.shear_force(x)[None], jnp.reshape(model.phi(v, V), (1,))])

    values = stacked(y)
    D = jax.jacfwd(stacked)(y)  # 5×4: rows f (3), G, φ; columns α, ω, u, v
    return Jacobians(f=values[:3], f_x=D[:3, :3], f_v=D[:3, 3], F_tilde=D[3, :3], phi_v=D[4, 3])


def schur_complement(jac: Jacobians, tau: ArrayLike) -> Array:
    """J_t(τ) = −∂φ/∂v + τ·F̃·(𝐈 − τ·∂f/∂x)⁻¹·∂f/∂v (Lemma 1)."""
    w = solve_3x3(jnp.eye(3) - tau * jac.f_x, jac.f_v)
    return -jac.phi_v + tau * jnp.dot(jac.F_tilde, w)


def neumann_terms(jac: Jacobians, tau: ArrayLike, m: int) -> Float[Array, " m"]:
    """The first m terms τ^p·F̃·(∂f/∂x)^{p−1}·∂f/∂v, p = 1…m, of J_t's expansion (eq. ``hvex``)."""
    terms = []
    w = jac.f_v
    for p in range(1, m + 1):
        terms.append(tau**p * jnp.dot(jac.F_tilde, w))
        w = jac.f_x @ w
    return jnp.stack(terms)


def truncated_schur_complement(jac: Jacobians, tau: ArrayLike, m: int) -> Array:
    """J̃_t = −∂φ/∂v + Σ_{p=1}^{m} τ^p·F̃·(∂f/∂x)^{p−1}·∂f/∂v, the m-term truncation of eq. ``hvex``.

    ``m = 0`` gives −∂φ/∂v, the Schur complement of the τ → 0 (index-1) limit.
    """
    if m == 0:
        return -jac.phi_v
    return -jac.phi_v + jnp.sum(neumann_terms(jac, tau, m))


def neumann_radius(jac: Jacobians) -> Array:
    """1/ρ(∂f/∂x): the Neumann series of J_t converges for τ below this value."""
    return 1.0 / jnp.max(jnp.abs(jnp.linalg.eigvals(jac.f_x)))


def local_index(J: ArrayLike, tau: ArrayLike) -> Int[Array, "..."]:
    """Local differential index ⌈log_τ|J_t|⌉ + 1 of Lemma 2, with the conventions of the module doc.

    Returns 1 where |J_t| ≥ 1 or τ ≥ 1, and at most ``MAX_INDEX``.
    """
    J = jnp.asarray(J)
    tau = jnp.asarray(tau)
    absJ = jnp.abs(J)
    regular = (absJ > 0) & (absJ < 1) & (tau < 1)
    # log_τ|J| > 0 on the regular set; guard both logs so no branch sees log(0) or log(1).
    log_ratio = jnp.log(jnp.where(regular, absJ, 0.5)) / jnp.log(jnp.where(tau < 1, tau, 0.5))
    index = jnp.ceil(jnp.minimum(log_ratio, MAX_INDEX - 1)) + 1
    index = jnp.where(regular, index, jnp.where((absJ == 0) & (tau < 1), MAX_INDEX, 1))
    return jnp.clip(index, 1, MAX_INDEX).astype(jnp.int32)


def is_fast_scale(J: ArrayLike, tau: ArrayLike) -> Bool[Array, "..."]:
    """The *fast scale* (stick-slip) of the paper: local index > 1, i.e. |J_t| < 1 = τ⁰."""
    return local_index(J, tau) > 1


PHI_SEARCH_RANGE = (1e-8, 1e2)  # × max(V, 1) m/s
_PHI_GRID = 256
_PHI_BISECTIONS = 60


def phi_extremum(model: PeelingModel, V: ArrayLike, kind: Literal["max", "min"] = "max") -> Array:
    """The first maximum (∂φ/∂v from + to −) or minimum (− to +) of φ(·, V); NaN if none.

    ∂φ/∂v (``jax.grad``) is sampled at 256 points log-spaced in v ∈ [1e-8, 1e2]·max(V, 1); the
    first sign change of the kind asked brackets the extremum, and 60 bisection steps in log v
    refine it (relative accuracy ~1e-14). Traced in V and the model: ``jit`` and ``vmap`` work
    (the sweep engine finds v̂ per lane this way; :func:`peeljax.phi_extrema` calls it on the host).
    Its derivatives are the implicit function theorem's on ∂φ/∂v(v̂) = 0 (the bisection is
    not differentiated).
    """
    if kind not in ("max", "min"):
        raise ValueError(f"kind must be 'max' or 'min', got {kind!r}")
    return _phi_extrema(model, V, (kind,))[0]


def phi_max_and_min(model: PeelingModel, V: ArrayLike) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """φ's first maximum and first minimum in v, as :func:`phi_extremum` finds each, by one search."""
    v_max, v_min = _phi_extrema(model, V, ("max", "min"))
    return v_max, v_min


@eqx.filter_jit  # called on the host too (phi_folds): its loop would be compiled anew at every call
def _phi_extrema(model: PeelingModel, V: ArrayLike, kinds: tuple[str, ...]) -> Array:
    """:func:`phi_extremum` for each of ``kinds`` at once: one grid of ∂φ/∂v serves them all,
    and one loop bisects their brackets together (φ's two folds cost one search, not two)."""
    V = jnp.asarray(V, float)
    rising = jnp.array([1.0 if kind == "max" else -1.0 for kind in kinds])  # ∂φ/∂v's sign before each
    scale = jnp.maximum(V, 1.0)
    log_v = jnp.linspace(jnp.log(PHI_SEARCH_RANGE[0]), jnp.log(PHI_SEARCH_RANGE[1]), _PHI_GRID) + jnp.log(scale)

    def slope(log_v):
        return jax.grad(lambda v: model.phi(v, V))(jnp.exp(log_v))

    slopes = rising[:, None] * jax.vmap(slope)(log_v)
    falls = (slopes[:, :-1] > 0) & (slopes[:, 1:] <= 0)
    index = jnp.argmax(falls, axis=1)

    def bisect(_, bracket):
        lo, hi = bracket
        mid = 0.5 * (lo + hi)
        before = rising * jax.vmap(slope)(mid) > 0
        return jnp.where(before, mid, lo), jnp.where(before, hi, mid)

    lo, hi = jax.lax.fori_loop(0, _PHI_BISECTIONS, bisect, (log_v[index], log_v[index + 1]))
    found = jnp.any(falls, axis=1)
    log_root = jax.lax.stop_gradient(jnp.where(found, 0.5 * (lo + hi), 0.0))
    # Derivatives by the implicit function theorem on ∂φ/∂v(v̂) = 0 (zero in value):
    # d log v̂ = −d(∂φ/∂v)/(∂²φ/∂v∂log v) at fixed v̂, with the curvature held constant.
    curvature = jax.lax.stop_gradient(jax.vmap(jax.grad(slope))(log_root))
    curvature = jnp.where(curvature != 0, curvature, 1.0)
    residual = jax.vmap(slope)(log_root)
    log_root = log_root - (residual - jax.lax.stop_gradient(residual)) / curvature
    return jnp.where(found, jnp.exp(log_root), jnp.nan)
