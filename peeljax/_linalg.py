"""Dense solves for tiny systems (n ≤ 4) written as unrolled scalar arithmetic.

XLA:CPU dispatches ``jnp.linalg.solve`` to LAPACK through a custom call that it cannot
fuse; inside a ``lax.scan`` body that call dominates a step that needs only a few hundred
flops. Unrolled Gaussian elimination with partial pivoting fuses into the surrounding
kernel and vectorises cleanly under ``vmap``.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float


def solve_small(A: Float[Array, "n n"], b: Float[Array, " n"]) -> Float[Array, " n"]:
    """Solve A·x = b by Gaussian elimination with partial pivoting, unrolled for static n."""
    n = A.shape[0]
    rows = [[A[i, j] for j in range(n)] + [b[i]] for i in range(n)]
    for k in range(n):
        # Partial pivoting by pairwise swaps: keep the row of largest |pivot| at position k.
        for i in range(k + 1, n):
            swap = jnp.abs(rows[i][k]) > jnp.abs(rows[k][k])
            rows[k], rows[i] = (
                [jnp.where(swap, ri, rk) for rk, ri in zip(rows[k], rows[i])],
                [jnp.where(swap, rk, ri) for rk, ri in zip(rows[k], rows[i])],
            )
        for i in range(k + 1, n):
            factor = rows[i][k] / rows[k][k]
            rows[i] = [rows[i][j] - factor * rows[k][j] if j > k else rows[i][j] for j in range(n + 1)]
    x = [None] * n
    for i in reversed(range(n)):
        acc = rows[i][n]
        for j in range(i + 1, n):
            acc = acc - rows[i][j] * x[j]
        x[i] = acc / rows[i][i]
    return jnp.stack(x)


def solve_3x3(A: Float[Array, "3 3"], b: Float[Array, " 3"]) -> Float[Array, " 3"]:
    """Solve A·x = b for a 3×3 A by its adjugate: x = adj(A)·b / det(A).

    The columns of adj(A) are cross products of A's rows. Branch-free, so forward-mode
    derivatives of it are about a third of the cost of those of :func:`solve_small`; used
    for (𝐈 − τ·∂f/∂x)⁻¹·∂f/∂v in the Schur complement, whose matrix is well conditioned on
    the solution (checked against LAPACK in ``tests/test_structure.py``).
    """
    c0 = jnp.cross(A[1], A[2])
    c1 = jnp.cross(A[2], A[0])
    c2 = jnp.cross(A[0], A[1])
    return (c0 * b[0] + c1 * b[1] + c2 * b[2]) / jnp.dot(A[0], c0)
