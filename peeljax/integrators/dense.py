"""Dense output: the cubic Hermite interpolant of a step (as diffrax's
``ThirdOrderHermitePolynomialInterpolation``).

On [t_n, t_n + h], with θ = (t − t_n)/h,

    y(t) = h00(θ)·y_n + h10(θ)·h·ψ_n + h01(θ)·y_{n+1} + h11(θ)·h·ψ_{n+1},
    h00 = 2θ³ − 3θ² + 1,  h10 = θ³ − 2θ² + θ,  h01 = −2θ³ + 3θ²,  h11 = θ³ − θ²,

which matches y and y' = ψ at both ends: its error is O(h⁴) on a smooth solution, below the
α-method's own O(h²) global error.
"""

from __future__ import annotations

import math

import numpy as np
from jaxtyping import Array, Float

__all__ = ["hermite", "output_count", "output_times"]


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
