"""scipy's ``solve_ivp`` (Radau, BDF) with ψ and its exact Jacobian compiled by numba (``numba_peer.compiled_rhs``).

* (P1/P2) :class:`ScipyPeer`: Radau or BDF on y, or on z = (α, ω, u, log v), atol = 1e-2·rtol;
* (P3) :func:`radau_y`: Radau on y for one (V, τ), looped over a few trajectories;
* (P5) :func:`dae_index1_ode`: Radau on the index-1 ODE v' = F̃·f/∂φ/∂v (eq. ``hv`` at τ = 0).
"""

from __future__ import annotations

import numpy as np
from compare_problems import GRID, T_FINAL

from peers import MaybeLog, physical_v
from peers.numba_peer import compiled_rhs


class ScipyPeer(MaybeLog):
    def __init__(self, tau, settings, method, log_v=False):
        self.base_name = f"scipy {method}"
        super().__init__(tau, settings, log_v)
        self.method = method

    def prepare(self):
        from scipy.integrate import solve_ivp

        self._solve_ivp = solve_ivp
        self._rhs, self._jac, self._y0 = compiled_rhs(self.tau, self.log_v)

    def run(self, rtol):
        sol = self._solve_ivp(
            self._rhs,
            (0.0, T_FINAL),
            self._y0,
            method=self.method,
            t_eval=GRID,
            rtol=rtol,
            atol=1e-2 * rtol,
            jac=self._jac,
        )
        v = np.full(GRID.size, np.nan)
        v[: sol.y.shape[1]] = physical_v(sol.y[3], self.log_v)
        return v


def radau_y(Vp, tau, rtol):
    """scipy Radau on y with the compiled ψ and exact Jacobian (as the P1 peer); v on ``GRID``."""
    from scipy.integrate import solve_ivp

    rhs, jac, y0 = compiled_rhs(tau, False, Vp)
    sol = solve_ivp(rhs, (0.0, T_FINAL), y0, method="Radau", t_eval=GRID, rtol=rtol, atol=1e-2 * rtol, jac=jac)
    v = np.full(GRID.size, np.nan)
    v[: sol.y.shape[1]] = sol.y[3]
    return v


def dae_index1_ode(Vp, rtol, method="Radau"):
    """scipy ``method`` on the index-1 ODE v' = F̃·f/∂φ/∂v (eq. ``hv`` at τ = 0)."""
    from peers.compiled_loop import evaluate, initial_state, parameters
    from scipy.integrate import solve_ivp

    p = parameters(Vp, 0.0)
    psi, jac = np.empty(4), np.empty((4, 4))

    def rhs(t, y):
        evaluate(np.asarray(y, dtype=float), p, psi, jac, False)
        return psi.copy()

    def jacobian(t, y):
        evaluate(np.asarray(y, dtype=float), p, psi, jac, True)
        return jac.copy()

    sol = solve_ivp(rhs, (0.0, T_FINAL), initial_state(p), method=method, rtol=rtol, atol=1e-2 * rtol, jac=jacobian)
    finite = np.all(np.isfinite(sol.y), axis=0)
    last = int(np.argmin(finite)) - 1 if not finite.all() else sol.t.size - 1
    return float(sol.t[last]), float(sol.y[3, last]), " ".join(str(sol.message).split())[:60]
