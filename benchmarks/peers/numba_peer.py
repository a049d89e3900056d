"""The α-method as a numba loop (``compiled_loop.py``), the practical limit, and the compiled ψ of the other peers.

* (P1/P2) :class:`NumbaAlpha`: peeljax's algorithm on a uniform mesh, compiled (solver settings
  read from ``peeljax.AlphaMethod()`` by ``compiled_loop.options_of``);
* :func:`compiled_rhs`: ψ and its exact Jacobian ψ' compiled by numba (``compiled_loop.evaluate_carried``),
  in y = (α, ω, u, v) or z = (α, ω, u, log v): what the scipy and SUNDIALS peers integrate.
"""

from __future__ import annotations

import math

import numpy as np
from compare_problems import T_FINAL, V

from peers import Peer


class NumbaAlpha(Peer):
    name = "numba α-method"
    setting_name = "N"

    def prepare(self):
        from peers.compiled_loop import initial_state, integrate, options_of, parameters

        import peeljax

        self._p = parameters(V, self.tau)
        self._y0 = initial_state(self._p)
        self._options = options_of(peeljax.AlphaMethod())
        self._integrate = integrate

    def setup(self, n):
        self.run(n)  # numba compiles the loop on its first call

    def run(self, n):
        ys, _, _, _status, _ = self._integrate(self._y0, self._p, T_FINAL / n, n, **self._options)
        v = ys[:, 3].copy()
        return v[:: n // 300]


def compiled_rhs(tau, log_v, Vp=V):
    """Compiled ψ and ψ' in y = (α, ω, u, v), or in z = (α, ω, u, log v) when ``log_v``; (rhs, jacobian, y0)."""
    from peers.compiled_loop import evaluate_carried, initial_state, parameters

    p = parameters(Vp, tau)
    psi = np.empty(4)
    jac = np.empty((4, 4))
    yy = np.empty(4)

    def rhs(t, y, out=None):
        out = psi if out is None else out
        evaluate_carried(np.asarray(y, dtype=float), log_v, p, out, jac, yy, False)
        return out.copy()

    def jacobian(t, y, out=None):
        out = jac if out is None else out
        evaluate_carried(np.asarray(y, dtype=float), log_v, p, psi, out, yy, True)
        return out.copy()

    y0 = initial_state(p)
    if log_v:
        y0[3] = math.log(y0[3])
    return rhs, jacobian, y0
