"""peeljax itself, the row every ratio of ``compare.py`` is taken against.

* (P1/P2) :class:`PeeljaxAlpha`: the α-method on a uniform mesh (``peeljax.simulate``, h = 3/N);
  :class:`PeeljaxAdaptive`: the error-controlled α-method (``simulate(dt=None, rtol, atol=1e-3·rtol,
  ts=GRID)``: PI controller on the estimate C·h²·(a_{n+1} − a_n), Hermite dense output);
* (P3) :func:`peeljax_batch` (``peeljax.sweep`` on a uniform mesh) and :func:`peeljax_batch_adaptive`
  (``peeljax.sweep`` with error control, v saved at ``GRID`` by ``save_dt``);
* (P4) :func:`alpha_loss_of` (``integrate_alpha`` on N steps) and :func:`adaptive_alpha_loss`
  (``simulate(…, rtol=…, ts=P4_TIMES)``), differentiated by ``jax.grad``.
"""

from __future__ import annotations

import numpy as np
from compare_problems import (
    ADAPTIVE_ALPHA_ATOL, COEFFICIENT_NAMES, GRID, P3_SAVE_DT, P4_T_FINAL, P4_TAU, P4_TIMES, T_FINAL, V
)  # fmt: skip

from peers import Peer


class PeeljaxAlpha(Peer):
    name = "peeljax α-method"
    setting_name = "N"

    def prepare(self):
        import jax

        import peeljax

        self._jax, self._pj = jax, peeljax

    def setup(self, n):
        self.run(n)  # the mesh size is static: one compilation per N

    def run(self, n):
        sol = self._pj.simulate(V=V, tau=self.tau, dt=T_FINAL / n, t_final=T_FINAL)
        v = np.asarray(self._jax.block_until_ready(sol.ys))[:, 3]
        return v[:: n // 300]


class PeeljaxAdaptive(Peer):
    """The error-controlled α-method: ``peeljax.simulate(dt=None, rtol, atol, ts=GRID)``.

    atol = 1e-3·rtol (the error of α, ω, u is then mostly relative; log v is weighted by rtol
    alone in any case), which gives a clean second-order work-precision curve. The last run's
    ``stats`` per setting are kept (device arrays, read only when the results are collected).
    """

    name = "peeljax adaptive α"
    setting_name = "rtol"

    def prepare(self):
        import jax

        import peeljax

        self._jax, self._pj = jax, peeljax
        self.stats = {}

    def setup(self, rtol):
        self.run(rtol)  # compiles once (rtol is traced: later settings find the program compiled)

    def run(self, rtol):
        sol = self._pj.simulate(
            V=V, tau=self.tau, t_final=T_FINAL, rtol=rtol, atol=ADAPTIVE_ALPHA_ATOL * rtol, ts=GRID, solver="alpha"
        )  # (named: the default for τ > 0 switches to Tsit5 where it can, benchmarks/switching.py)
        v = np.asarray(self._jax.block_until_ready(sol.ys))[:, 3]  # NaN after a stop
        self.stats[rtol] = sol.stats
        return v

    def run_stats(self, rtol):
        stats = getattr(self, "stats", {})
        if rtol not in stats:
            return None
        return {k: int(stats[rtol][k]) for k in ("accepted_steps", "rejected_steps", "newton_iterations")}

    def info(self):
        return {"stats": "adaptive"}


def peeljax_batch(Vs, taus, n):
    """``peeljax.sweep`` on a uniform mesh of n steps, states kept at ``GRID`` (every n/300 steps); (v, status)."""
    import peeljax

    result = peeljax.sweep(
        None, Vs, taus, T_FINAL / n, T_FINAL, grid="pairs", save_every=n // (GRID.size - 1), progress=False
    )
    return result.ys[:, :, 3], result.status


def peeljax_batch_adaptive(Vs, taus, rtol, rho=0.0, atol_factor=ADAPTIVE_ALPHA_ATOL):
    """``peeljax.sweep`` with error control (default devices and lane_batch), v at ``GRID``, atol =
    ``atol_factor``·rtol; (v, status, accepted steps, rejected steps)."""
    import peeljax

    result = peeljax.sweep(
        None, Vs, taus, None, T_FINAL, rtol=rtol, atol=atol_factor * rtol, save_dt=P3_SAVE_DT,
        grid="pairs", progress=False, rho=rho, solver="alpha",
    )  # fmt: skip
    return result.ys[:, :, 3], result.status, result.accepted_steps, result.rejected_steps


def model_of(c):
    """``peeljax.PeelingModel`` with φ's 14 coefficients ``c`` (in ``COEFFICIENT_NAMES`` order)."""
    import peeljax

    law = peeljax.AdhesionLaw(**{name: c[i] for i, name in enumerate(COEFFICIENT_NAMES)})
    return peeljax.PeelingModel(adhesion=law)


def alpha_loss_of(v_data):
    """L(c, n) of the α-method on n uniform steps on [0, ``P4_T_FINAL``] (``integrate_alpha``); (L, status)."""
    import jax.numpy as jnp

    import peeljax
    from peeljax.integrators.uniform_mesh import integrate_alpha

    vd = jnp.asarray(v_data)

    def alpha_loss(c, n):
        model = model_of(c)
        ode = peeljax.HomogenizedODE(model, V, P4_TAU)
        sol = integrate_alpha(ode, peeljax.AlphaMethod(), model.initial_state(V), 0.0, P4_T_FINAL, n)
        v = jnp.where(sol.valid, sol.ys[:, 3], 0.0)[:: n // (P4_TIMES.size - 1)]  # the double where of fit.py
        return jnp.mean((v - vd) ** 2), sol.status

    return alpha_loss


def adaptive_alpha_loss(v_data):
    """L(c, rtol) through ``peeljax.simulate(model, …, rtol=rtol, atol=1e-3·rtol, ts=P4_TIMES)``
    (the error-controlled α-method, dense output at the data times; ``adjoint="reverse"``, the
    default: ``jax.grad`` through its checkpointed while loop). rtol is a Python number: one
    compilation per rtol. Returns (L, status)."""
    import jax.numpy as jnp

    import peeljax

    vd = jnp.asarray(v_data)

    def loss(c, rtol):
        sol = peeljax.simulate(
            model_of(c), V=V, tau=P4_TAU, t_final=P4_T_FINAL, rtol=rtol, atol=ADAPTIVE_ALPHA_ATOL * rtol, ts=P4_TIMES,
            solver="alpha",
        )  # fmt: skip
        # Under jit the rows are the output times' and room for the jumps' sides, in time order:
        # P4 (τ = 0.1) has no jump, so its output times' rows come first (a jump would make L NaN).
        rows = vd.shape[0]
        v = jnp.where(sol.valid[:rows], sol.ys[:rows, 3], 0.0)
        loss = jnp.where(sol.jumps.count == 0, jnp.mean((v - vd) ** 2), jnp.nan)
        return loss, sol.status

    return loss
