"""Reverse mode through a run: by forward tangents when few inputs are perturbed.

``jax.grad`` of a run needs its vector–Jacobian product. The checkpointed while loop gives it
by running every step's pullback backwards; for the α-method at τ > 0 each pullback rebuilds
the step's exact Newton matrix (four tangents of ψ, itself holding the model's Jacobian), so
the gradient through 158 jumps costs 20.6× the run (``benchmarks/jump_gradient_cost.py --tau
1e-3``). The run's forward mode (the plain loop under ``jax.jvp``) reuses the kept matrix
and costs 2.2× with one tangent. The usual ``jax.grad`` perturbs few numbers (one or a few of
φ's coefficients, V, τ): with k perturbed scalars, k tangents of the plain loop give the
whole Jacobian of the run with respect to them, and the cotangent is contracted with it.

:func:`reverse_by_tangents` is that dispatch, decided at trace time from the perturbed leaves
(``equinox.filter_custom_vjp``): at most ``limit`` perturbed scalars, tangents; more, the
checkpointed loop's pullback (memory bounded by its checkpoints). Both give the derivative
of the discrete run with its step sizes held fixed; they are different programs, so where
round-off decides a step the two may differ as two runs would (``docs/fitting.md``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

__all__ = ["TANGENT_BYTES", "TANGENT_LIMITS", "reverse_by_tangents", "undefined_where_unreached"]

# Most perturbed scalars differentiated by tangents (3 s at V = 1.1, rtol 1e-6, the run's
# time ×, benchmarks/jump_gradient_cost.py --tangents, results/jump_gradient_cost*.md,
# 2026-12-06): the DAE (τ = 0, 210 jumps) 1, 4, 7 tangents 1.2, 1.7, 2.2, then a step, 8
# tangents 5.0, the checkpointed loop 4.5; the homogenized ODE with its default stepper, the
# same step at 8: τ = 0.01 (no jump) 4, 7, 8, 16 tangents 2.6, 3.5, 8.9, 10.8, the checkpointed
# loop 5.9; τ = 1e-3 (158 jumps) 4, 8, 16 tangents 4.4, 12.1, 16.7, the checkpointed loop 12.3.
# Yet the limit at τ > 0 stays 16: with the α-method's steps the checkpointed loop's pullback is
# dear (each step's exact Newton matrix), and compare.py's P4 (14 coefficients, the adaptive
# α-method) took 3.0–5.9× as long with a limit of 7 (docs/fitting.md).
TANGENT_LIMITS = {"dae": 7, "ode": 16}
# Most bytes the k tangents of a run's output rows may take (they are kept for the backward pass).
TANGENT_BYTES = 256 * 2**20

Solve = Callable[[Any, Literal["lax", "checkpointed"]], Any]


def reverse_by_tangents(solve: Solve, inputs: Any, limit: int) -> Any:
    """``solve(inputs, "lax")``, differentiated in reverse mode by tangents of the perturbed inputs.

    Args:
        solve: ``solve(inputs, kind)``, the run with its loop of ``kind``: ``"lax"`` (a plain
            while loop: forward mode) or ``"checkpointed"`` (reverse mode). A function of its
            arguments alone (it closes over no traced value).
        inputs: every input a derivative may be taken with respect to (a pytree).
        limit: most perturbed scalars that take tangents (static).

    Returns:
        ``solve``'s output. Its reverse-mode derivative with respect to the k perturbed
        scalars of ``inputs``: k ≤ ``limit``, the cotangent contracted with the k tangents of
        the plain loop (``jax.vmap`` of ``jax.jvp``; for k = 1 ``jax.jvp`` alone, which traces
        in about 0.6–0.7 of the time: 10.8 against 17.5 s for a run through jumps at τ = 0.01);
        otherwise the checkpointed loop's pullback.
        Forward mode (``jax.jvp``) is refused, as for any ``custom_vjp``: call the plain loop.
    """
    return _reverse(inputs, solve, limit)


@eqx.filter_custom_vjp
def _reverse(inputs, solve, limit):
    return solve(inputs, "lax")


@_reverse.def_fwd
def _reverse_fwd(perturbed, inputs, solve, limit):
    diff, fixed = eqx.partition(inputs, perturbed)
    flat, unravel = ravel_pytree(diff)
    static = []  # the output's part that is not an array (kept from the trace)

    def arrays(kind):
        """The run as a function of the perturbed scalars: its float arrays, and the rest as aux."""

        def run(params):
            out = solve(eqx.combine(unravel(params), fixed), kind)
            floats, rest = eqx.partition(out, eqx.is_inexact_array)
            rest_arrays, rest_static = eqx.partition(rest, eqx.is_array)
            if not static:
                static.append(rest_static)
            return floats, rest_arrays

        return run

    if flat.size == 0:  # nothing perturbed that the run reads: no tangent, a zero gradient
        floats, rest = arrays("lax")(flat)
        return eqx.combine(floats, rest, static[0]), ("tangents", jax.tree.map(lambda x: jnp.zeros((0, *x.shape)), floats), None)
    if flat.size > limit:
        floats, pullback, rest = jax.vjp(arrays("checkpointed"), flat, has_aux=True)
        return eqx.combine(floats, rest, static[0]), ("pullback", pullback, floats)

    def tangent(direction):
        return jax.jvp(arrays("lax"), (flat,), (direction,), has_aux=True)

    if flat.size == 1:  # one tangent: the loop under jax.jvp alone, not batched (traced faster)
        floats, tangent_1, rest = tangent(jnp.ones(1, flat.dtype))
        tangents = jax.tree.map(lambda t: t[None], tangent_1)
    else:
        floats, tangents, rest = jax.vmap(tangent, out_axes=(None, 0, None))(jnp.eye(flat.size, dtype=flat.dtype))
    return eqx.combine(floats, rest, static[0]), ("tangents", tangents, None)


@_reverse.def_bwd
def _reverse_bwd(residuals, cotangent, perturbed, inputs, solve, limit):
    how, derivative, floats = residuals
    flat, unravel = ravel_pytree(eqx.partition(inputs, perturbed)[0])
    if how == "pullback":  # None (a symbolic zero) becomes zeros for jax.vjp's pullback
        leaves, treedef = jax.tree_util.tree_flatten(floats)
        cts = treedef.flatten_up_to(cotangent)
        filled = [jnp.zeros_like(x) if c is None else c for x, c in zip(leaves, cts, strict=True)]
        (gradient,) = derivative(jax.tree_util.tree_unflatten(treedef, filled))
        return unravel(gradient)
    leaves, treedef = jax.tree_util.tree_flatten(derivative)
    total = jnp.zeros(flat.size, flat.dtype)
    for c, t in zip(treedef.flatten_up_to(cotangent), leaves, strict=True):
        if c is not None:
            total = total + _contract(c, t)
    return unravel(total)


def _contract(cotangent, tangents):
    """Σ cotangent · tangent for each of the k tangents; a zero cotangent on a NaN tangent (a
    padded row past a stop) adds 0. Skipped where the cotangent is zero: the room kept for
    jumps is k times its size in tangents, and a loss that reads no jump hands it a zero
    cotangent (P4: 4.8 of 15.5 ms went to this product, measured)."""
    k = tangents.shape[0]
    if cotangent.size <= 4096:
        return jnp.where(cotangent != 0, cotangent * tangents, 0.0).reshape(k, -1).sum(axis=1)
    return jax.lax.cond(
        jnp.any(cotangent != 0),
        lambda: jnp.where(cotangent != 0, cotangent * tangents, 0.0).reshape(k, -1).sum(axis=1),
        lambda: jnp.zeros(k, tangents.dtype),
    )


def undefined_where_unreached(solution, inputs, reverse: bool):
    """``solution`` with NaN derivatives where they do not exist: the rows a run did not reach
    (``valid`` False: past a stop, or padding), the jump slots it did not fill, and whatever
    follows a grazing of a fold within the run's error (``stats["grazed_at"]``: a jump that
    appears or vanishes under any perturbation) or a singular passage followed
    (``stats["singular_passage_at"]``, ``fold="follow"``: one of several solutions there).

    Without this the derivative of a NaN value would be a finite zero (``jnp.where`` sends none
    through the NaN branch), and past a grazing the one-sided derivative of the branch the run
    happened to take. Forward mode: a NaN tangent there. Reverse mode (``reverse``): a nonzero
    cotangent on such a value makes the gradient with respect to every float of ``inputs``
    (what the run was computed from) NaN; a zero one adds nothing, so a gradient of the values
    that exist stays finite.
    """
    ends = [solution.stats[k] for k in ("grazed_at", "singular_passage_at") if k in solution.stats]
    derivatives_end = jnp.fmin(*ends) if len(ends) == 2 else (ends[0] if ends else None)
    jumps = solution.jumps
    fields = () if jumps is None else tuple(n for n in ("t", "v_before", "v_after", "G", "F") if getattr(jumps, n) is not None)
    values = (solution.ys, *(getattr(jumps, n) for n in fields))
    defined = (solution.valid[:, None], *(jumps.slot_valid() for _ in fields))
    if derivatives_end is not None:  # (NaN: none; ts is NaN where not valid)
        before = (~(solution.ts > derivatives_end))[:, None], *(~(jumps.t > derivatives_end) for _ in fields)
        defined = tuple(d & b for d, b in zip(defined, before, strict=True))
    if reverse:
        values = _undefined_reverse((values, inputs), defined)
    else:
        values = tuple(_undefined_forward(x, d) for x, d in zip(values, defined, strict=True))
    solution = eqx.tree_at(lambda s: s.ys, solution, values[0])
    if fields:
        solution = eqx.tree_at(
            lambda s: [getattr(s.jumps, n) for n in fields], solution, list(values[1:])
        )
    return solution


@jax.custom_jvp
def _undefined_forward(values, defined):
    return values


@_undefined_forward.defjvp
def _undefined_forward_jvp(primals, tangents):
    values, defined = primals
    return values, jnp.where(defined, tangents[0], jnp.nan)


@eqx.filter_custom_vjp
def _undefined_reverse(values_and_inputs, defined):
    return values_and_inputs[0]


@_undefined_reverse.def_fwd
def _undefined_reverse_fwd(perturbed, values_and_inputs, defined):
    return values_and_inputs[0], None


@_undefined_reverse.def_bwd
def _undefined_reverse_bwd(residuals, cotangent, perturbed, values_and_inputs, defined):
    values, inputs = values_and_inputs
    cts = jax.tree_util.tree_structure(values).flatten_up_to(cotangent)
    undefined = jnp.asarray(False)
    for c, d in zip(cts, defined, strict=True):
        if c is not None:
            undefined = undefined | jnp.any(~d & (c != 0))
    to_inputs = jax.tree.map(
        lambda x, p: jnp.where(undefined, jnp.nan, jnp.zeros_like(x)) if p else None,
        inputs, perturbed[1], is_leaf=lambda x: x is None,
    )
    return cotangent, to_inputs
