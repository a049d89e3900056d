"""diffrax's implicit Runge–Kutta methods (Kvaerno5, Kvaerno3) on the homogenized ODE in y = (α, ω, u, v).

* (P1/P2) :class:`DiffraxPeer`: ``peeljax.simulate_reference`` with that solver, atol = 1e-2·rtol;
* (P3) :func:`diffrax_vmap`: Kvaerno5 under ``jax.vmap`` over (V, τ), rtol traced (also the P3 reference);
* (P4) :func:`diffrax_loss_of`: Kvaerno5 with ``RecursiveCheckpointAdjoint``, differentiated by ``jax.grad``;
* (P5) :func:`dae_diffrax_index1`: Kvaerno5 on the index-1 ODE (eq. ``hv`` at τ = 0).
"""

from __future__ import annotations

import numpy as np
from compare_problems import GRID, P4_T_FINAL, P4_TAU, P4_TIMES, T_FINAL, V

from peers import Peer
from peers.peeljax_peer import model_of


class DiffraxPeer(Peer):
    def __init__(self, tau, settings, solver_name):
        super().__init__(tau, settings)
        self.solver_name = solver_name
        self.name = f"diffrax {solver_name}"

    def prepare(self):
        import diffrax
        import jax

        import peeljax

        self._jax, self._pj = jax, peeljax
        self._solver = getattr(diffrax, self.solver_name)()

    def setup(self, rtol):
        self.run(rtol)  # compiles

    def run(self, rtol):
        sol = self._pj.simulate_reference(
            V=V, tau=self.tau, dt=T_FINAL / 300, t_final=T_FINAL, solver=self._solver, rtol=rtol, atol=1e-2 * rtol
        )
        return np.asarray(self._jax.block_until_ready(sol.ys))[:, 3]


def diffrax_vmap():
    """diffrax Kvaerno5 under ``jax.vmap`` over (V, τ), rtol traced: one compilation per batch size."""
    import diffrax
    import jax
    import jax.numpy as jnp

    import peeljax

    model, ts = peeljax.PeelingModel(), jnp.asarray(GRID)

    def one(Vp, tau, rtol, atol):
        sol = peeljax.integrate_reference(
            peeljax.HomogenizedODE(model, Vp, tau), model.initial_state(Vp), ts, solver=diffrax.Kvaerno5(),
            rtol=rtol, atol=atol, dtmin=1e-12 * T_FINAL, max_steps=200_000,
        )  # fmt: skip
        return sol.ys[:, 3], sol.status

    batched = jax.jit(jax.vmap(one, in_axes=(0, 0, None, None)))

    def run(Vs, taus, rtol, atol=None):
        atol = 1e-2 * rtol if atol is None else atol
        v, status = jax.block_until_ready(batched(jnp.asarray(Vs), jnp.asarray(taus), rtol, atol))
        return np.asarray(v), np.asarray(status)

    return run


def diffrax_loss_of(v_data):
    """L(c, rtol) by Kvaerno5 on [0, ``P4_T_FINAL``] with ``RecursiveCheckpointAdjoint`` (rtol may be traced)."""
    import diffrax
    import jax.numpy as jnp

    import peeljax

    vd = jnp.asarray(v_data)

    def diffrax_loss(c, rtol):
        model = model_of(c)
        ode = peeljax.HomogenizedODE(model, V, P4_TAU)
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(lambda t, y, args: ode(y)), diffrax.Kvaerno5(), 0.0, P4_T_FINAL, 1e-6 * P4_T_FINAL,
            model.initial_state(V), saveat=diffrax.SaveAt(ts=jnp.asarray(P4_TIMES)),
            stepsize_controller=diffrax.PIDController(rtol=rtol, atol=1e-2 * rtol), max_steps=65_536,
            adjoint=diffrax.RecursiveCheckpointAdjoint(), throw=False,
        )  # fmt: skip
        return jnp.mean((sol.ys[:, 3] - vd) ** 2)

    return diffrax_loss


def dae_diffrax_index1(Vp, rtol):
    """diffrax Kvaerno5 on the index-1 ODE (``truncation=0``), as ``peeljax.simulate_reference``."""
    import peeljax

    sol = peeljax.simulate_reference(
        V=Vp, tau=1.0, dt=T_FINAL / 3000, t_final=T_FINAL, rtol=rtol, atol=1e-2 * rtol, truncation=0
    )
    v = np.asarray(sol.ys)[:, 3]
    last = int(np.sum(np.asarray(sol.valid))) - 1
    return float(sol.t_stop), float(v[max(last, 0)]), sol.status_name
