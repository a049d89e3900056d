"""Dense output: a step's interpolant, evaluated anywhere inside the step.

Every stepper hands the loop an interpolant of each step with ``evaluate(ts)`` (times in
[t, t + h], shape (m,) → (m, n)): the α-method the cubic Hermite one below
(:class:`HermiteInterpolant`, as diffrax's ``ThirdOrderHermitePolynomialInterpolation``), a
diffrax solver its own (:class:`SolverInterpolant`: Tsit5's and Dopri5's fourth-order,
Dopri8's seventh-order, Kvaerno's Hermite). Output, a sweep's statistics and the fold events
all read it.

On [t_n, t_n + h], with θ = (t − t_n)/h,

    y(t) = h00(θ)·y_n + h10(θ)·h·ψ_n + h01(θ)·y_{n+1} + h11(θ)·h·ψ_{n+1},
    h00 = 2θ³ − 3θ² + 1,  h10 = θ³ − 2θ² + θ,  h01 = −2θ³ + 3θ²,  h11 = θ³ − θ²,

which matches y and y' = ψ at both ends: its error is O(h⁴) on a smooth solution, below the
α-method's own O(h²) global error.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

__all__ = [
    "HermiteInterpolant",
    "PhysicalTimeInterpolant",
    "SolverInterpolant",
    "hermite",
    "output_count",
    "output_times",
]


def hermite(
    t0: Float[Array, ""],
    h: Float[Array, ""],
    y0: Float[Array, " n"],
    psi0: Float[Array, " n"],
    y1: Float[Array, " n"],
    psi1: Float[Array, " n"],
    t: Float[Array, " m"],
) -> Float[Array, "m n"]:
    """The cubic Hermite interpolant through (y0, ψ0) at t0 and (y1, ψ1) at t0 + h, at times t."""
    theta = ((t - t0) / h)[:, None]
    theta2 = theta * theta
    theta3 = theta2 * theta
    h00 = 2 * theta3 - 3 * theta2 + 1
    h10 = theta3 - 2 * theta2 + theta
    h01 = -2 * theta3 + 3 * theta2
    h11 = theta3 - theta2
    return h00 * y0 + h10 * (h * psi0) + h01 * y1 + h11 * (h * psi1)


class HermiteInterpolant(eqx.Module):
    """The cubic Hermite interpolant of a step (:func:`hermite`) through (y0, ψ0) at t0 and (y1, ψ1) at t0 + h."""

    t0: Array
    h: Array
    y0: Array
    psi0: Array
    y1: Array
    psi1: Array

    def evaluate(self, t: Float[Array, " m"]) -> Float[Array, "m n"]:
        return hermite(self.t0, self.h, self.y0, self.psi0, self.y1, self.psi1, t)


class SolverInterpolant(eqx.Module):
    """A diffrax solver's own interpolant of a step (``solver.interpolation_cls(t0, t1, **dense_info)``)."""

    interpolation: eqx.Module

    def evaluate(self, t: Float[Array, " m"]) -> Float[Array, "m n"]:
        return jax.vmap(self.interpolation.evaluate)(t)


def _stop(tree):
    """``lax.stop_gradient`` on a pytree's inexact arrays."""
    return jax.tree_util.tree_map(lambda a: jax.lax.stop_gradient(a) if eqx.is_inexact_array(a) else a, tree)


_TIME_ITERATIONS = 56  # bisection halvings of [s0, s1]: to round-off in double precision


class PhysicalTimeInterpolant(eqx.Module):
    """A step in pseudo-time s (:class:`~peeljax.DesingularizedDAE`) as an interpolant in time.

    The step's own interpolant z(s) on [s0, s1] carries the time t(s) as component
    ``time_index``, increasing in s; ``evaluate(ts)`` returns z at the s where t(s) = ts
    (found by bisection, as the fold events are), with the implicit function theorem's
    derivative ds = −(∂t/∂p − dts)/(dt/ds) (as :func:`peeljax.integrators.events.locate_fold`).
    """

    interpolant: eqx.Module
    s0: Array
    s1: Array
    time_index: int = eqx.field(static=True)

    def pseudo_time(self, t: Float[Array, ""]) -> Array:
        """The s in [s0, s1] with t(s) = t (value only)."""
        interpolant, s0, s1, target = _stop((self.interpolant, self.s0, self.s1, t))

        def bisect(_, bracket):
            lo, hi = bracket
            mid = 0.5 * (lo + hi)
            past = interpolant.evaluate(mid[None])[0, self.time_index] >= target
            return jnp.where(past, lo, mid), jnp.where(past, mid, hi)

        lo, hi = jax.lax.fori_loop(0, _TIME_ITERATIONS, bisect, (s0, s1))
        return 0.5 * (lo + hi)

    def at(self, t: Float[Array, ""]) -> tuple[Array, Float[Array, " n"]]:
        """(s in value, z(s)) where t(s) = t, z with the implicit function theorem's derivative."""
        s = self.pseudo_time(t)
        frozen = _stop(self.interpolant)
        _, rate = jax.jvp(lambda s: frozen.evaluate(s[None])[0, self.time_index], (s,), (jnp.ones_like(s),))
        residual = self.interpolant.evaluate(s[None])[0, self.time_index] - t
        correction = -(residual - jax.lax.stop_gradient(residual)) / jnp.where(rate > 0, rate, 1.0)
        return s, self.interpolant.evaluate((s + correction)[None])[0]

    def evaluate(self, t: Float[Array, " m"]) -> Float[Array, "m n"]:
        return jax.vmap(lambda t: self.at(t)[1])(jnp.asarray(t, float))


def output_count(save_dt: float, t_final: float) -> int:
    """``len(output_times(save_dt, t_final))``, without making the array (checked before a run)."""
    last = math.floor(t_final / save_dt + 1e-9)
    return last + 1 + (t_final - min(last * save_dt, t_final) > 1e-9 * save_dt)


def output_times(save_dt: float, t_final: float) -> Float[np.ndarray, " m"]:
    """t = k·S for k = 0 … floor(t_final/S + 1e-9), plus t_final when it is not on that grid."""
    k = np.arange(math.floor(t_final / save_dt + 1e-9) + 1)
    ts = np.minimum(k * save_dt, t_final)
    if t_final - ts[-1] > 1e-9 * save_dt:
        ts = np.append(ts, t_final)
    return ts
