"""CasADi: ψ built from CasADi symbols (with its own automatic Jacobian) for its SUNDIALS integrators.

* (P1/P2) :class:`CasadiPeer`: cvodes on y, or on z = (α, ω, u, log v), atol = 1e-2·rtol; one
  integrator per rtol, built by ``setup`` outside the timed call;
* (P3) :class:`CasadiBatch`: cvodes on z, one integrator with (V, τ) as parameters, called per trajectory;
* (P4) :class:`CasadiLoss`: the loss by cvodes on z and its gradient from the forward sensitivities
  (also the reference gradient at rtol 1e-11 and the data, :func:`p4_data`);
* (P5) :func:`dae_casadi_idas`: idas on the direct DAE with v algebraic.
"""

from __future__ import annotations

import math

import numpy as np
from compare_problems import COEFFICIENT_NAMES, GRID, P4_TAU, P4_TIMES, PAPER_PHI, T_FINAL, V
from machine import timed

from peers import MaybeLog, physical_v


def casadi_parametric(log_v=True):
    """ψ of eq. ``hv`` as CasADi symbols with parameters P = (V, τ, φ's 14 coefficients).

    Returns (state symbol, P, ψ, a Function P ↦ the paper's initial state); in z = (α, ω, u, log v)
    when ``log_v``. The initial state depends on φ through u0 (from (sac)), so derivatives
    with respect to the coefficients include that dependence.
    """
    import casadi as ca

    R, I, K = 0.1, 1e-2, 1000.0
    Vp, tau, c = ca.SX.sym("V"), ca.SX.sym("tau"), ca.SX.sym("c", len(COEFFICIENT_NAMES))
    C = {name: c[i] for i, name in enumerate(COEFFICIENT_NAMES)}
    y = ca.SX.sym("y", 4)
    al, om, u, v = y[0], y[1], y[2], y[3]
    x = y[:3]
    slip = om - v / R
    f = ca.vertcat(slip, -R * K * u * ca.sin(al) / I, R * ca.sin(al) * slip + Vp - v)
    G = (1 + ca.sin(al)) * K * u

    def safe_pow(a, p):  # peeljax's policy: v^p := 0 for v ≤ 0
        return ca.if_else(a > 0, ca.fmax(a, 1e-300) ** p, 0)

    def phi(v):
        C6 = C["c6"] - C["c7"] * Vp ** C["p7"] - C["c8"] * Vp ** C["p8"]
        return (C["c1"] * safe_pow(v, C["p1"]) + C["c2"] * safe_pow(v, C["p2"]) + C["c3"] * ca.exp(v / C["c4"])
                - C["c5"] * Vp ** C["p5"] - C6 * safe_pow(v, C["p9"]))  # fmt: skip

    f_x, f_v = ca.jacobian(f, x), ca.jacobian(f, v)
    F_tilde, phi_v = ca.jacobian(G, x), ca.jacobian(phi(v), v)
    w = ca.solve(ca.SX.eye(3) - tau * f_x, f_v)
    J = -phi_v + tau * ca.mtimes(F_tilde, w)
    psi = ca.vertcat(f, -ca.mtimes(F_tilde, f) / J)
    P = ca.vertcat(Vp, tau, c)
    v0, al0 = 1e-10 * Vp, 0.25 * math.pi * 1e-8
    y0 = ca.vertcat(al0, v0 / R, phi(v0) / (1 + math.sin(al0)) / K, v0)
    if not log_v:
        return y, P, psi, ca.Function("y0", [P], [y0])
    psi_of = ca.Function("psi", [y, P], [psi])
    z = ca.SX.sym("z", 4)
    ez = ca.exp(z[3])
    psi_z = psi_of(ca.vertcat(z[:3], ez), P)
    return z, P, ca.vertcat(psi_z[:3], psi_z[3] / ez), ca.Function("z0", [P], [ca.vertcat(y0[:3], ca.log(y0[3]))])


def casadi_psi(tau, log_v=False):
    """ψ of eq. ``hv`` (paper geometry, the paper's φ) as CasADi symbols (in z when ``log_v``):
    :func:`casadi_parametric` with V, τ and φ's coefficients substituted."""
    import casadi as ca

    y, P, psi, _ = casadi_parametric(log_v)
    return y, ca.substitute(psi, P, ca.SX(ca.DM([V, tau, *PAPER_PHI])))


def cvodes_on_grid(ca, dae, rtol):
    """CasADi's cvodes integrator of ``dae`` from 0 to the times of ``GRID``, atol = 1e-2·rtol."""
    options = {"abstol": 1e-2 * rtol, "reltol": rtol, "max_num_steps": 200_000, "print_stats": False}
    return ca.integrator("F", "cvodes", dae, 0.0, GRID[1:], options)


class CasadiPeer(MaybeLog):
    base_name = "CasADi cvodes"

    def prepare(self):
        import casadi as ca
        from peers.compiled_loop import initial_state, parameters

        self._ca = ca
        self._y, self._psi = casadi_psi(self.tau, self.log_v)
        self._y0 = initial_state(parameters(V, self.tau))
        if self.log_v:
            self._y0[3] = math.log(self._y0[3])

        self._integrators = {}

    def setup(self, rtol):
        """CasADi's integrator for ``rtol``, built once: its construction is set-up, not the run."""
        self._integrators[rtol] = cvodes_on_grid(self._ca, {"x": self._y, "ode": self._psi}, rtol)

    def run(self, rtol):
        out = self._integrators[rtol](x0=self._y0)
        xf = np.asarray(out["xf"])
        return physical_v(np.concatenate([[self._y0[3]], xf[3]]), self.log_v)


class CasadiBatch:
    """CasADi cvodes on z = (α, ω, u, log v), one integrator with (V, τ) as parameters, called per trajectory.

    ``setup(rtol)`` builds the integrator for ``rtol`` once, outside the timed calls (its time is
    kept in ``setup_seconds``); ``batch(V, τ, rtol)`` only calls it.
    """

    def __init__(self):
        import casadi as ca

        self._ca = ca
        self._z, self._P, self._psi, self._z0 = casadi_parametric(log_v=True)
        self._integrators = {}
        self.setup_seconds = {}

    def setup(self, rtol):
        if rtol not in self._integrators:
            dae = {"x": self._z, "p": self._P, "ode": self._psi}
            self._integrators[rtol], self.setup_seconds[rtol] = timed(cvodes_on_grid, self._ca, dae, rtol)

    def __call__(self, Vp, tau, rtol):
        from peers.compiled_loop import initial_state, parameters

        z0 = initial_state(parameters(Vp, tau))
        z0[3] = math.log(z0[3])
        try:
            xf = np.asarray(self._integrators[rtol](x0=z0, p=[Vp, tau, *PAPER_PHI])["xf"])
        except RuntimeError:  # CasADi raises when CVODES fails; the trajectory counts as stopped
            return np.full(GRID.size, np.nan)
        return np.exp(np.concatenate([[z0[3]], xf[3]]))


class CasadiLoss:
    """L(c) = mean over ``P4_TIMES`` of (v − v_data)² by CasADi cvodes on z = (α, ω, u, log v).

    ``gradient`` takes dL/dc from the forward sensitivities dv(t_i)/dc (14 directions:
    ``casadi.jtimes`` with the identity as seeds, i.e. forward mode, the integrator's forward
    sensitivity equations), including the dependence of the initial state on c.
    """

    def __init__(self, rtol, v_data=None):
        import casadi as ca

        z, P, psi, z0 = casadi_parametric(log_v=True)
        options = {"abstol": 1e-2 * rtol, "reltol": rtol, "max_num_steps": 200_000, "print_stats": False}
        integrator = ca.integrator("F", "cvodes", {"x": z, "p": P, "ode": psi}, 0.0, P4_TIMES[1:], options)
        c = ca.MX.sym("c", len(COEFFICIENT_NAMES))
        Pc = ca.vertcat(V, P4_TAU, c)
        v = ca.exp(integrator(x0=z0(Pc), p=Pc)["xf"][3, :]).T  # v at P4_TIMES[1:]; v(0) = 1e-10·V is fixed
        self.trajectory = ca.Function("v", [c], [v])
        if v_data is None:
            return
        r = v - v_data[1:]
        n = P4_TIMES.size
        L = (ca.sumsqr(r) + (1e-10 * V - v_data[0]) ** 2) / n
        dv_dc = ca.jtimes(v, c, ca.MX.eye(len(COEFFICIENT_NAMES)))  # forward mode: 14 seeds
        self.loss = ca.Function("L", [c], [L])
        self.gradient = ca.Function("dL", [c], [L, ca.mtimes(dv_dc.T, 2 * r) / n])

    def value_and_grad(self, c):
        L, g = self.gradient(c)
        return float(L), np.asarray(g).ravel()

    def value(self, c):
        return float(self.loss(c))


def p4_data():
    """v_data at ``P4_TIMES``: the paper's φ, CasADi cvodes at rtol 1e-11 (log v)."""
    v = np.asarray(CasadiLoss(1e-11).trajectory(np.array(PAPER_PHI))).ravel()
    return np.concatenate([[1e-10 * V], v])


def dae_casadi_idas(Vp, rtol):
    """CasADi's IDAS on the same DAE with v algebraic; returns (t_stop, v there, message)."""
    import casadi as ca
    from peers.compiled_loop import initial_state, parameters

    R, I, K, _, _, c1, p1, c2, p2, c3, c4, C6, p9 = parameters(Vp, 0.0)
    x = ca.SX.sym("x", 3)
    v = ca.SX.sym("v")
    al, om, u = x[0], x[1], x[2]
    slip = om - v / R
    ode = ca.vertcat(slip, -R * K * u * ca.sin(al) / I, R * ca.sin(al) * slip + Vp - v)
    w = ca.fmax(v, 1e-300)
    phi = c1 * w**p1 + c2 * w**p2 + c3 * ca.exp(v / c4) - 2.0 * Vp**1.5 - C6 * w**p9
    alg = (1 + ca.sin(al)) * K * u - phi
    y0 = initial_state(parameters(Vp, 0.0))
    grid = np.linspace(0.0, T_FINAL, 3001)[1:]
    options = {"abstol": 1e-2 * rtol, "reltol": rtol, "max_num_steps": 100_000}
    integrator = ca.integrator("F", "idas", {"x": x, "z": v, "ode": ode, "alg": alg}, 0.0, grid, options)
    # Integrate output interval by output interval so that a failure tells where it happened.
    t_last, v_last, message = 0.0, float(y0[3]), "completed"
    x0, z0 = y0[:3], y0[3]
    for t_end in np.linspace(0.0, T_FINAL, 61)[1:]:
        step = ca.integrator("F", "idas", {"x": x, "z": v, "ode": ode, "alg": alg}, t_last, [t_end], options)
        try:
            out = step(x0=x0, z0=z0)
        except RuntimeError as error:
            message = " ".join(str(error).split()[-12:])[:60]
            break
        x0, z0 = np.asarray(out["xf"]).ravel(), float(np.asarray(out["zf"]).ravel()[0])
        t_last, v_last = float(t_end), z0
    del integrator, grid
    return t_last, v_last, message
