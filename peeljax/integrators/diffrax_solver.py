"""The α-method as a diffrax solver, for any ODE y' = f(t, y) (diffrax has no generalized-α solver).

    sol = diffrax.diffeqsolve(diffrax.ODETerm(f), peeljax.AlphaSolver(rho=0.0), t0, t1, dt0, y0,
                              stepsize_controller=diffrax.PIDController(rtol=1e-6, atol=1e-9))

One step from (y_n, f_n, a_n) with h = t_{n+1} − t_n, b = β/γ (the scheme of
:mod:`peeljax.integrators.alpha`):

    y_{n+1} = y_n + (1 − b)·h·f_n + b·h·f(t_{n+1}, y_{n+1}) + (1/2 − b)·h²·a_n
    a_{n+1} = (f_{n+1} − f_n)/(γ·h) + (1 − 1/γ)·a_n,      a_0 = df/dt(t_0) (autodiff),

solved by an optimistix root finder (Newton by default, differentiated by the implicit
function theorem through optimistix's ``ImplicitAdjoint``). The error estimate is
C·h²·(a_{n+1} − a_n) (:func:`peeljax.integrators.adaptive.error_constant`), of order 3 for the
controller; a root find that fails returns an infinite error, so diffrax rejects the step
and retries with a smaller one. Dense output: diffrax's cubic Hermite interpolation.
(f_n, a_n) are the solver state: a rejected step leaves them as they were.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import optimistix as optx

from .._validation import check_rho
from .adaptive import error_constant
from .alpha import alpha_coefficients

__all__ = ["AlphaSolver"]


class AlphaSolver(diffrax.AbstractImplicitSolver, diffrax.AbstractAdaptiveSolver):
    """The first-order generalized-α method (the paper's α-method) as a diffrax solver.

    Attributes:
        rho: spectral radius at infinity, ρ ∈ [0, 1) (0 damps the most).
        root_finder: an optimistix root finder for the step equation (default Newton with
            rtol 1e-10, atol 1e-12).
        root_find_max_steps: iteration cap; a step that does not converge is rejected.
    """

    term_structure: ClassVar = diffrax.ODETerm
    interpolation_cls: ClassVar[Callable[..., diffrax.ThirdOrderHermitePolynomialInterpolation]] = (
        diffrax.ThirdOrderHermitePolynomialInterpolation.from_k
    )

    rho: float = 0.0
    root_finder: optx.AbstractRootFinder = optx.Newton(rtol=1e-10, atol=1e-12)
    root_find_max_steps: int = eqx.field(static=True, default=25)

    def __check_init__(self):
        check_rho(self.rho)

    def order(self, terms):
        return 2

    def error_order(self, terms):
        return 3

    def _start(self, terms, t0, y0, args):
        f0 = terms.vf(t0, y0, args)
        # a_0 = df/dt along the solution = ∂f/∂t + ∂f/∂y·f.
        _, a0 = jax.jvp(lambda t, y: terms.vf(t, y, args), (t0, y0), (jnp.ones_like(t0), f0))
        return f0, a0

    def init(self, terms, t0, t1, y0, args):
        return self._start(terms, jnp.asarray(t0, float), y0, args)

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        f0, a0 = jax.lax.cond(
            made_jump, lambda: self._start(terms, jnp.asarray(t0, float), y0, args), lambda: solver_state
        )
        h = t1 - t0
        gamma, beta = alpha_coefficients(self.rho)
        b = beta / gamma
        known = jtu.tree_map(lambda y, f, a: y + (1 - b) * h * f + (0.5 - b) * h**2 * a, y0, f0, a0)

        def residual(y1, _):
            f1 = terms.vf(t1, y1, args)
            return jtu.tree_map(lambda y, k, f: y - k - b * h * f, y1, known, f1)

        solution = optx.root_find(residual, self.root_finder, y0, None, max_steps=self.root_find_max_steps, throw=False)
        y1 = solution.value
        f1 = terms.vf(t1, y1, args)
        a1 = jtu.tree_map(lambda f_1, f_0, a: (f_1 - f_0) / (gamma * h) + (1 - 1 / gamma) * a, f1, f0, a0)
        converged = solution.result == optx.RESULTS.successful
        C = error_constant(self.rho)
        y_error = jtu.tree_map(lambda a_1, a_0: jnp.where(converged, C * h**2 * (a_1 - a_0), jnp.inf), a1, a0)
        k = jtu.tree_map(lambda f_0, f_1: jnp.stack([h * f_0, h * f_1]), f0, f1)
        dense_info = dict(y0=y0, y1=y1, k=k)
        return y1, y_error, dense_info, (f1, a1), diffrax.RESULTS.promote(solution.result)

    def func(self, terms, t0, y0, args):
        return terms.vf(t0, y0, args)
