"""The α-method as a diffrax solver, for any ODE y' = f(t, y) (diffrax has no generalized-α solver).

    sol = diffrax.diffeqsolve(diffrax.ODETerm(f), peeljax.AlphaSolver(rho=0.0), t0, t1, dt0, y0,
                              stepsize_controller=diffrax.PIDController(rtol=1e-6, atol=1e-9))

One step from (y_n, f_n, a_n) with h = t_{n+1} − t_n, b = β/γ (the scheme of
:mod:`peeljax.integrators.alpha`):

    y_{n+1} = y_n + (1 − b)·h·f_n + b·h·f(t_{n+1}, y_{n+1}) + (1/2 − b)·h²·a_n
    a_{n+1} = (f_{n+1} − f_n)/(γ·h) + (1 − 1/γ)·a_n,      a_0 = df/dt(t_0) (autodiff),

solved by an optimistix root finder (Newton by default, differentiated by the implicit
function theorem through optimistix's ``ImplicitAdjoint``). A root find that fails returns an
infinite error, so diffrax rejects the step and retries with a smaller one. Dense output:
diffrax's cubic Hermite interpolation. (f_n, a_n) are the solver state: a rejected step leaves
them as they were. Real and complex states (any inexact dtype; the scheme's real coefficients
are cast to each leaf's dtype, so it runs under JAX's strict dtype promotion).

The error estimate (``error_estimate``):

* ``"embedded"`` (default): y_{n+1} − (y_n + h·f_n), the difference between the α-method and the
  explicit Euler step from the same point — an embedded pair of orders 2 and 1, the estimate of
  diffrax's own second-order solvers (Heun, Midpoint, Ralston), of order 2 for the controller.
  It overestimates the α-method's local error by a factor ∝ 1/h, and that is what makes the
  global error proportional to the tolerance: on the non-stiff test set of Hull, Enright, Fellen
  and Sedgwick (1972) at rtol = atol = 1e-6 over [0, 20] every end point is within diffrax's
  bound for second-order solvers, 1e-3·(1 + |y|) (``benchmarks/studies/detest.py`` (retired: ``benchmarks/studies/README.md``)).
* ``"local"``: C·h²·(a_{n+1} − a_n) (:func:`peeljax.integrators.steppers.error_constant`), the
  α-method's own local error C·h³·y‴ (the estimate of peeljax's loop), of order 3. It is honest
  step by step — measured within a factor 1.6 of the true local error on every accepted step of
  that test set — and gives the fewest steps for a given global error, but the global error then
  grows like tol^(2/3)·(the steps' accumulation), not like tol: at rtol = atol = 1e-6 the Kepler
  orbits D1–D5 end 5e-3 … 6e-2 off (``docs/theory.md``).
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
from .alpha import alpha_coefficients
from .steppers import error_constant

__all__ = ["AlphaSolver", "ERROR_ESTIMATES"]

ERROR_ESTIMATES = ("embedded", "local")


def _scaled(c, leaf):
    """The real coefficient c in ``leaf``'s dtype (strict dtype promotion: no implicit casts)."""
    return jnp.asarray(c).astype(jnp.result_type(leaf))


class AlphaSolver(diffrax.AbstractImplicitSolver, diffrax.AbstractAdaptiveSolver):
    """The first-order generalized-α method (the paper's α-method) as a diffrax solver.

    Attributes:
        rho: spectral radius at infinity, ρ ∈ [0, 1) (0 damps the most).
        root_finder: an optimistix root finder for the step equation (default Newton with
            rtol 1e-10, atol 1e-12).
        root_find_max_steps: iteration cap; a step that does not converge is rejected.
        error_estimate: ``"embedded"`` (default: the difference with the explicit Euler step,
            error order 2, global error proportional to the tolerance) or ``"local"`` (the
            α-method's local error C·h²·(a_{n+1} − a_n), error order 3: fewer steps at equal
            global error, which grows like tol^(2/3)); see the module docstring.
    """

    term_structure: ClassVar = diffrax.ODETerm
    interpolation_cls: ClassVar[Callable[..., diffrax.ThirdOrderHermitePolynomialInterpolation]] = (
        diffrax.ThirdOrderHermitePolynomialInterpolation.from_k
    )

    rho: float = 0.0
    root_finder: optx.AbstractRootFinder = optx.Newton(rtol=1e-10, atol=1e-12)
    root_find_max_steps: int = eqx.field(static=True, default=25)
    error_estimate: str = eqx.field(static=True, default="embedded")

    def __check_init__(self):
        check_rho(self.rho)
        if self.error_estimate not in ERROR_ESTIMATES:
            raise ValueError(f"error_estimate must be one of {list(ERROR_ESTIMATES)}, got {self.error_estimate!r}")

    def order(self, terms):
        return 2

    def error_order(self, terms):
        return 2 if self.error_estimate == "embedded" else 3

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
        known = jtu.tree_map(
            lambda y, f, a: y + _scaled((1 - b) * h, y) * f + _scaled((0.5 - b) * h**2, y) * a, y0, f0, a0
        )

        def residual(y1, _):
            f1 = terms.vf(t1, y1, args)
            return jtu.tree_map(lambda y, k, f: y - k - _scaled(b * h, y) * f, y1, known, f1)

        solution = optx.root_find(residual, self.root_finder, y0, None, max_steps=self.root_find_max_steps, throw=False)
        y1 = solution.value
        f1 = terms.vf(t1, y1, args)
        a1 = jtu.tree_map(
            lambda f_1, f_0, a: (f_1 - f_0) * _scaled(1 / (gamma * h), a) + _scaled(1 - 1 / gamma, a) * a, f1, f0, a0
        )
        converged = solution.result == optx.RESULTS.successful
        if self.error_estimate == "embedded":
            # y_{n+1} minus the explicit Euler step y_n + h·f_n (orders 2 and 1).
            error = jtu.tree_map(lambda y_1, y_0, f: y_1 - y_0 - _scaled(h, f) * f, y1, y0, f0)
        else:
            C = error_constant(self.rho)
            error = jtu.tree_map(lambda a_1, a_0: _scaled(C * h**2, a_1) * (a_1 - a_0), a1, a0)
        y_error = jtu.tree_map(lambda e: jnp.where(converged, e, jnp.inf), error)
        k = jtu.tree_map(lambda f_0, f_1: jnp.stack([_scaled(h, f_0) * f_0, _scaled(h, f_1) * f_1]), f0, f1)
        dense_info = dict(y0=y0, y1=y1, k=k)
        return y1, y_error, dense_info, (f1, a1), diffrax.RESULTS.promote(solution.result)

    def func(self, terms, t0, y0, args):
        return terms.vf(t0, y0, args)
