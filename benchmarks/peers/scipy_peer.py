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
        self._compiled = compiled_rhs(self.tau, self.log_v)

    def run(self, rtol):
        return _v_on_grid(self._compiled, self.method, rtol, self.log_v)


def _v_on_grid(compiled, method, rtol, log_v):
    """v on ``GRID`` (NaN after a stop) by ``solve_ivp`` on ``compiled_rhs``'s (rhs, jacobian, y0), atol = 1e-2·rtol."""
    from scipy.integrate import solve_ivp

    rhs, jac, y0 = compiled
    sol = solve_ivp(rhs, (0.0, T_FINAL), y0, method=method, t_eval=GRID, rtol=rtol, atol=1e-2 * rtol, jac=jac)
    v = np.full(GRID.size, np.nan)
    v[: sol.y.shape[1]] = physical_v(sol.y[3], log_v)
    return v


def radau_y(Vp, tau, rtol):
    """scipy Radau on y with the compiled ψ and exact Jacobian (as the P1 peer); v on ``GRID``."""
    return _v_on_grid(compiled_rhs(tau, False, Vp), "Radau", rtol, False)


def dae_index1_ode(Vp, rtol, method="Radau"):
    """scipy ``method`` on the index-1 ODE v' = F̃·f/∂φ/∂v (eq. ``hv`` at τ = 0)."""
    from scipy.integrate import solve_ivp

    rhs, jacobian, y0 = compiled_rhs(0.0, False, Vp)  # τ = 0: ψ is the index-1 ODE
    sol = solve_ivp(rhs, (0.0, T_FINAL), y0, method=method, rtol=rtol, atol=1e-2 * rtol, jac=jacobian)
    finite = np.all(np.isfinite(sol.y), axis=0)
    last = int(np.argmin(finite)) - 1 if not finite.all() else sol.t.size - 1
    return float(sol.t[last]), float(sol.y[3, last]), " ".join(str(sol.message).split())[:60]
