"""Floquet multipliers of a stick-slip orbit and the test functions of its bifurcations.

The orbit's monodromy on the section Σ is M = ∂P^k/∂s, the 2 × 2 Jacobian of the return map
after k stick → slip events (:mod:`peeljax.orbits.period`), by forward-mode autodiff through
the loop with every event time and jump differentiated (the saltation included). Σ has the
dimension of x minus one, so M has no trivial multiplier: its eigenvalues λ₁, λ₂ are the
orbit's nontrivial Floquet multipliers (the eigenvalues of the full monodromy of x other than
the flow direction's 1), and the orbit is asymptotically stable iff max |λ| < 1.

A branch of orbits changes stability where a multiplier crosses the unit circle, detected by
the sign of the test functions of COCO's ``hspo`` toolbox (and AUTO's), polynomial in M so
they are smooth along a branch:

* fold of cycles (a multiplier through +1): det(M − I) = (λ₁ − 1)(λ₂ − 1);
* period doubling (through −1): det(M + I) = (λ₁ + 1)(λ₂ + 1);
* torus (a complex pair through |λ| = 1): det M − 1 = λ₁λ₂ − 1, a Neimark–Sacker point where
  the pair is complex (tr² < 4 det), a neutral saddle where it is real.

The eigenvalues of a 2 × 2 matrix are computed in closed form (tr/2 ± √(tr²/4 − det)), which
runs on every backend and under ``vmap``.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Complex, Float

__all__ = ["multipliers", "test_functions", "TEST_FUNCTIONS"]

TEST_FUNCTIONS = ("fold", "period_doubling", "torus")


def multipliers(monodromy: Float[Array, "2 2"]) -> Complex[Array, "2"]:
    """λ₁, λ₂ of the 2 × 2 monodromy on Σ, the larger modulus first."""
    M = jnp.asarray(monodromy)
    half_trace = 0.5 * (M[0, 0] + M[1, 1])
    det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    root = jnp.sqrt((half_trace**2 - det).astype(complex))
    pair = jnp.stack([half_trace + root, half_trace - root])
    order = jnp.argsort(-jnp.abs(pair))
    return pair[order]


def test_functions(monodromy: Float[Array, "2 2"]) -> dict[str, Array]:
    """The fold, period-doubling and torus test functions of M (module docstring)."""
    M = jnp.asarray(monodromy)
    trace = M[0, 0] + M[1, 1]
    det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    return {
        "fold": det - trace + 1.0,  # det(M − I)
        "period_doubling": det + trace + 1.0,  # det(M + I)
        "torus": det - 1.0,
    }
