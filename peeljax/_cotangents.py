"""Reverse mode through work whose result the program may discard: a zero cotangent stays zero.

A rejected step attempt is computed and then not used: ``jnp.where(accept, candidate, state)``
sends it an exactly-zero cotangent. Its pullback should return zero, but where the attempt
overflowed on the way to its (finite, rejected) result, a partial derivative inside it is
±inf and 0·inf = NaN poisons every gradient of the run. :func:`skip_zero_cotangents` wraps a
function so that its pullback is not evaluated at all for an exactly-zero cotangent (the
derivative of a linear map at zero is zero), and is evaluated as before otherwise. Forward
mode never needs it: there the rejected tangent is selected away, not multiplied.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp

__all__ = ["skip_zero_cotangents"]


def skip_zero_cotangents(fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` with a reverse-mode rule that returns exact zeros, without running ``fn``'s
    pullback, for an incoming cotangent that is exactly zero on every output.

    Differentiates with respect to every floating-point array among the arguments (closures
    over other traced values are not differentiated: pass them as arguments). Reverse mode
    only (a ``custom_vjp``): call the unwrapped ``fn`` under forward mode.
    """

    def call(*args):
        diff, rest = eqx.partition(args, eqx.is_inexact_array)
        rest_arrays, rest_static = eqx.partition(rest, eqx.is_array)
        static_out = []  # the outputs' non-array part and the dtypes of their integer arrays

        def as_floats(diff, rest_arrays):
            """fn's array outputs, integers and booleans carried as floats: a custom_vjp's
            integer outputs count as perturbed, which equinox's checkpointed loop refuses."""
            out = fn(*eqx.combine(diff, rest_arrays, rest_static))
            out_arrays, out_static = eqx.partition(out, eqx.is_array)
            if not static_out:
                static_out.append((out_static, jax.tree.map(lambda x: x.dtype, out_arrays)))
            return jax.tree.map(lambda x: x if eqx.is_inexact_array(x) else x.astype(float), out_arrays)

        @jax.custom_vjp
        def wrapped(diff, rest_arrays):
            return as_floats(diff, rest_arrays)

        def wrapped_fwd(diff, rest_arrays):
            out, pullback = jax.vjp(lambda d: as_floats(d, rest_arrays), diff)
            return out, (pullback, jax.tree.map(jnp.zeros_like, diff))

        def wrapped_bwd(residuals, cotangent):
            pullback, zeros = residuals
            leaves = jax.tree_util.tree_leaves(cotangent)
            nonzero = jnp.any(jnp.stack([jnp.any(leaf != 0) for leaf in leaves])) if leaves else jnp.asarray(False)
            return jax.lax.cond(nonzero, lambda: pullback(cotangent)[0], lambda: zeros), None

        wrapped.defvjp(wrapped_fwd, wrapped_bwd)
        out = wrapped(diff, rest_arrays)
        out_static, dtypes = static_out[0]
        out = jax.tree.map(lambda x, dtype: x.astype(dtype), out, dtypes)
        return eqx.combine(out, out_static)

    return call
