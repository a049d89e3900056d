"""SUNDIALS through scikit-sundae: CVODE (BDF, dense) with the compiled ψ and ψ', and IDA on the direct DAE.

* (P1/P2) :class:`CvodePeer`: CVODE on y, or on z = (α, ω, u, log v), atol = 1e-2·rtol;
* (P3) :class:`CvodeBatch`: CVODE on z, one solver object per rtol (built outside the timing), looped over (V, τ);
* (P5) :func:`dae_ida`: IDA on the semi-explicit index-1 DAE x' = f, 0 = G − φ (v algebraic).
"""

from __future__ import annotations

import math

import numpy as np
from compare_problems import GRID, T_FINAL, V
from machine import timed

from peers import MaybeLog, physical_v
from peers.numba_peer import compiled_rhs


def cvode_of(p, log_v):
    """rtol ↦ CVODE (BDF, atol = 1e-2·rtol) with the compiled ψ and ψ' at the parameter vector ``p``
    (read at every call), in z = (α, ω, u, log v) when ``log_v``."""
    from peers.compiled_loop import evaluate_carried
    from sksundae.cvode import CVODE

    psi, yy, scratch = np.empty(4), np.empty(4), np.empty((4, 4))

    def rhsfn(t, y, yp):  # SUNDIALS' own arrays: y read-only, yp the output
        evaluate_carried(y, log_v, p, yp, scratch, yy, False)

    def jacfn(t, y, yp, JJ):
        evaluate_carried(y, log_v, p, psi, JJ, yy, True)

    return lambda rtol: CVODE(rhsfn, jacfn=jacfn, method="BDF", rtol=rtol, atol=1e-2 * rtol, max_num_steps=200_000)


class CvodePeer(MaybeLog):
    base_name = "SUNDIALS CVODE (BDF)"

    def prepare(self):
        from peers.compiled_loop import parameters

        _, _, self._y0 = compiled_rhs(self.tau, self.log_v)
        self._make = cvode_of(parameters(V, self.tau), self.log_v)
        self._solvers = {}

    def setup(self, rtol):
        """The solver object for ``rtol``, built once (``solve`` re-initializes it: the same answer each call)."""
        self._solvers[rtol] = self._make(rtol)

    def run(self, rtol):
        sol = self._solvers[rtol].solve(GRID, self._y0)
        v = np.full(GRID.size, np.nan)
        y = np.asarray(sol.y)
        v[: y.shape[0]] = physical_v(y[:, 3], self.log_v)
        return v


class CvodeBatch:
    """SUNDIALS CVODE (BDF) on z = (α, ω, u, log v), compiled ψ and ψ' (as the P1 peer), looped over (V, τ).

    One solver object per rtol, built by ``setup`` outside the timed calls (its time kept in
    ``setup_seconds``); a call writes its
    (V, τ) into the parameter vector the callbacks read, then ``solve`` re-initializes the solver.
    Called as ``batch(V, τ, rtol)``: v on ``GRID`` (NaN after a stop).
    """

    def __init__(self):
        from peers.compiled_loop import parameters

        self._p = np.array(parameters(V, 0.01), dtype=float)
        self._make = cvode_of(self._p, True)
        self._solvers = {}
        self.setup_seconds = {}

    def setup(self, rtol):
        if rtol not in self._solvers:
            self._solvers[rtol], self.setup_seconds[rtol] = timed(self._make, rtol)

    def __call__(self, Vp, tau, rtol):
        from peers.compiled_loop import initial_state, parameters

        self._p[:] = parameters(Vp, tau)
        z0 = initial_state(self._p)
        z0[3] = math.log(z0[3])
        y = np.asarray(self._solvers[rtol].solve(GRID, z0).y)
        v = np.full(GRID.size, np.nan)
        v[: y.shape[0]] = np.exp(y[:, 3])
        return v


def dae_functions(Vp):
    """f(x, v), G(x) − φ(v, V) of the DAE (paper geometry, the paper's φ) in plain Python."""
    from peers.compiled_loop import parameters

    R, I, K, _, _, c1, p1, c2, p2, c3, c4, C6, p9 = parameters(Vp, 0.0)
    c5, p5 = 2.0, 1.5

    def phi(v):
        w = max(v, 0.0)  # peeljax's policy: v^p := 0 for v ≤ 0
        return c1 * w**p1 + c2 * w**p2 + c3 * math.exp(v / c4) - c5 * Vp**p5 - C6 * w**p9

    def f(al, om, u, v):
        slip = om - v / R
        return slip, -R * K * u * math.sin(al) / I, R * math.sin(al) * slip + Vp - v

    def g(al, u, v):
        return (1 + math.sin(al)) * K * u - phi(v)

    return f, g


def dae_ida(Vp, rtol):
    """SUNDIALS IDA on the semi-explicit index-1 DAE (x' = f, 0 = G − φ); returns (t_stop, v there, message)."""
    from peers.compiled_loop import initial_state, parameters
    from sksundae.ida import IDA

    f, g = dae_functions(Vp)
    y0 = initial_state(parameters(Vp, 0.0))
    yp0 = np.array([*f(*y0), 0.0])

    def resfn(t, y, yp, res):
        fx = f(y[0], y[1], y[2], y[3])
        res[0], res[1], res[2] = yp[0] - fx[0], yp[1] - fx[1], yp[2] - fx[2]
        res[3] = g(y[0], y[2], y[3])

    solver = IDA(resfn, algebraic_idx=[3], rtol=rtol, atol=1e-2 * rtol, max_num_steps=100_000)
    sol = solver.solve(np.array([0.0, T_FINAL]), y0, yp0)
    t = np.asarray(sol.t)
    y = np.asarray(sol.y)
    return float(t[-1]), float(y[-1, 3]), " ".join(str(getattr(sol, "message", "")).split())[:60]
