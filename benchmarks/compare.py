"""peeljax against the solvers people would use instead, on this very problem.

Problems (V = 1.1, paper geometry and initial data, t ∈ [0, 3 s]):

* (P1) one trajectory at τ = 0.01 and τ = 0.1: for each method, the cheapest setting whose
  error in v is at most ``TARGET`` (1e-3), its median time, and that time divided by
  peeljax's at the same target;
* (P2) work-precision: wall time against the error in v (max over the 301 times
  0, 0.01, …, 3 s) relative to a tight reference (diffrax Kvaerno5, rtol 1e-11), over a range
  of tolerances (adaptive peers) or steps (α-methods); ``results/work_precision.png``.

Peers (each one's answer is checked against the reference before it is timed; a run that
reports success but misses the reference by more than 10 % of max|v|, or an adaptive run off
by more than max(1e3·rtol, 1e-4)·max|v|, is reported as a wrong answer and not timed):

* ``peeljax``: the α-method (``peeljax.simulate``), h = 3/N, N ∈ {300, 600, …};
* ``numba α``: the same algorithm as a compiled loop (``compiled_loop.py``), the practical limit;
* ``diffrax Kvaerno5``, ``diffrax Kvaerno3``: ``peeljax.simulate_reference`` with that solver;
* ``scipy Radau``, ``scipy BDF``: ``solve_ivp`` with ψ and its exact Jacobian compiled by
  numba (``compiled_loop.evaluate``);
* ``CVODE``: SUNDIALS CVODE (BDF, dense) through scikit-sundae, same compiled ψ and Jacobian;
* ``CasADi cvodes``: CasADi's CVODES integrator on ψ built from CasADi symbols, with its own
  automatic Jacobian;
* the SUNDIALS, scipy BDF and CasADi peers also run on z = (α, ω, u, log v) ("(log v)"), the
  coordinates peeljax discretises: on y they stumble over the non-Lipschitz start v0 = 1e-10·V.

(P5) the direct DAE at V = 1.1, 2, 4: where SUNDIALS IDA, CasADi idas (v algebraic), scipy
Radau and diffrax Kvaerno5 on the index-1 ODE (eq. ``hv`` at τ = 0) stop, per tolerance.

All peers integrate the homogenized ODE (eq. ``hv``) in the physical state (α, ω, u, v);
peeljax and the numba loop discretise (α, ω, u, log v) (``AlphaMethod.log_discretization``).

    python benchmarks/compare.py            # full: ~5 min on 2 cores
    python benchmarks/compare.py --quick    # ~1 min: τ = 0.01 only, fewer settings and repeats

Writes ``benchmarks/results/latest.md`` (``latest_quick.md`` with ``--quick``) and the plot.
Times are medians of repeated runs after a warm-up run, measured round-robin so that load on
the shared machine hits every peer alike. Nothing here is asserted by a test except that the
script runs (``tests/test_compare_script.py``).
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from machine import cpu_model  # noqa: E402

V = 1.1
T_FINAL = 3.0
GRID = np.linspace(0.0, T_FINAL, 301)
TARGET = 1e-3
REF_RTOL, REF_ATOL = 1e-11, 1e-13


# --------------------------------------------------------------------------- peers
class Peer:
    """A method with a list of settings; ``run(setting)`` returns v on ``GRID`` (NaN after a stop)."""

    name = ""
    setting_name = "rtol"

    def __init__(self, tau: float, settings):
        self.tau = tau
        self.settings = list(settings)

    def prepare(self) -> None:
        """Compile or build whatever the runs need (outside the timed region)."""

    def run(self, setting) -> np.ndarray:
        raise NotImplementedError


class PeeljaxAlpha(Peer):
    name = "peeljax α-method"
    setting_name = "N"

    def prepare(self):
        import jax

        import peeljax

        self._jax, self._pj = jax, peeljax

    def run(self, n):
        sol = self._pj.simulate(V=V, tau=self.tau, dt=T_FINAL / n, t_final=T_FINAL)
        v = np.asarray(self._jax.block_until_ready(sol.ys))[:, 3]
        return v[:: n // 300]


class NumbaAlpha(Peer):
    name = "numba α-method"
    setting_name = "N"

    def prepare(self):
        import peeljax
        from compiled_loop import initial_state, integrate, options_of, parameters

        self._p = parameters(V, self.tau)
        self._y0 = initial_state(self._p)
        self._options = options_of(peeljax.AlphaMethod())
        self._integrate = integrate

    def run(self, n):
        ys, _, _, status, _ = self._integrate(self._y0, self._p, T_FINAL / n, n, **self._options)
        v = ys[:, 3].copy()
        return v[:: n // 300]


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

    def run(self, rtol):
        sol = self._pj.simulate_reference(
            V=V, tau=self.tau, dt=T_FINAL / 300, t_final=T_FINAL, solver=self._solver, rtol=rtol, atol=1e-2 * rtol
        )
        return np.asarray(self._jax.block_until_ready(sol.ys))[:, 3]


def _numba_rhs(tau, log_v):
    """Compiled ψ and ψ' in y = (α, ω, u, v), or in z = (α, ω, u, log v) when ``log_v``."""
    from compiled_loop import evaluate_carried, initial_state, parameters

    p = parameters(V, tau)
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


def _physical_v(v, log_v):
    return np.exp(v) if log_v else v


class _MaybeLog(Peer):
    """A peer that integrates y, or z = (α, ω, u, log v) when ``log_v`` (v > 0 by construction)."""

    base_name = ""

    def __init__(self, tau, settings, log_v=False):
        super().__init__(tau, settings)
        self.log_v = log_v
        self.name = self.base_name + (" (log v)" if log_v else "")


class ScipyPeer(_MaybeLog):
    def __init__(self, tau, settings, method, log_v=False):
        self.base_name = f"scipy {method}"
        super().__init__(tau, settings, log_v)
        self.method = method

    def prepare(self):
        from scipy.integrate import solve_ivp

        self._solve_ivp = solve_ivp
        self._rhs, self._jac, self._y0 = _numba_rhs(self.tau, self.log_v)

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
        v[: sol.y.shape[1]] = _physical_v(sol.y[3], self.log_v)
        return v


class CvodePeer(_MaybeLog):
    base_name = "SUNDIALS CVODE (BDF)"

    def prepare(self):
        from compiled_loop import evaluate_carried, parameters
        from sksundae.cvode import CVODE

        _, _, self._y0 = _numba_rhs(self.tau, self.log_v)
        p = parameters(V, self.tau)
        psi, yy, scratch, log_v = np.empty(4), np.empty(4), np.empty((4, 4)), self.log_v

        def rhsfn(t, y, yp):  # SUNDIALS' own arrays: y read-only, yp the output
            evaluate_carried(y, log_v, p, yp, scratch, yy, False)

        def jacfn(t, y, yp, JJ):
            evaluate_carried(y, log_v, p, psi, JJ, yy, True)

        self._make = lambda rtol: CVODE(
            rhsfn, jacfn=jacfn, method="BDF", rtol=rtol, atol=1e-2 * rtol, max_num_steps=200_000
        )

    def run(self, rtol):
        sol = self._make(rtol).solve(GRID, self._y0)
        v = np.full(GRID.size, np.nan)
        y = np.asarray(sol.y)
        v[: y.shape[0]] = _physical_v(y[:, 3], self.log_v)
        return v


def casadi_psi(tau, log_v=False):
    """ψ of eq. ``hv`` (paper geometry, the paper's φ) as CasADi symbols (in z when ``log_v``)."""
    import casadi as ca
    from compiled_loop import parameters

    R, I, K, Vp, tau_, c1, p1, c2, p2, c3, c4, C6, p9 = parameters(V, tau)
    c5, p5 = 2.0, 1.5
    y = ca.SX.sym("y", 4)
    al, om, u, v = y[0], y[1], y[2], y[3]
    x = y[:3]
    slip = om - v / R
    f = ca.vertcat(slip, -R * K * u * ca.sin(al) / I, R * ca.sin(al) * slip + Vp - v)
    G = (1 + ca.sin(al)) * K * u

    def safe_pow(x, p):  # peeljax's policy: v^p := 0 for v ≤ 0 (the solver may try v < 0)
        return ca.if_else(x > 0, ca.fmax(x, 1e-300) ** p, 0)

    phi = c1 * safe_pow(v, p1) + c2 * safe_pow(v, p2) + c3 * ca.exp(v / c4) - c5 * Vp**p5 - C6 * safe_pow(v, p9)
    f_x, f_v = ca.jacobian(f, x), ca.jacobian(f, v)
    F_tilde, phi_v = ca.jacobian(G, x), ca.jacobian(phi, v)
    w = ca.solve(ca.SX.eye(3) - tau * f_x, f_v)
    J = -phi_v + tau * ca.mtimes(F_tilde, w)
    psi = ca.vertcat(f, -ca.mtimes(F_tilde, f) / J)
    if not log_v:
        return y, psi
    psi_of_y = ca.Function("psi", [y], [psi])
    z = ca.SX.sym("z", 4)
    v = ca.exp(z[3])
    psi_z = psi_of_y(ca.vertcat(z[:3], v))
    return z, ca.vertcat(psi_z[:3], psi_z[3] / v)


class CasadiPeer(_MaybeLog):
    base_name = "CasADi cvodes"

    def prepare(self):
        import casadi as ca
        from compiled_loop import initial_state, parameters

        self._ca = ca
        self._y, self._psi = casadi_psi(self.tau, self.log_v)
        self._y0 = initial_state(parameters(V, self.tau))
        if self.log_v:
            self._y0[3] = math.log(self._y0[3])

    def _integrator(self, rtol):
        options = {"abstol": 1e-2 * rtol, "reltol": rtol, "max_num_steps": 200_000, "print_stats": False}
        return self._ca.integrator("F", "cvodes", {"x": self._y, "ode": self._psi}, 0.0, GRID[1:], options)

    def run(self, rtol):
        integrator = self._integrator(rtol)
        out = integrator(x0=self._y0)
        xf = np.asarray(out["xf"])
        return _physical_v(np.concatenate([[self._y0[3]], xf[3]]), self.log_v)


# --------------------------------------------------------------------------- (P5) the direct DAE
def _dae_functions(Vp):
    """f(x, v), G(x) − φ(v, V) of the DAE (paper geometry, the paper's φ) in plain Python."""
    from compiled_loop import parameters

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
    from compiled_loop import initial_state, parameters
    from sksundae.ida import IDA

    f, g = _dae_functions(Vp)
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


def dae_casadi_idas(Vp, rtol):
    """CasADi's IDAS on the same DAE with v algebraic; returns (t_stop, v there, message)."""
    import casadi as ca
    from compiled_loop import initial_state, parameters

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


def dae_index1_ode(Vp, rtol, method="Radau"):
    """scipy ``method`` on the index-1 ODE v' = F̃·f/∂φ/∂v (eq. ``hv`` at τ = 0)."""
    from compiled_loop import evaluate, initial_state, parameters
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


def dae_diffrax_index1(Vp, rtol):
    """diffrax Kvaerno5 on the index-1 ODE (``truncation=0``), as ``peeljax.simulate_reference``."""
    import peeljax

    sol = peeljax.simulate_reference(
        V=Vp, tau=1.0, dt=T_FINAL / 3000, t_final=T_FINAL, rtol=rtol, atol=1e-2 * rtol, truncation=0
    )
    v = np.asarray(sol.ys)[:, 3]
    last = int(np.sum(np.asarray(sol.valid))) - 1
    return float(sol.t_stop), float(v[max(last, 0)]), sol.status_name


def direct_dae_table(emit, velocities, rtols):
    emit("## (P5) the direct DAE: where each solver stops")
    emit()
    emit("t_stop [s] (v there [m/s]) per tolerance; t_final = 3 s means it completed. The paper")
    emit("claims that direct DAE solvers fail at the stick-slip points (J_t → 0 at the maximum of φ).")
    emit("IDA and scipy report their last internal step; CasADi idas runs output interval by output interval")
    emit("(every 0.05 s) and reports the last one reached; diffrax reports its last output time (every 1 ms).")
    emit("φ at V = 1.1 has its maximum at v = 0.524 and its minimum at v = 8.49.")
    emit()
    solvers = [
        ("SUNDIALS IDA (scikit-sundae)", dae_ida),
        ("CasADi idas", dae_casadi_idas),
        ("scipy Radau, index-1 ODE", dae_index1_ode),
        ("diffrax Kvaerno5, index-1 ODE", dae_diffrax_index1),
    ]
    emit("| solver | V | " + " | ".join(f"rtol {r:g}" for r in rtols) + " |")
    emit("|---|---:|" + "---:|" * len(rtols))
    for name, run in solvers:
        for Vp in velocities:
            cells = []
            for rtol in rtols:
                try:
                    t_stop, v_stop, message = run(Vp, rtol)
                    cells.append(f"{t_stop:.4g} ({v_stop:.3g})")
                except Exception as error:
                    cells.append(f"error: {_one_line(error)[:40]}")
            emit(f"| {name} | {Vp:g} | " + " | ".join(cells) + " |")
    emit()


# --------------------------------------------------------------------------- measuring
def reference(tau):
    import jax

    import peeljax

    sol = peeljax.simulate_reference(V=V, tau=tau, dt=T_FINAL / 300, t_final=T_FINAL, rtol=REF_RTOL, atol=REF_ATOL)
    v = np.asarray(jax.block_until_ready(sol.ys))[:, 3]
    if not bool(sol.completed):
        raise RuntimeError(f"the reference stopped at t = {float(sol.t_stop)} (tau = {tau})")
    return v


def check(peer: Peer, v_ref: np.ndarray):
    """Prepare the peer and run each setting once (warm-up, compilation), checking its answer."""
    rows = []
    try:
        peer.prepare()
    except Exception as error:  # a missing optional peer is reported, not fatal
        return [{"setting": None, "status": f"unavailable: {_one_line(error)}"}]
    scale = np.max(np.abs(v_ref))
    for setting in peer.settings:
        try:
            started = time.perf_counter()
            v = peer.run(setting)
            first = time.perf_counter() - started
        except Exception as error:
            rows.append({"setting": setting, "status": f"failed: {_one_line(error)}"})
            continue
        finite = np.isfinite(v)
        if not finite.all():
            stop = GRID[np.argmin(finite)] if not finite[0] else GRID[np.argmax(~finite) - 1]
            rows.append({"setting": setting, "status": f"stopped near t = {stop:.3g} s", "first_s": first})
            continue
        error = float(np.max(np.abs(v - v_ref)))
        # Wrong: off by 10 % of max|v|, or (adaptive peers) far above what the tolerance asks.
        limit = 0.1 if peer.setting_name != "rtol" else min(0.1, max(1e3 * setting, 1e-4))
        status = "ok" if error <= limit * scale else f"wrong answer (max/Δv/ = {error:.2g})"
        rows.append({"setting": setting, "status": status, "error": error, "first_s": first, "times": []})
    return rows


def time_round_robin(peers, rows_of, repeats):
    """``repeats`` rounds, each running every checked (peer, setting) once: load hits all alike."""
    for _ in range(repeats):
        for peer in peers:
            for row in rows_of[peer.name]:
                if row.get("status") == "ok":
                    started = time.perf_counter()
                    peer.run(row["setting"])
                    row["times"].append(time.perf_counter() - started)
    for rows in rows_of.values():
        for row in rows:
            if row.get("times"):
                row["median_s"] = float(np.median(row["times"]))


def _one_line(error: Exception) -> str:
    text = " ".join(str(error).split()).replace("|", "/")
    return f"{type(error).__name__}: {text[:70]}"


def cheapest_at(rows, target):
    ok = [r for r in rows if r.get("status") == "ok" and r["error"] <= target]
    return min(ok, key=lambda r: r["median_s"]) if ok else None


def versions():
    out = [f"python {platform.python_version()}"]
    for module in ("jax", "jaxlib", "diffrax", "equinox", "numpy", "scipy", "numba", "sksundae", "casadi"):
        try:
            out.append(f"{module} {importlib.import_module(module).__version__}")
        except Exception:
            out.append(f"{module} missing")
    return ", ".join(out)


def work_precision_plot(results, path):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    taus = sorted(results)
    fig = Figure(figsize=(5.5 * len(taus), 4.5), layout="constrained")
    axes = fig.subplots(1, len(taus), squeeze=False)[0]
    for ax, tau in zip(axes, taus):
        for name, rows in results[tau].items():
            pts = sorted((r["error"], r["median_s"]) for r in rows if r.get("status") == "ok")
            if pts:
                errors, times = zip(*pts)
                ax.loglog(errors, times, "o-", label=name, lw=1.2, ms=4)
        ax.axvline(TARGET, color="0.6", ls=":", lw=1)
        ax.set_xlabel("max |v − v_ref| over 301 times [m/s]")
        ax.set_ylabel("wall time per run [s]")
        ax.set_title(f"V = {V} m/s, τ = {tau} s, t ∈ [0, {T_FINAL:g}] s")
        ax.grid(True, which="both", alpha=0.3)
    axes[-1].legend(fontsize=8)
    FigureCanvasAgg(fig).print_figure(path, dpi=120)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="τ = 0.01 only, fewer settings and repeats (~1 min)")
    parser.add_argument("--repeats", type=int, default=None, help="timed runs per setting (default 5, quick 3)")
    parser.add_argument("--smoke", action="store_true", help="one setting per peer, one repeat: checks the script runs")
    parser.add_argument("--out", default=None, help="markdown output (default results/latest[_quick].md)")
    args = parser.parse_args(argv)
    repeats = args.repeats or (1 if args.smoke else 3 if args.quick else 5)
    taus = (0.01,) if (args.quick or args.smoke) else (0.01, 0.1)
    if args.smoke:
        steps, rtols = (300,), (1e-4,)
    elif args.quick:
        steps, rtols = (300, 1200, 4800, 9600), (1e-3, 1e-5, 1e-7)
    else:
        steps, rtols = (300, 600, 1200, 2400, 4800, 9600, 19200, 38400), (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9)
    started = time.perf_counter()

    out = []

    def emit(line=""):
        print(line, flush=True)
        out.append(line)

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    emit("# peeljax against its peers (issue 6: P1, P2)")
    emit()
    emit(f"- CPU: {cpu_model()}, {os.cpu_count()} logical cores; load average at start {load:.2f}")
    emit(f"- {versions()}")
    emit(f"- problem: V = {V}, t ∈ [0, {T_FINAL:g}] s, paper geometry and initial data; error = max over the")
    emit(f"  301 times 0, 0.01, …, 3 s of |v − v_ref|, v_ref = diffrax Kvaerno5 at rtol {REF_RTOL:g}, atol {REF_ATOL:g}")
    emit(f"- medians of {repeats} runs after a warm-up run; adaptive peers use atol = 1e-2·rtol")
    emit()

    results = {}
    for tau in taus:
        v_ref = reference(tau)
        peers = [
            PeeljaxAlpha(tau, steps),
            NumbaAlpha(tau, steps),
            DiffraxPeer(tau, rtols, "Kvaerno5"),
            DiffraxPeer(tau, rtols, "Kvaerno3"),
            ScipyPeer(tau, rtols, "Radau"),
            ScipyPeer(tau, rtols, "BDF"),
            ScipyPeer(tau, rtols, "BDF", log_v=True),
            CvodePeer(tau, rtols),
            CvodePeer(tau, rtols, log_v=True),
            CasadiPeer(tau, rtols),
            CasadiPeer(tau, rtols, log_v=True),
        ]
        results[tau] = {}
        for peer in peers:
            results[tau][peer.name] = check(peer, v_ref)
            print(f"  [τ = {tau}: {peer.name} checked]", file=sys.stderr, flush=True)
        time_round_robin(peers, results[tau], repeats)

        emit(f"## τ = {tau}")
        emit()
        emit(f"### (P1) the cheapest setting with error ≤ {TARGET:g}")
        emit()
        base = cheapest_at(results[tau]["peeljax α-method"], TARGET)
        emit("| method | setting | error | median s | time / peeljax's |")
        emit("|---|---:|---:|---:|---:|")
        for peer in peers:
            best = cheapest_at(results[tau][peer.name], TARGET)
            if best is None:
                statuses = sorted({r["status"] for r in results[tau][peer.name] if r.get("status") != "ok"})
                emit(f"| {peer.name} | – | – | – | not reached ({'; '.join(statuses) or 'error above target'}) |")
                continue
            ratio = best["median_s"] / base["median_s"] if base else math.nan
            emit(
                f"| {peer.name} | {peer.setting_name} = {best['setting']:g} | {best['error']:.1e} "
                f"| {best['median_s']:.4f} | {ratio:.2f} |"
            )
        emit()
        emit("### (P2) work-precision: every setting")
        emit()
        emit("| method | setting | status | error | median s | first call s |")
        emit("|---|---:|---|---:|---:|---:|")
        for peer in peers:
            for r in results[tau][peer.name]:
                setting = "–" if r["setting"] is None else f"{peer.setting_name} = {r['setting']:g}"
                error = f"{r['error']:.1e}" if "error" in r else "–"
                median = f"{r['median_s']:.4f}" if "median_s" in r else "–"
                first = f"{r['first_s']:.2f}" if "first_s" in r else "–"
                emit(f"| {peer.name} | {setting} | {r['status']} | {error} | {median} | {first} |")
        emit()

    direct_dae_table(emit, (1.1,) if args.smoke else (1.1, 2.0, 4.0), (1e-6,) if args.smoke else (1e-4, 1e-6, 1e-8))

    results_dir = HERE / "results"
    results_dir.mkdir(exist_ok=True)
    suffix = "_quick" if args.quick else "_smoke" if args.smoke else ""
    path = Path(args.out) if args.out else results_dir / f"latest{suffix}.md"
    plot_path = path.parent / f"work_precision{suffix}.png"
    work_precision_plot(results, plot_path)
    emit(f"Work-precision plot: `{plot_path.name}`. Total benchmark time: {time.perf_counter() - started:.0f} s.")
    path.write_text("\n".join(out) + "\n")
    print(f"(written to {path})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
