"""The window rows' program: a table's statistics over a window of runs from rest, as functions of θ.

Each row at V_i runs from the paper's initial data through the folds (τ = 0: the DAE with
jumps; τ > 0: eq. ``hv`` with jumps) and its statistics over [transient, transient + window]
(:func:`peeljax.measurements.statistics.jump_statistics`, tapered where asked) are compared with the
table's: r_is = (model_s(V_i; θ) − data_is)/σ_is, σ_is² the table's variance plus the model
window's cycle-to-cycle scatter² (:func:`peeljax.measurements.statistics.window_scatter`). A statistic
the run does not produce (no slip in the window) costs ``MISSING_RESIDUAL`` with zero
derivative. Used by the window method of :func:`peeljax.fit.fit_stick_slip` and by the rows
without a periodic attractor of the orbit method (:mod:`peeljax.fit.table_rows`).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..adhesion import AdhesionLaw
from ..constrained import ConstrainedDAE
from ..homogenized import HomogenizedODE
from ..integrators.base import AbstractIntegrator
from ..integrators.select import integrator_for
from ..model import PeelingModel
from .parameters import law_from
from ..measurements.statistics import jump_statistics, window_scatter

__all__ = ["MISSING_RESIDUAL", "TableFit", "build_table_fit", "table_residuals"]

MISSING_RESIDUAL = 10.0  # a statistic the model does not produce at θ (as in the window fit)


class TableFit(eqx.Module):
    """θ ↦ residuals of a stick-slip table (module docstring); a pytree, so its compiled
    programs are reused by fits of the same shapes."""

    start: AdhesionLaw
    model: PeelingModel
    V: Float[Array, " n"]
    data: Float[Array, "n 5"]
    sigma: Float[Array, "n 5"]
    tau: Float[Array, ""]
    integrator: AbstractIntegrator
    names: tuple[str, ...] = eqx.field(static=True)
    measured: tuple[tuple[int, ...], tuple[int, ...]] = eqx.field(static=True)  # (rows, columns)
    transient: float = eqx.field(static=True)
    window: float = eqx.field(static=True)
    n_samples: int = eqx.field(static=True)
    dae: bool = eqx.field(static=True)
    cycle_scatter: bool = eqx.field(static=True, default=True)
    taper: float = eqx.field(static=True, default=0.0)

    def run(self, law: AdhesionLaw, V) -> tuple[Array, Array, Array]:
        """One row: (statistics (5,), available (5,), (v_lo, v_hi) visited in the window)."""
        return self.run_with_scatter(law, V)[:3]

    def run_with_scatter(self, law: AdhesionLaw, V) -> tuple[Array, Array, Array, Array]:
        """:meth:`run` and the statistics' cycle-to-cycle standard errors over the window
        (:func:`peeljax.measurements.statistics.window_scatter`)."""
        model = eqx.tree_at(lambda m: m.adhesion, self.model, law)
        ode = ConstrainedDAE(model, V) if self.dae else HomogenizedODE(model, V, self.tau)
        t_end = self.transient + self.window
        ts = jnp.linspace(self.transient, t_end, self.n_samples)
        sol = self.integrator.integrate(ode, model.initial_state(V), 0.0, t_end, ts)
        ys = jnp.where(sol.valid[:, None], sol.ys, 1.0)
        F = model.tension(ys[:, 2], ys[:, 0])
        values, available = jump_statistics(sol.jumps, F, self.transient, t_end, taper=self.taper)
        scatter = window_scatter(sol.jumps, self.transient, t_end)
        v = jax.lax.stop_gradient(ys[:, 3])
        return values, available & (sol.status == 0), jnp.stack([jnp.min(v), jnp.max(v)]), scatter

    def statistics(self, theta) -> tuple[Array, Array, Array]:
        """Per row: the model's statistics, which are available, and the v range visited."""
        return self.statistics_with_scatter(theta)[:3]

    def statistics_with_scatter(self, theta) -> tuple[Array, Array, Array, Array]:
        """:meth:`statistics` and each row's cycle-to-cycle standard errors (n, 5)."""
        law = law_from(theta, self.start)
        # One row after another (lax.map), not vmap: under vmap the jump branch of every step
        # (root search, bisection) runs for all rows at every step, measured 20x slower.
        return jax.lax.map(lambda V: self.run_with_scatter(law, V), self.V)

    def residuals(self, theta, args=None) -> Float[Array, " m"]:
        """r(θ): the measured entries of (model − data)/σ, row by row."""
        return self.residuals_and_range(theta)[0]

    def residuals_and_range(self, theta) -> tuple[Float[Array, " m"], Float[Array, "n 2"]]:
        """r(θ) and each row's (v_lo, v_hi) visited in its window (no derivative); σ² is the
        table's plus the model window's cycle-to-cycle scatter (``cycle_scatter``)."""
        values, available, v_range, scatter = self.statistics_with_scatter(theta)
        sigma = jnp.sqrt(self.sigma**2 + jnp.where(self.cycle_scatter, scatter**2, 0.0))
        r = jnp.where(available, (values - self.data) / sigma, MISSING_RESIDUAL)
        return r[self.measured], jax.lax.stop_gradient(v_range)


def build_table_fit(
    start: AdhesionLaw, model: PeelingModel, V, data, sigma, measured, *, names, tau, transient, window,
    n_samples, rtol, atol, max_jumps, max_steps, cycle_scatter=True, taper=0.0,
) -> TableFit:  # fmt: skip
    """The :class:`TableFit` of (n, 5) ``data``/``sigma``/``measured`` arrays at the pull
    velocities ``V``, its rows run with the error-controlled α-method through the folds
    (forward mode: the Jacobian is a tangent per coefficient). Options as :func:`fit_stick_slip`."""
    dae = tau == 0
    integrator = integrator_for(
        None, t_final=transient + window, rtol=rtol, atol=atol, fold="jump", max_jumps=max_jumps,
        max_steps=max_steps, adjoint="forward", dae=dae,
    )  # fmt: skip
    # The statistics read the jump record and F on the equally spaced ts: no rows for the jumps.
    integrator = dataclasses.replace(integrator, save_jumps=False)
    return TableFit(
        start=start, model=model, V=jnp.asarray(V, float), data=jnp.asarray(data, float),
        sigma=jnp.asarray(sigma, float), tau=jnp.asarray(float(tau)), integrator=integrator, names=tuple(names),
        measured=tuple(tuple(int(k) for k in a) for a in np.nonzero(measured)),
        transient=float(transient), window=float(window), n_samples=int(n_samples), dae=dae,
        cycle_scatter=bool(cycle_scatter), taper=float(taper),
    )  # fmt: skip


def table_residuals(fit: TableFit, theta) -> Array:
    """The residual vector r(θ) of a :class:`TableFit` (measured entries only, row-major)."""
    return fit.residuals(theta)
