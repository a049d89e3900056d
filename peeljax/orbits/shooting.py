"""Shooting for a stick-slip orbit: Newton on the return map, derivatives by the implicit
function theorem.

A periodic orbit with k stick → slip events per period is a fixed point of the return map
after k events on the section Σ (:mod:`peeljax.orbits.section`, :mod:`peeljax.orbits.period`):

    r(z; θ) = P^k(z; θ) − z = 0,

z the scaled section coordinates, θ everything the orbit depends on (V, the model, φ's
coefficients). Newton's method (optimistix's ``Newton``: the Jacobian ∂P^k/∂z by forward-mode
autodiff through the loop, its events and jumps) solves it; the Jacobian at the solution is
the orbit's monodromy M on Σ (:mod:`peeljax.orbits.floquet`).

Derivatives are not taken through Newton's iterations. The fixed point z*(θ) is
differentiated by the implicit function theorem, one linear solve with I − M:

    dz* = (I − M)⁻¹ ∂P^k/∂θ·dθ,    dq = ∂q/∂z·dz* + ∂q/∂θ·dθ

for every quantity q of the period (its time, forces, jump times, statistics), with ∂/∂z and
∂/∂θ by forward-mode passes through one period, one per tangent: the two section directions
and the components of θ that carry a tangent (an ``equinox.filter_custom_jvp``: components not
differentiated cost nothing). The tangent rule is linear in dθ with constant
matrices, so JAX transposes it: ``jax.grad``, ``jax.jacrev``, ``jax.jvp`` and ``jax.jacfwd``
all work, the loop itself only ever differentiated forward. The monodromy and its
multipliers are held constant in derivatives (their derivative needs second derivatives of
P^k).
"""

from __future__ import annotations

import enum

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float, Int

from ..integrators.adaptive import ErrorControl
from ..model import PeelingModel
from .period import OnePeriod, one_period
from .section import SlipSection

__all__ = [
    "FLOOR_RESIDUAL", "FLOOR_RTOL", "Linearised", "OrbitStatus", "Shooting", "ShootingResult", "at_floor",
    "keep_converged", "linearised", "shoot",
]


# Newton's floor (docs/attractors.md): a solve that ends NOT_CONVERGED with |P^k(z) − z| below
# FLOOR_RESIDUAL is held up by the runs' own error through k slips, not by its start; shot again
# from its last iterate with the runs at FLOOR_RTOL it converges.
FLOOR_RESIDUAL = 1e-6
FLOOR_RTOL = 1e-10


class OrbitStatus(enum.IntEnum):
    """Why shooting ended. ``CONVERGED`` is the only success."""

    CONVERGED = 0
    NOT_CONVERGED = 1
    DIVERGED = 2
    EVENTS_CHANGED = 3
    NO_FOLD = 4

    @property
    def message(self) -> str:
        return _MESSAGES[self]


_MESSAGES = {
    OrbitStatus.CONVERGED: "converged: the return map's fixed point was found",
    OrbitStatus.NOT_CONVERGED: (
        "Newton's method did not converge within max_iterations (a start far from the orbit, or an orbit close "
        "to a bifurcation, where I − M is near-singular)"
    ),
    OrbitStatus.DIVERGED: "Newton's method diverged: the start is outside the orbit's basin for Newton",
    OrbitStatus.EVENTS_CHANGED: (
        "the run from the section did not come back through k stick → slip events within its time bound "
        "(3 periods of the start's): the stick-slip ended (steady peeling, a stuck tape), or the orbit asked "
        "for does not exist here"
    ),
    OrbitStatus.NO_FOLD: "phi has no fold at this V: the peeling is steady, there is no stick-slip orbit",
}


def at_floor(status, residual, start, period) -> np.ndarray:
    """The indices of a batch of solves held at Newton's floor (NOT_CONVERGED, residual below
    :data:`FLOOR_RESIDUAL`) whose last iterate ``start`` (n, d) and ``period`` are finite: those
    to shoot again from there at :data:`FLOOR_RTOL`."""
    return np.flatnonzero((np.asarray(status) == OrbitStatus.NOT_CONVERGED) & (np.asarray(residual) < FLOOR_RESIDUAL)
                          & np.all(np.isfinite(start), axis=-1) & np.isfinite(period))  # fmt: skip


def keep_converged(out: dict, again: dict, rows: np.ndarray) -> None:
    """``out``'s arrays at ``rows`` replaced by ``again``'s (the solves shot again, in that order)
    where those converged; in place."""
    closed = np.asarray(again["status"]) == OrbitStatus.CONVERGED
    for name in out:
        out[name][rows[closed]] = again[name][closed]


class Shooting(eqx.Module):
    """How an orbit is shot: the integrator of one period and Newton's settings.

    Attributes:
        integrator: the error-controlled loop with fold events whose record holds one jump
            (:func:`peeljax.integrators.integrator_for` with ``adjoint="forward"``,
            ``max_jumps=1``): each run goes from one slip to the next.
        max_iterations: Newton's iteration cap (traced: another cap compiles nothing new).
        tolerance: the largest |P^k(z) − z| at a converged orbit, in the scaled coordinates
            (radians and units of V/R).
    """

    integrator: ErrorControl
    max_iterations: Int[Array, ""] = eqx.field(converter=lambda n: jnp.asarray(n, jnp.int32), default=20)
    tolerance: float = eqx.field(static=True, default=1e-10)


class ShootingResult(eqx.Module):
    """The fixed point and its period (scaled coordinates z = s/scale).

    Attributes:
        z: the section coordinates of the orbit, scaled.
        period: the run of one period from it (:class:`~peeljax.orbits.period.OnePeriod`).
        monodromy: M = ∂P^k/∂s (2 × 2, unscaled), no derivative.
        residual: max |P^k(z) − z| (scaled).
        iterations: Newton's iterations.
        status: an :class:`OrbitStatus` code.
    """

    z: Float[Array, "2"]
    period: OnePeriod
    monodromy: Float[Array, "2 2"]
    residual: Float[Array, ""]
    iterations: Int[Array, ""]
    status: Int[Array, ""]


def _return(shooting: Shooting, model: PeelingModel, V, z, slips, t_max) -> tuple[Array, OnePeriod]:
    """(r(z) = P^k(z) − z scaled, the period's runs) at scaled coordinates z, k = ``slips``."""
    section = SlipSection.at(model, V)
    scale = section.scale
    period = one_period(section, shooting.integrator, z * scale, slips, t_max)
    return (period.end - z * scale) / scale, period


class Linearised(eqx.Module):
    """One period as a function of w = (z, θ_p) with its forward-mode Jacobian (module docstring).

    ``at(w, is_last=None)`` → (the Jacobian of every float output in w, r, the period): one
    forward-mode pass through one period per component of w; those of θ_p only where
    ``is_last(r, period)`` is True, if given (their columns are zero otherwise: Newton's steps
    need z's). θ_p are the leaves of (model, V) at
    ``theta_leaves`` (raveled); ``theta`` their values; ``unravel`` makes a column of the
    Jacobian into (r, period) tangents.
    """

    at: object
    unravel: object
    theta: Array
    shapes: tuple  # of ``at``'s outputs (ShapeDtypeStructs): its result made without tracing it

    def w(self, z: Float[Array, "2"]) -> Array:
        return jnp.concatenate([z, self.theta])


def linearised(shooting: Shooting, model, V, slips, t_max, theta_leaves: tuple[int, ...]) -> Linearised:
    """The :class:`Linearised` period of the orbit with k = ``slips``."""
    leaves, treedef = jax.tree_util.tree_flatten((model, V))
    theta = [jnp.ravel(jnp.asarray(leaves[i], float)) for i in theta_leaves]
    sizes = [t.size for t in theta]
    z_shape = jax.ShapeDtypeStruct((2,), jnp.dtype(float))
    returned = jax.eval_shape(lambda z: _return(shooting, model, V, z, slips, t_max), z_shape)
    floats_shape = eqx.filter(returned, lambda a: jnp.issubdtype(a.dtype, jnp.inexact))
    floats, unravel = ravel_pytree(jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), floats_shape))
    w_size = 2 + sum(sizes)
    shapes = (jax.ShapeDtypeStruct((floats.size, w_size), jnp.dtype(float)), *returned)

    def outputs(w):
        new = list(leaves)
        offset = 2
        for i, size in zip(theta_leaves, sizes):
            new[i] = w[offset : offset + size].reshape(jnp.shape(leaves[i]))
            offset += size
        m, v = jax.tree_util.tree_unflatten(treedef, new)
        r, period = _return(shooting, m, v, w[:2], slips, t_max)
        return ravel_pytree(eqx.partition((r, period), eqx.is_inexact_array)[0])[0], (r, period)

    def column(w, dw):
        _, d_floats, (r, period) = jax.jvp(outputs, (w,), (dw,), has_aux=True)
        return d_floats, r, period

    def at(w, is_last=None):
        # One column of the Jacobian at a time, not jax.jacfwd's batch of tangents: batched, the
        # period's loops took 1.8x as long to run and 1.6x as long to trace (the orbit at V = 1.1:
        # 42 ms against 76, measured). Column 0 gives r and the period; the columns of θ only
        # where ``is_last(r, period)`` (Newton needs those of z alone). One loop: one pass compiled.
        n = w.shape[0]
        directions = jnp.eye(n)

        def more(carry):
            return carry[0] < carry[-1]

        def next_column(carry):
            j, jac, r, period, wanted = carry
            d_floats, r_j, period_j = column(w, directions[j])
            first = j == 0
            r, period = jax.tree_util.tree_map(lambda a, b: jnp.where(first, a, b), (r_j, period_j), (r, period))
            last = True if is_last is None else is_last(r_j, period_j)
            wanted = jnp.where(first, jnp.where(last, n, 2), wanted)
            return j + 1, jac.at[:, j].set(d_floats), r, period, wanted

        jac0, r0, period0 = jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), shapes)
        init = (jnp.asarray(0), jac0, r0, period0, jnp.asarray(1))
        _, jac, r, period, _ = jax.lax.while_loop(more, next_column, init)
        return jac, r, period

    return Linearised(at, unravel, jnp.concatenate([jnp.zeros(0), *theta]), shapes)


class _Newton(eqx.Module):
    z: Array  # the point evaluated last
    step: Array  # the Newton step from it
    jac: Array
    r: Array
    period: OnePeriod
    iterations: Array
    first_residual: Array
    done: Array
    diverged: Array


def _solve(shooting: Shooting, model, V, z0, slips, t_max, avoid, theta_leaves: tuple[int, ...] = ()):
    """Newton's method on r(z) = 0, each iteration forward-mode passes through one period
    (:func:`linearised`: the two of z, and at the last point those of θ too). Ends at the first
    point with |r| ≤ tolerance and returns what was computed there — the period and its
    Jacobian, without another pass. Values only: nothing
    is differentiated through the iterations. Steps are limited to 0.5 in the scaled
    coordinates; |r| growing 100× past the first residual is divergence.

    ``avoid`` (scaled, NaN: none) is a known fixed point deflated away (Farrell, Birkisson &
    Funke 2015): Newton on m(z)·r(z), m = 1/|z − avoid|² + 1, whose step is the plain one times
    τ = 1/(1 − ∇m·δ/m). Past a period doubling P^{2k} has the k-orbit as a fixed point too, and
    plain Newton from beside it returns there: measured on the 5-slip orbit at 0.5 m/s of
    ``benchmarks/fit_coverage.py --problem wide``, 0.008–0.16 % of c1 past its doubling, from 23
    of 30 starts 0.003–0.3 away along the multiplier's eigenvector; deflated, 17 of 18 starts
    0.001–0.1 away reached the doubled orbit."""
    lin = linearised(shooting, model, V, slips, t_max, theta_leaves)
    at, unravel = lin.at, lin.unravel

    def residual_jacobian(jac):
        columns = [unravel(jac[:, j])[0] for j in range(2)]
        return jnp.stack(columns, axis=1)

    def outcome(c: _Newton, r, period):
        """(|r|, first |r|, converged, diverged, done) at a point whose residual is r."""
        norm = jnp.max(jnp.abs(r))
        first = jnp.where(c.iterations == 0, norm, c.first_residual)
        converged = norm <= shooting.tolerance
        diverged = ~jnp.isfinite(norm) | (norm > 100.0 * jnp.maximum(first, shooting.tolerance))
        done = converged | diverged | ~period.reached | (c.iterations + 1 >= shooting.max_iterations)
        return norm, first, converged, diverged, done

    def evaluate(c: _Newton, z) -> _Newton:
        jac, r, period = at(lin.w(z), lambda r, period: outcome(c, r, period)[-1])
        norm, first, converged, diverged, done = outcome(c, r, period)
        r_z = residual_jacobian(jac)
        step = -jnp.linalg.solve(jnp.where(jnp.isfinite(r_z), r_z, 0.0) + jnp.where(jnp.all(jnp.isfinite(r_z)), 0.0, jnp.eye(2)), r)
        step = jnp.where(jnp.all(jnp.isfinite(step)), step, 0.0)
        step = step * _deflation(z, step, avoid)
        step = step * jnp.minimum(1.0, 0.5 / jnp.maximum(jnp.max(jnp.abs(step)), 1e-300))
        return _Newton(z, step, jac, r, period, c.iterations + 1, first, done, diverged & ~converged)

    # (``at``'s shapes from one trace of a period, not from a trace of its forward-mode Jacobian:
    # each trace of that took seconds)
    zeros = jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), lin.shapes)
    # The loop's body holds the one pass (a pass outside it would be compiled twice).
    init = _Newton(z0, jnp.zeros(2), zeros[0], zeros[1], zeros[2], jnp.asarray(0), jnp.asarray(jnp.inf), jnp.asarray(False), jnp.asarray(False))
    final = jax.lax.while_loop(lambda c: ~c.done, lambda c: evaluate(c, c.z + c.step), init)
    return final, unravel, residual_jacobian(final.jac)


def _deflation(z, step, avoid) -> Array:
    """τ of :func:`_solve`'s deflated step at z (1 where ``avoid`` is NaN)."""
    e = z - jnp.where(jnp.isfinite(avoid), avoid, 0.0)
    e2 = jnp.maximum(jnp.sum(e * e), 1e-300)
    tau = 1.0 / (1.0 + 2.0 * jnp.dot(e, step) / (e2 * (1.0 + e2)))
    return jnp.where(jnp.all(jnp.isfinite(avoid)) & jnp.isfinite(tau), tau, 1.0)


def _result(shooting: Shooting, model, V, newton: _Newton, r_z) -> ShootingResult:
    section = SlipSection.at(model, V)
    scale = section.scale
    monodromy = (r_z + jnp.eye(2)) * scale[:, None] / scale[None, :]
    residual = jnp.max(jnp.abs(newton.r))
    converged = residual <= shooting.tolerance
    status = jnp.select(
        [~section.folds.exist, ~newton.period.reached, converged, newton.diverged],
        [OrbitStatus.NO_FOLD, OrbitStatus.EVENTS_CHANGED, OrbitStatus.CONVERGED, OrbitStatus.DIVERGED],
        OrbitStatus.NOT_CONVERGED,
    ).astype(jnp.int32)
    return ShootingResult(
        z=newton.z, period=newton.period, monodromy=jax.lax.stop_gradient(monodromy), residual=residual,
        iterations=newton.iterations.astype(jnp.int32), status=status,
    )  # fmt: skip


@eqx.filter_custom_jvp
def _shoot(params, guess):
    shooting, model, V = params
    z0, slips, t_max, avoid = guess
    newton, _, r_z = _solve(shooting, model, V, z0, slips, t_max, avoid)
    return _result(shooting, model, V, newton, r_z)


def _tangent_leaves(primal, tangent) -> list:
    """The tangents of ``primal``'s leaves (None where not differentiated)."""
    leaves, treedef = jax.tree_util.tree_flatten(primal)
    if tangent is None:
        return [None] * len(leaves)
    return treedef.flatten_up_to(tangent)


@_shoot.def_jvp
def _shoot_jvp(primals, tangents):
    params, guess = primals
    shooting, model, V = params
    z0, slips, t_max, avoid = guess
    t_leaves = _tangent_leaves((model, V), (tangents[0][1], tangents[0][2]))
    theta_leaves = tuple(i for i, t in enumerate(t_leaves) if t is not None)

    newton, unravel, r_z = _solve(shooting, model, V, z0, slips, t_max, avoid, theta_leaves)
    primal = _result(shooting, model, V, newton, r_z)
    jac = newton.jac
    if theta_leaves:
        d_theta = jnp.concatenate([jnp.ravel(jnp.asarray(t_leaves[i], float)) for i in theta_leaves])
        direct = jac[:, 2:] @ d_theta  # ∂q/∂θ·dθ for every float output q
    else:
        direct = jnp.zeros(jac.shape[0])
    # The implicit function theorem: r(z*(θ), θ) = 0 ⇒ ∂r/∂z·dz* = −∂r/∂θ·dθ. Off a converged
    # orbit (or at a multiplier 1, where ∂r/∂z is singular) z* has no derivative: the tangent
    # is then that of the point reached, never NaN (the status says so).
    invertible = (primal.status == OrbitStatus.CONVERGED) & jnp.all(jnp.isfinite(r_z)) & (jnp.abs(jnp.linalg.det(r_z)) > 1e-300)
    inverse = jnp.where(invertible, jnp.linalg.inv(jnp.where(invertible, r_z, jnp.eye(2))), 0.0)
    dz = -inverse @ unravel(direct)[0]
    d_period = unravel(direct + jac[:, :2] @ dz)[1]
    tangent = ShootingResult(z=dz, period=d_period, monodromy=None, residual=None, iterations=None, status=None)
    return primal, tangent


def shoot(shooting: Shooting, model: PeelingModel, V, z0: Float[Array, "2"], slips, t_max,
          avoid: Float[Array, "2"] | None = None) -> ShootingResult:  # fmt: skip
    """The periodic orbit through k = ``slips`` stick → slip events (a traced integer) nearest
    (for Newton) to the scaled section coordinates z0 (module docstring); ``t_max`` bounds
    one period's runs; ``avoid``: a fixed point (scaled) Newton is kept away from (deflation,
    :func:`_solve`; None or NaN: none).

    Differentiable in ``model`` and ``V`` by the implicit function theorem; z0, k, t_max and
    ``avoid`` carry no derivative (the orbit does not depend on them).
    """
    avoid = jnp.full(2, jnp.nan) if avoid is None else jnp.asarray(avoid, float)
    guess = (jnp.asarray(z0, float), jnp.asarray(slips, jnp.int32), jnp.asarray(t_max, float), avoid)
    return _shoot((shooting, model, jnp.asarray(V, float)), guess)
