"""peeljax against the solvers people would use instead, on this very problem (issue 6).

Problems (paper geometry and initial data):

* (P1) one trajectory at V = 1.1, τ = 0.01 and τ = 0.1, t ∈ [0, 3 s]: for each method, the
  cheapest setting whose error in v is at most ``TARGET`` (1e-3), its median time, and that time
  divided by peeljax's (uniform mesh) and by peeljax's adaptive α-method's at the same target;
* (P2) work-precision: wall time against the error in v (max over the 301 times
  0, 0.01, …, 3 s) relative to a tight reference (diffrax Kvaerno5, rtol 1e-11), over a range
  of tolerances (adaptive peers) or steps (α-methods); ``results/work_precision.png``;
* (P3) a batch of 1024 trajectories (V ∈ {1.1, 2, 4, 8} × 256 τ log-spaced in [0.005, 0.5] s,
  t ∈ [0, 3 s]): ``peeljax.sweep`` with error control (the α-method with a step size per
  trajectory, rtol ∈ {1e-3, 3e-4, …, 1e-7}, atol = 1e-3·rtol, v saved at ``GRID`` by
  ``save_dt = 0.01``; lanes sharded over every JAX device, one at a time per device on a CPU),
  the row every ratio is taken against, and ``peeljax.sweep`` on a uniform mesh (``dt``, the
  same N for every trajectory: the before) against diffrax Kvaerno5 under ``jax.vmap`` and
  against looping CVODE, CasADi cvodes (both on log v) and scipy Radau (on a few trajectories,
  extrapolated), each at the cheapest setting tried whose relative error in v
  (max|v − v_ref| / max|v_ref|) is ≤ ``TARGET`` on 32 trajectories spread over the grid (the
  tight reference for all 1024 would be too slow); PETSc TSALPHA (fixed steps, the uniform
  mesh's N) through petsc4py if another
  interpreter has it (``PETSC_PYTHON``, default ``/usr/bin/python3``; ``petsc_tsalpha.py``);
* (P4) the gradient of L = mean over t_i = i/82 s, t ∈ [0, 1 s], of (v(t_i) − v_data(t_i))²
  (V = 1.1, τ = 0.1) with respect to φ's 14 coefficients: peeljax reverse mode (``jax.grad``
  through ``integrate_alpha``; the adaptive α-method: ``jax.grad`` through ``simulate(…, rtol=…, ts=…)``,
  its checkpointed while loop) against CasADi cvodes forward sensitivities, central finite
  differences (28 forward runs, of peeljax and of CasADi) and diffrax's
  ``RecursiveCheckpointAdjoint`` on Kvaerno5 (full mode only), every gradient checked against
  CasADi's at rtol 1e-11;
* (P5) the direct DAE at V = 1.1, 2, 4: where SUNDIALS IDA, CasADi idas (v algebraic), scipy
  Radau and diffrax Kvaerno5 on the index-1 ODE (eq. ``hv`` at τ = 0) stop, per tolerance.

Peers (each one's answer is checked against the reference before it is timed; in P1/P2 a run
that reports success but misses the reference by more than 10 % of max|v|, or an adaptive run
off by more than max(1e3·rtol, 1e-4)·max|v|, is reported as a wrong answer and not timed):

* ``peeljax``: the α-method (``peeljax.simulate``), h = 3/N, N ∈ {300, 600, …};
* ``peeljax adaptive α``: the error-controlled α-method (``peeljax.simulate(dt=None, rtol=…,
  atol=1e-3·rtol, ts=GRID)``: PI controller on the estimate C·h²·(a_{n+1} − a_n), Hermite
  dense output), rtol ∈ {1e-2, …, 1e-8};
* ``numba α``: the same algorithm as a compiled loop (``compiled_loop.py``), the practical limit;
* ``diffrax Kvaerno5``, ``diffrax Kvaerno3``: ``peeljax.simulate_reference`` with that solver;
* ``scipy Radau``, ``scipy BDF``: ``solve_ivp`` with ψ and its exact Jacobian compiled by
  numba (``compiled_loop.evaluate``);
* ``CVODE``: SUNDIALS CVODE (BDF, dense) through scikit-sundae, same compiled ψ and Jacobian;
* ``CasADi cvodes``: CasADi's CVODES integrator on ψ built from CasADi symbols, with its own
  automatic Jacobian;
* the SUNDIALS, scipy BDF and CasADi peers also run on z = (α, ω, u, log v) ("(log v)"), the
  coordinates peeljax discretises: on y they stumble over the non-Lipschitz start v0 = 1e-10·V;
* ``petsc4py TSALPHA``: PETSc's generalized-α for first-order systems (ρ∞ = peeljax's ρ) with
  its own error control (TSAdapt basic), on log v, v at ``GRID`` by TSInterpolate; run by
  ``petsc_tsalpha.py --serve`` in a long-lived subprocess of the interpreter that has petsc4py
  (its time includes ψ and a finite-difference Jacobian in Python, and one JSON round trip).

All peers integrate the homogenized ODE (eq. ``hv``) in the physical state (α, ω, u, v)
unless marked "(log v)"; peeljax and the numba loop discretise (α, ω, u, log v)
(``AlphaMethod.log_discretization``).

    python benchmarks/compare.py                  # full: ~5.5 min on a 2-core Intel Xeon (9-14 min on a 2-core
                                                  # AMD EPYC); P3 on 1024 trajectories
    python benchmarks/compare.py --quick          # ~2.5 min: τ = 0.01 only, P3 on 16 trajectories, fewer settings;
                                                  # --smoke (the test): ~1.3 min, one setting per peer
    python benchmarks/compare.py --only P3 P4     # some problems only (P1 includes P2)

Writes ``benchmarks/results/latest.md`` (``latest_quick.md`` with ``--quick``) and the plot.
Times are medians of repeated runs after a warm-up run, measured round-robin so that load on
the shared machine hits every peer alike; compile times are listed apart. Much of --quick and
--smoke is compilation (peeljax's gradient alone compiles for ~1–1.5 min here). Nothing here is
asserted by a test except that the script runs (``tests/test_compare_script.py``).
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import platform
import re
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from machine import cpu_model

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


ADAPTIVE_ALPHA_ATOL = 1e-3  # the adaptive α-method runs at atol = ADAPTIVE_ALPHA_ATOL·rtol


class PeeljaxAdaptive(Peer):
    """The error-controlled α-method: ``peeljax.simulate(dt=None, rtol, atol, ts=GRID)``.

    atol = 1e-3·rtol (the error of α, ω, u is then mostly relative; log v is weighted by rtol
    alone in any case), which gives a clean second-order work-precision curve. The last run's
    ``stats`` per setting are kept (device arrays, read only when the tables are written).
    """

    name = "peeljax adaptive α"
    setting_name = "rtol"

    def prepare(self):
        import jax

        import peeljax

        self._jax, self._pj = jax, peeljax
        self.stats = {}

    def run(self, rtol):
        sol = self._pj.simulate(V=V, tau=self.tau, t_final=T_FINAL, rtol=rtol, atol=ADAPTIVE_ALPHA_ATOL * rtol, ts=GRID)
        v = np.asarray(self._jax.block_until_ready(sol.ys))[:, 3]  # NaN after a stop
        self.stats[rtol] = sol.stats
        return v

    def describe(self, rtol):
        st = {k: int(self.stats[rtol][k]) for k in ("accepted_steps", "rejected_steps", "newton_iterations")}
        return f"{st['accepted_steps']}/{st['rejected_steps']}, {st['newton_iterations']}"


class NumbaAlpha(Peer):
    name = "numba α-method"
    setting_name = "N"

    def prepare(self):
        from compiled_loop import initial_state, integrate, options_of, parameters

        import peeljax

        self._p = parameters(V, self.tau)
        self._y0 = initial_state(self._p)
        self._options = options_of(peeljax.AlphaMethod())
        self._integrate = integrate

    def run(self, n):
        ys, _, _, _status, _ = self._integrate(self._y0, self._p, T_FINAL / n, n, **self._options)
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


class NotRun(Exception):
    """A peer that cannot run on this machine (an optional dependency is missing): reported, not fatal."""


PETSC_DT0 = 1e-8  # TSALPHA's first step [s]; TSAdapt basic grows it by at most 10× a step


class PetscAlphaPeer(Peer):
    """PETSc TSALPHA with TSAdapt basic on z = (α, ω, u, log v), in a ``petsc_tsalpha.py --serve`` subprocess."""

    name = "petsc4py TSALPHA, TSAdapt basic (log v)"
    setting_name = "rtol"

    def prepare(self):
        import json
        import subprocess

        import peeljax

        self._json = json
        self.radius = float(peeljax.AlphaMethod().rho)
        python, script = petsc_python(), str(HERE / "petsc_tsalpha.py")
        try:
            check = subprocess.run([python, script, "--check"], check=False, capture_output=True, text=True, timeout=60)
        except (OSError, subprocess.SubprocessError) as error:
            raise NotRun(f"{python} cannot be run ({_one_line(error)})") from error
        if check.returncode != 0:
            last = (check.stderr.strip().splitlines() or ["?"])[-1]
            raise NotRun(f"petsc4py not installed ({python}: {last[:80]})")
        command = [python, script, "--serve"]
        self._proc = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.version = json.loads(self._proc.stdout.readline())["petsc"]
        self.stats = {}

    def run(self, rtol):
        request = {"V": V, "tau": self.tau, "rtol": rtol, "atol": 1e-2 * rtol, "grid": GRID.tolist(),
                   "radius": self.radius, "dt0": PETSC_DT0}  # fmt: skip
        self._proc.stdin.write(self._json.dumps(request) + "\n")
        self._proc.stdin.flush()
        line = self._proc.stdout.readline()
        if not line:
            raise RuntimeError(f"petsc_tsalpha.py --serve ended (exit code {self._proc.poll()})")
        result = self._json.loads(line)
        if result["v"] is None:
            raise RuntimeError(result["status"])
        self.stats[rtol] = result
        return np.array([np.nan if a is None else a for a in result["v"]], float)

    def describe(self, rtol):
        r = self.stats[rtol]
        return f"{r['steps']}/{r['rejected']}, {r['snes_iterations']} ({r['snes_failures']} failed)"

    def close(self):
        proc = getattr(self, "_proc", None)
        if proc is not None and proc.poll() is None:
            proc.stdin.write("\n")
            proc.stdin.flush()
            proc.wait(timeout=60)


def _numba_rhs(tau, log_v, Vp=V):
    """Compiled ψ and ψ' in y = (α, ω, u, v), or in z = (α, ω, u, log v) when ``log_v``."""
    from compiled_loop import evaluate_carried, initial_state, parameters

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
    """ψ of eq. ``hv`` (paper geometry, the paper's φ) as CasADi symbols (in z when ``log_v``):
    :func:`casadi_parametric` with V, τ and φ's coefficients substituted."""
    import casadi as ca

    y, P, psi, _ = casadi_parametric(log_v)
    return y, ca.substitute(psi, P, ca.SX(ca.DM([V, tau, *PAPER_PHI])))


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
                    t_stop, v_stop, _message = run(Vp, rtol)
                    cells.append(f"{t_stop:.4g} ({v_stop:.3g})")
                except Exception as error:  # noqa: BLE001 (a solver's failure is the result)
                    cells.append(f"error: {_one_line(error)[:40]}")
            emit(f"| {name} | {Vp:g} | " + " | ".join(cells) + " |")
    emit()


# --------------------------------------------------------------------------- (P3) a batch of trajectories
P3_VELOCITIES = (1.1, 2.0, 4.0, 8.0)
P3_TAU_RANGE = (0.005, 0.5)
COEFFICIENT_NAMES = ("c1", "p1", "c2", "p2", "c3", "c4", "c5", "p5", "c6", "c7", "p7", "c8", "p8", "p9")
PAPER_PHI = (400.0, 0.35, 110.0, 0.15, 130.0, 11.0, 2.0, 1.5, 415.0, 45.0, 0.4, 0.35, 2.15, 0.5)


def p3_grid(n_tau):
    """(V, τ) of the batch: every V of ``P3_VELOCITIES`` with ``n_tau`` τ log-spaced in ``P3_TAU_RANGE``."""
    taus = np.geomspace(*P3_TAU_RANGE, n_tau)
    return np.repeat(np.asarray(P3_VELOCITIES, float), n_tau), np.tile(taus, len(P3_VELOCITIES))


def p3_subsample(n_tau, per_v):
    """Indices of ``per_v`` τ per V spread over [τ_min, τ_max] (both ends included)."""
    j = np.unique(np.linspace(0, n_tau - 1, per_v).round().astype(int))
    return np.concatenate([k * n_tau + j for k in range(len(P3_VELOCITIES))])


def relative_errors(v, v_ref):
    """Per trajectory: max over ``GRID`` of |v − v_ref| / max |v_ref| (inf where v stopped)."""
    v, v_ref = np.atleast_2d(v), np.atleast_2d(v_ref)
    error = np.max(np.abs(v - v_ref), axis=1) / np.max(np.abs(v_ref), axis=1)
    return np.where(np.all(np.isfinite(v), axis=1), error, np.inf)


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


def peeljax_batch(Vs, taus, n):
    """``peeljax.sweep`` on a uniform mesh of n steps, states kept at ``GRID`` (every n/300 steps); (v, status)."""
    import peeljax

    result = peeljax.sweep(
        None, Vs, taus, T_FINAL / n, T_FINAL, grid="pairs", save_every=n // (GRID.size - 1), progress=False
    )
    return result.ys[:, :, 3], result.status


P3_SAVE_DT = 0.01  # output_times(0.01, 3) is GRID (checked in batch_table)
# Loose to tight, atol = ADAPTIVE_ALPHA_ATOL·rtol. The error falls only about as rtol^(2/3) (P2: error ∝
# steps^-2, steps ∝ rtol^(-1/3)), so the rungs are half a decade apart.
P3_ADAPTIVE_RTOLS = (1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 3e-6, 1e-6, 3e-7, 1e-7)


def peeljax_batch_adaptive(Vs, taus, rtol):
    """``peeljax.sweep`` with error control (default devices and lane_batch), v at ``GRID``;
    (v, status, accepted steps, rejected steps)."""
    import peeljax

    result = peeljax.sweep(
        None, Vs, taus, None, T_FINAL, rtol=rtol, atol=ADAPTIVE_ALPHA_ATOL * rtol, save_dt=P3_SAVE_DT,
        grid="pairs", progress=False,
    )  # fmt: skip
    return result.ys[:, :, 3], result.status, result.accepted_steps, result.rejected_steps


def cvode_logv(Vp, tau, rtol):
    """SUNDIALS CVODE (BDF) on z = (α, ω, u, log v), compiled ψ and ψ' (as the P1 peer); v on ``GRID``."""
    from compiled_loop import evaluate_carried, initial_state, parameters
    from sksundae.cvode import CVODE

    p = parameters(Vp, tau)
    psi, yy, scratch = np.empty(4), np.empty(4), np.empty((4, 4))

    def rhsfn(t, y, yp):
        evaluate_carried(y, True, p, yp, scratch, yy, False)

    def jacfn(t, y, yp, JJ):
        evaluate_carried(y, True, p, psi, JJ, yy, True)

    z0 = initial_state(p)
    z0[3] = math.log(z0[3])
    solver = CVODE(rhsfn, jacfn=jacfn, method="BDF", rtol=rtol, atol=1e-2 * rtol, max_num_steps=200_000)
    y = np.asarray(solver.solve(GRID, z0).y)
    v = np.full(GRID.size, np.nan)
    v[: y.shape[0]] = np.exp(y[:, 3])
    return v


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


class CasadiBatch:
    """CasADi cvodes on z = (α, ω, u, log v), one integrator with (V, τ) as parameters, called per trajectory."""

    def __init__(self):
        import casadi as ca

        self._ca = ca
        self._z, self._P, self._psi, self._z0 = casadi_parametric(log_v=True)
        self._integrators = {}

    def integrator(self, rtol):
        if rtol not in self._integrators:
            options = {"abstol": 1e-2 * rtol, "reltol": rtol, "max_num_steps": 200_000, "print_stats": False}
            dae = {"x": self._z, "p": self._P, "ode": self._psi}
            self._integrators[rtol] = self._ca.integrator("F", "cvodes", dae, 0.0, GRID[1:], options)
        return self._integrators[rtol]

    def __call__(self, Vp, tau, rtol):
        from compiled_loop import initial_state, parameters

        z0 = initial_state(parameters(Vp, tau))
        z0[3] = math.log(z0[3])
        try:
            xf = np.asarray(self.integrator(rtol)(x0=z0, p=[Vp, tau, *PAPER_PHI])["xf"])
        except RuntimeError:  # CasADi raises when CVODES fails; the trajectory counts as stopped
            return np.full(GRID.size, np.nan)
        return np.exp(np.concatenate([[z0[3]], xf[3]]))


def radau_y(Vp, tau, rtol):
    """scipy Radau on y with the compiled ψ and exact Jacobian (as the P1 peer); v on ``GRID``."""
    from scipy.integrate import solve_ivp

    rhs, jac, y0 = _numba_rhs(tau, False, Vp)
    sol = solve_ivp(rhs, (0.0, T_FINAL), y0, method="Radau", t_eval=GRID, rtol=rtol, atol=1e-2 * rtol, jac=jac)
    v = np.full(GRID.size, np.nan)
    v[: sol.y.shape[1]] = sol.y[3]
    return v


def petsc_python():
    return os.environ.get("PETSC_PYTHON", "/usr/bin/python3")


def petsc_tsalpha(pairs, n, radius):
    """PETSc TSALPHA in a subprocess (``petsc_tsalpha.py``); (v rows, seconds per run, statuses), or an error text."""
    import json
    import subprocess
    import tempfile

    script = HERE / "petsc_tsalpha.py"
    python = petsc_python()
    try:
        check = subprocess.run([python, str(script), "--check"], check=False, capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError) as error:
        return f"unavailable: {python} cannot be run ({_one_line(error)}); not run here"
    if check.returncode != 0:
        last = (check.stderr.strip().splitlines() or ["?"])[-1]
        return f"unavailable: petsc4py not installed ({python}: {last[:80]}); not run here"
    with tempfile.TemporaryDirectory() as tmp:
        jobs, out = Path(tmp) / "jobs.json", Path(tmp) / "out.json"
        every = n // (GRID.size - 1)
        jobs.write_text(json.dumps({"jobs": [list(map(float, p)) for p in pairs], "n_steps": n,
                                    "t_final": T_FINAL, "every": every, "radius": radius}))  # fmt: skip
        command = [python, str(script), str(jobs), str(out)]
        done = subprocess.run(command, check=False, capture_output=True, text=True, timeout=3600)
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or ["?"])[-1]
            return f"failed: {last[:100]}"
        result = json.loads(out.read_text())
    runs = result["runs"]
    v = np.array([[np.nan if a is None else a for a in (r["v"] or [None] * GRID.size)] for r in runs], float)
    seconds = np.array([np.nan if r["seconds"] is None else r["seconds"] for r in runs])
    return v, seconds, [r["status"] for r in runs], result["petsc"]


def _loop(fn, Vs, taus, setting):
    return np.stack([fn(float(Vp), float(tau), setting) for Vp, tau in zip(Vs, taus)])


def _stopped_note(label, setting, completed, stopped_ok, Vs, taus, B):
    """One sentence: where ``label`` stopped (by V, up to which τ) and how the others did there."""
    stopped = ~completed
    if not stopped.any():
        return f"{label} completed all {B} trajectories at {setting}"
    return (f"{label} stopped on {int(stopped.sum())} of {B} (V, τ) at {setting}: "
            + ", ".join(f"V = {Vp:g}: τ ≤ {taus[stopped & (Vs == Vp)].max():.3g} ({int(np.sum(stopped & (Vs == Vp)))})"
                        for Vp in P3_VELOCITIES if np.any(stopped & (Vs == Vp)))
            + "; on those, " + ", ".join(f"{k} completed {int(np.sum(ok[stopped]))}" for k, ok in stopped_ok.items()))  # fmt: skip


def batch_table(emit, n_tau, per_v, settings, repeats, radau_count):
    """(P3): the batch of 4·n_tau trajectories; errors checked on a subsample of 4·per_v."""
    import jax

    import peeljax
    from peeljax.integrators.dense import output_times

    Vs, taus = p3_grid(n_tau)
    B = Vs.size
    sub = p3_subsample(n_tau, per_v)
    radau_sub = sub[np.linspace(0, sub.size - 1, radau_count).round().astype(int)]
    save_ts = output_times(P3_SAVE_DT, T_FINAL)
    if save_ts.shape != GRID.shape or np.max(np.abs(save_ts - GRID)) > 1e-12 * T_FINAL:
        raise RuntimeError(f"output_times({P3_SAVE_DT}, {T_FINAL}) is not GRID: the error-controlled sweep would "
                           "save v at other times than the peers'")  # fmt: skip
    devices = jax.devices()
    emit(f"## (P3) a batch of {B} trajectories")
    emit()
    emit(f"V ∈ {{{', '.join(f'{v:g}' for v in P3_VELOCITIES)}}} × {n_tau} τ log-spaced in "
         f"[{P3_TAU_RANGE[0]:g}, {P3_TAU_RANGE[1]:g}] s, t ∈ [0, {T_FINAL:g}] s, paper initial data, v kept at the 301 times "
         f"of P1. Error of a trajectory: max over those times of |v − v_ref| / max|v_ref| (relative to the largest v of "
         f"the reference), v_ref = diffrax Kvaerno5 at rtol {REF_RTOL:g}, atol {REF_ATOL:g} under vmap; checked on "
         f"{sub.size} trajectories spread over the grid ({per_v} τ per V, both ends included). Each method's setting is "
         f"the cheapest of those tried whose max error on them is ≤ {TARGET:g}.")  # fmt: skip
    emit()
    kind = devices[0].platform + ("" if devices[0].device_kind == devices[0].platform else f", {devices[0].device_kind}")
    emit(f"peeljax.sweep ran on {len(devices)} JAX device(s) ({kind}; "
         f"jax.devices() of this process), its lanes dealt over them; with error control each device runs its lanes "
         f"{'one at a time (lane_batch = 1, the CPU default)' if devices[0].platform == 'cpu' else 'together (vmap)'} "
         f"and v is saved at the 301 times by save_dt = {P3_SAVE_DT:g} (dense output). diffrax under vmap runs on "
         "one device; the looped peers run one trajectory after another in this process (one core).")  # fmt: skip
    emit()
    started = time.perf_counter()
    run_diffrax = diffrax_vmap()
    v_ref, ref_status = run_diffrax(Vs[sub], taus[sub], REF_RTOL, REF_ATOL)
    if np.any(ref_status != 0):
        raise RuntimeError(f"the P3 reference stopped at (V, τ) = {list(zip(Vs[sub][ref_status != 0], taus[sub]))}")
    print(f"  [P3 reference on {sub.size} trajectories: {time.perf_counter() - started:.0f} s]", file=sys.stderr)
    casadi = CasadiBatch()
    calibration = {}

    def calibrate(name, values, run_sub, key=lambda s: s):
        """Settings from the cheapest on; stop at the first whose max error on the subsample is ≤ TARGET."""
        tried = []
        for setting in values:
            try:
                v = run_sub(setting)
                errors = relative_errors(v, v_ref[key(setting)])
                tried.append((setting, float(np.max(errors)), int(np.sum(np.isfinite(errors)))))
            except Exception as error:  # noqa: BLE001 (a failing setting is reported)
                tried.append((setting, math.inf, f"failed: {_one_line(error)}"))
            if tried[-1][1] <= TARGET:
                break
        calibration[name] = tried
        print(f"  [P3 {name}: {tried}]", file=sys.stderr, flush=True)
        ok = [t for t in tried if t[1] <= TARGET]
        return (ok[0] if ok else min(tried, key=lambda t: t[1])), bool(ok)

    everything = slice(None)
    (r_adaptive, _, _), met_adaptive = calibrate(
        "peeljax error control (rtol)", settings["rtols_adaptive"],
        lambda r: peeljax_batch_adaptive(Vs[sub], taus[sub], r)[0], key=lambda s: everything,
    )  # fmt: skip
    (n_alpha, _, _), met_alpha = calibrate(
        "peeljax uniform mesh (N)", settings["steps"], lambda n: peeljax_batch(Vs[sub], taus[sub], n)[0],
        key=lambda s: everything,
    )  # fmt: skip
    (r_diffrax, _, _), met_diffrax = calibrate(
        "diffrax", settings["rtols_diffrax"], lambda r: run_diffrax(Vs[sub], taus[sub], r)[0], key=lambda s: everything
    )
    (r_cvode, _, _), met_cvode = calibrate(
        "cvode", settings["rtols_loop"], lambda r: _loop(cvode_logv, Vs[sub], taus[sub], r), key=lambda s: everything
    )
    (r_casadi, _, _), met_casadi = calibrate(
        "casadi", settings["rtols_loop"], lambda r: _loop(casadi, Vs[sub], taus[sub], r), key=lambda s: everything
    )
    radau_pos = np.searchsorted(sub, radau_sub)
    (r_radau, _, _), met_radau = calibrate(
        "radau", settings["rtols_radau"], lambda r: _loop(radau_y, Vs[radau_sub], taus[radau_sub], r),
        key=lambda s: radau_pos,
    )  # fmt: skip
    radius = float(peeljax.AlphaMethod().rho)
    petsc = petsc_tsalpha(list(zip(Vs[radau_sub], taus[radau_sub])), n_alpha, radius)

    # First (compiling) calls on the whole batch, then `repeats` round-robin rounds.
    first = {}
    start = time.perf_counter()
    v_adaptive, status_adaptive, accepted, rejected = peeljax_batch_adaptive(Vs, taus, r_adaptive)
    first["adaptive"] = time.perf_counter() - start
    start = time.perf_counter()
    v_alpha, status_alpha = peeljax_batch(Vs, taus, n_alpha)
    first["uniform"] = time.perf_counter() - start
    start = time.perf_counter()
    v_dfx, status_dfx = run_diffrax(Vs, taus, r_diffrax)
    first["diffrax"] = time.perf_counter() - start
    times = {k: [] for k in ("adaptive", "uniform", "diffrax", "cvode", "casadi", "radau")}
    outputs = {}
    for _ in range(repeats):
        for key, call in (
            ("adaptive", lambda: peeljax_batch_adaptive(Vs, taus, r_adaptive)),
            ("uniform", lambda: peeljax_batch(Vs, taus, n_alpha)),
            ("diffrax", lambda: run_diffrax(Vs, taus, r_diffrax)),
            ("cvode", lambda: _loop(cvode_logv, Vs, taus, r_cvode)),
            ("casadi", lambda: _loop(casadi, Vs, taus, r_casadi)),
            ("radau", lambda: _loop(radau_y, Vs[radau_sub], taus[radau_sub], r_radau)),
        ):
            start = time.perf_counter()
            outputs[key] = call()
            times[key].append(time.perf_counter() - start)
        print(f"  [P3 round: { {k: round(t[-1], 2) for k, t in times.items()} }]", file=sys.stderr, flush=True)
    median = {k: float(np.median(t)) for k, t in times.items()}
    completed = {
        "adaptive": status_adaptive == 0,
        "uniform": status_alpha == 0,
        "diffrax": status_dfx == 0,
        "cvode": np.all(np.isfinite(outputs["cvode"]), axis=1),
        "casadi": np.all(np.isfinite(outputs["casadi"]), axis=1),
    }
    # The errors of the timed runs themselves, on the checked subsample.
    check_error = {
        "adaptive": float(np.max(relative_errors(v_adaptive[sub], v_ref))),
        "uniform": float(np.max(relative_errors(v_alpha[sub], v_ref))),
        "diffrax": float(np.max(relative_errors(v_dfx[sub], v_ref))),
        "cvode": float(np.max(relative_errors(outputs["cvode"][sub], v_ref))),
        "casadi": float(np.max(relative_errors(outputs["casadi"][sub], v_ref))),
        "radau": float(np.max(relative_errors(outputs["radau"], v_ref[radau_pos]))),
    }
    base = median["adaptive"]

    def compiled(key):  # the first call on the whole batch compiles, unless the check ran the same batch size
        return "in the check" if B == sub.size else f"{first[key] - median[key]:.1f}"

    rows = [
        ("peeljax.sweep, error control (α-method, a step size per trajectory)",
         f"rtol = {r_adaptive:g}, atol = {ADAPTIVE_ALPHA_ATOL:g}·rtol", "adaptive", met_adaptive, compiled("adaptive"),
         B, ""),
        ("peeljax.sweep, uniform mesh", f"N = {n_alpha} (dt = 1/{n_alpha / T_FINAL:g})", "uniform", met_alpha,
         compiled("uniform"), B, ""),
        ("diffrax Kvaerno5 under jax.vmap", f"rtol = {r_diffrax:g}", "diffrax", met_diffrax,
         compiled("diffrax"), B, ""),
        ("SUNDIALS CVODE (BDF) (log v), looped", f"rtol = {r_cvode:g}", "cvode", met_cvode, "–", B, ""),
        ("CasADi cvodes (log v), looped", f"rtol = {r_casadi:g}", "casadi", met_casadi, "–", B, ""),
        ("scipy Radau, looped", f"rtol = {r_radau:g}", "radau", met_radau, "–", radau_sub.size,
         f" (timed on {radau_sub.size}, × {B / radau_sub.size:g})"),
    ]  # fmt: skip
    emit("| method | setting | completed | max error (checked) | s per batch | ms per trajectory | compile s "
         "| time / peeljax's |")  # fmt: skip
    emit("|---|---|---:|---:|---:|---:|---:|---:|")
    per_batch = {}
    for name, setting, key, met, compile_s, timed_n, note in rows:
        per_batch[key] = median[key] * B / timed_n
        done = f"{int(np.sum(completed[key]))}/{B}" if key in completed else "–"
        checked = sub.size if key != "radau" else radau_sub.size
        flag = "" if met else " (target not reached)"
        emit(f"| {name} | {setting}{flag} | {done} | {check_error[key]:.1e} ({checked}) | {per_batch[key]:.2f}{note} "
             f"| {1e3 * per_batch[key] / B:.2f} | {compile_s} | {per_batch[key] / base:.2f} |")  # fmt: skip
    if isinstance(petsc, str):
        emit(f"| PETSc TSALPHA (petsc4py), looped | – | – | – | – | – | – | {petsc} |")
    else:
        v_p, seconds, statuses, version = petsc
        ok = np.array([s == "ok" for s in statuses])
        error = float(np.max(relative_errors(v_p, v_ref[radau_pos])))
        per = float(np.nanmean(seconds)) * B
        emit(f"| PETSc {version} TSALPHA (ρ∞ = {radius:g}, log v), looped | N = {n_alpha} | {int(ok.sum())}/{ok.size} "
             f"of the timed | {error:.1e} ({ok.size}) | {per:.2f} (timed on {ok.size}, × {B / ok.size:g}) | "
             f"{1e3 * per / B:.2f} | – | {per / base:.2f} |")  # fmt: skip
    emit()
    emit(f"Times: median of {repeats} timed round-robin round(s) after a first (compiling) call on the whole batch; loops "
         "call one trajectory after another (CasADi: one integrator with (V, τ) as parameters, built outside the "
         "timing; CVODE: one solver object per trajectory, as in P1). Compile s = first call − median. "
         "time / peeljax's: divided by peeljax.sweep with error control (the first row; > 1: it is faster). "
         "Settings tried on the checked trajectories (setting: max error, completed):")  # fmt: skip
    emit()
    for name, tried in calibration.items():
        emit(f"- {name}: " + "; ".join(f"{s:g}: {e:.1e} ({c})" for s, e, c in tried))
    errors_adaptive = relative_errors(v_adaptive[sub], v_ref)
    errors_alpha = relative_errors(v_alpha[sub], v_ref)
    emit()
    emit(f"peeljax's max error by V (checked trajectories): error control at rtol = {r_adaptive:g}: "
         + ", ".join(f"{Vp:g}: {np.max(errors_adaptive[Vs[sub] == Vp]):.1e}" for Vp in P3_VELOCITIES)
         + f"; uniform mesh at N = {n_alpha}: "
         + ", ".join(f"{Vp:g}: {np.max(errors_alpha[Vs[sub] == Vp]):.1e}" for Vp in P3_VELOCITIES)
         + " (one dt serves the whole batch, so the hardest (V, τ) sets it; with error control each trajectory "
           "takes the steps its own error needs).")  # fmt: skip
    emit()
    emit(f"Steps of the error-controlled sweep per trajectory (whole batch): accepted mean {np.mean(accepted):.0f} "
         f"(min {int(np.min(accepted))}, max {int(np.max(accepted))}; by V: "
         + ", ".join(f"{Vp:g}: {np.mean(accepted[Vs == Vp]):.0f}" for Vp in P3_VELOCITIES)
         + f"), rejected mean {np.mean(rejected):.1f}; the uniform mesh takes N = {n_alpha} on every trajectory.")  # fmt: skip
    emit()
    others = {"diffrax": completed["diffrax"], "CVODE": completed["cvode"], "CasADi": completed["casadi"]}
    emit(_stopped_note("peeljax with error control", f"rtol = {r_adaptive:g}", completed["adaptive"], others, Vs, taus, B)
         + "; " + _stopped_note("on the uniform mesh", f"N = {n_alpha}", completed["uniform"], others, Vs, taus, B)
         + f"; diffrax completed {int(completed['diffrax'].sum())}, CVODE {int(completed['cvode'].sum())}, "
         f"CasADi {int(completed['casadi'].sum())}.")  # fmt: skip
    emit()
    n_cores = len(devices) if devices[0].platform == "cpu" else 1
    casadi_shared = per_batch["casadi"] / n_cores  # the loop split perfectly over the cores peeljax used
    ratio_dfx = per_batch["diffrax"] / base
    ratio_casadi = casadi_shared / base
    looped = {k: per_batch[k] for k in ("cvode", "casadi", "radau")}
    best = min(looped, key=looped.get)
    emit(f"Targets (issue 6): peeljax ≥ 10× faster than diffrax under vmap: "
         f"{'met' if ratio_dfx >= 10 else 'missed'} ({ratio_dfx:.2f}×); faster than looping CasADi cvodes (log v) on the "
         f"same cores: {'met' if ratio_casadi > 1 else 'missed'} ({ratio_casadi:.2f}×: CasADi's "
         f"{per_batch['casadi']:.2f} s per batch on one core / {n_cores} core(s), as if its loop were split perfectly "
         f"over the {n_cores} the sweep used; {per_batch['casadi'] / base:.2f}× as looped here). peeljax here is "
         f"peeljax.sweep with error control at equal error ({base:.2f} s per batch on {len(devices)} device(s)); on the "
         f"uniform mesh (before): {per_batch['diffrax'] / per_batch['uniform']:.2f}× diffrax, "
         f"{casadi_shared / per_batch['uniform']:.2f}× CasADi on the same cores. Best looped peer: {best} "
         f"({looped[best]:.2f} s per batch). P3 time: {time.perf_counter() - started:.0f} s.")  # fmt: skip
    emit()
    return {"B": B, "per_batch": per_batch, "base": base, "n": n_alpha, "rtol": r_adaptive}


# --------------------------------------------------------------------------- (P4) the gradient of a trajectory loss
P4_TAU, P4_T_FINAL, P4_DEN = 0.1, 1.0, 82
P4_TIMES = np.arange(round(P4_T_FINAL * P4_DEN) + 1) / P4_DEN
P4_PERTURBATION = ("c1", 1.02)
P4_FD_STEP = 1e-4  # relative step of the central differences


def p4_coefficients():
    """Where the gradient is taken: the paper's φ with c1 raised by 2 % (the data come from the paper's φ)."""
    c = np.array(PAPER_PHI)
    c[COEFFICIENT_NAMES.index(P4_PERTURBATION[0])] *= P4_PERTURBATION[1]
    return c


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


def central_differences(value, c):
    """dL/dc_i ≈ (L(c_i(1 + h)) − L(c_i(1 − h)))/(2h·c_i), 28 forward runs."""
    g = np.empty(c.size)
    for i in range(c.size):
        plus, minus = c.copy(), c.copy()
        plus[i] *= 1 + P4_FD_STEP
        minus[i] *= 1 - P4_FD_STEP
        g[i] = (value(plus) - value(minus)) / (2 * P4_FD_STEP * c[i])
    return g


def jax_losses(v_data):
    """peeljax (α-method, N steps on [0, 1 s]) and diffrax (Kvaerno5, RecursiveCheckpointAdjoint) losses of c."""
    import diffrax
    import jax.numpy as jnp

    import peeljax
    from peeljax.integrators.alpha import integrate_alpha

    vd = jnp.asarray(v_data)

    def model_of(c):
        law = peeljax.AdhesionLaw(**{name: c[i] for i, name in enumerate(COEFFICIENT_NAMES)})
        return peeljax.PeelingModel(adhesion=law)

    def alpha_loss(c, n):
        model = model_of(c)
        ode = peeljax.HomogenizedODE(model, V, P4_TAU)
        sol = integrate_alpha(ode, peeljax.AlphaMethod(), model.initial_state(V), 0.0, P4_T_FINAL, n)
        v = jnp.where(sol.valid, sol.ys[:, 3], 0.0)[:: n // (P4_TIMES.size - 1)]  # the double where of fit.py
        return jnp.mean((v - vd) ** 2), sol.status

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

    return alpha_loss, diffrax_loss


def adaptive_alpha_loss(v_data):
    """L(c, rtol) through ``peeljax.simulate(model, …, rtol=rtol, atol=1e-3·rtol, ts=P4_TIMES)``
    (the error-controlled α-method, dense output at the data times; ``adjoint="reverse"``, the
    default: ``jax.grad`` through its checkpointed while loop). rtol is a Python number: one
    compilation per rtol. Returns (L, status)."""
    import jax.numpy as jnp

    import peeljax

    vd = jnp.asarray(v_data)

    def loss(c, rtol):
        law = peeljax.AdhesionLaw(**{name: c[i] for i, name in enumerate(COEFFICIENT_NAMES)})
        sol = peeljax.simulate(
            peeljax.PeelingModel(adhesion=law), V=V, tau=P4_TAU, t_final=P4_T_FINAL, rtol=rtol,
            atol=ADAPTIVE_ALPHA_ATOL * rtol, ts=P4_TIMES,
        )  # fmt: skip
        v = jnp.where(sol.valid, sol.ys[:, 3], 0.0)
        return jnp.mean((v - vd) ** 2), sol.status

    return loss


def _scaled_error(g, g_ref, c):
    """max_i |c_i·(g − g_ref)_i| / max_i |c_i·g_ref,i|: the error of the sensitivities to relative changes of c."""
    return float(np.max(np.abs(c * (g - g_ref))) / np.max(np.abs(c * g_ref)))


def gradient_table(emit, settings, repeats):
    """(P4): dL/dc for the 14 coefficients of φ, every method against the exact gradient."""
    import jax
    import jax.numpy as jnp

    started = time.perf_counter()
    c = p4_coefficients()
    v_data = p4_data()
    reference = CasadiLoss(1e-11, v_data)
    L_ref, g_ref = reference.value_and_grad(c)
    alpha_loss, diffrax_loss = jax_losses(v_data)
    adaptive_loss = adaptive_alpha_loss(v_data)
    n_base = settings["steps"][0]
    emit("## (P4) the gradient of a trajectory loss with respect to φ's 14 coefficients")
    emit()
    emit(f"L(c) = mean over the {P4_TIMES.size} times t_i = i/{P4_DEN} s, t ∈ [0, {P4_T_FINAL:g}] s, of (v(t_i) − "
         f"v_data(t_i))², V = {V}, τ = {P4_TAU}; v_data: the paper's φ (CasADi cvodes, rtol 1e-11); the gradient is "
         f"taken at the paper's φ with {P4_PERTURBATION[0]} × {P4_PERTURBATION[1]:g} (L = {L_ref:.4e}). Reference "
         "gradient: CasADi cvodes forward sensitivities at rtol 1e-11 (atol 1e-13). Gradient error: "
         "max_i |c_i·(g − g_ref)_i| / max_i |c_i·g_ref,i| (sensitivities to relative changes of the coefficients); "
         "it includes each method's discretization error of the trajectory (different discretizations have "
         f"different gradients). Central differences: relative step {P4_FD_STEP:g}, 28 forward runs.")  # fmt: skip
    emit()
    methods = []  # (name, setting text, prepare() -> (setup s, call), family)

    def jit_compiled(fn, *args):
        start = time.perf_counter()
        exe = jax.jit(fn).lower(*args).compile()
        return time.perf_counter() - start, exe

    c_jax = jnp.asarray(c)
    for n in settings["steps"]:
        def prepare(n=n):
            setup, exe = jit_compiled(jax.value_and_grad(lambda c: alpha_loss(c, n), has_aux=True), c_jax)

            def call():
                (L, status), g = jax.block_until_ready(exe(c_jax))
                return float(L), np.asarray(g), int(status)

            return setup, call

        methods.append(("peeljax reverse mode (jax.grad)", f"N = {n} (dt = 1/{n / P4_T_FINAL:g})", prepare, "peeljax"))
    for rtol in settings.get("rtols_adaptive", ()):
        def prepare_adaptive(rtol=rtol):
            setup, exe = jit_compiled(jax.value_and_grad(lambda c: adaptive_loss(c, rtol), has_aux=True), c_jax)

            def call():
                (L, status), g = jax.block_until_ready(exe(c_jax))
                return float(L), np.asarray(g), int(status)

            return setup, call

        methods.append(("peeljax adaptive α, reverse mode (jax.grad)", f"rtol = {rtol:g}", prepare_adaptive, "adaptive"))
    def prepare_fd(n=n_base):
        setup, exe = jit_compiled(lambda c: alpha_loss(c, n)[0], c_jax)
        value = lambda x: float(exe(jnp.asarray(x)))
        L = value(c)
        return setup, lambda: (L, central_differences(value, c), 0)

    methods.append(("central differences of peeljax", f"N = {n_base}", prepare_fd, "fd"))
    for rtol in settings["rtols_casadi"]:
        def prepare_casadi(rtol=rtol):
            start = time.perf_counter()
            loss = CasadiLoss(rtol, v_data)
            return time.perf_counter() - start, lambda: (*loss.value_and_grad(c), 0)

        methods.append(("CasADi cvodes (log v), forward sensitivities", f"rtol = {rtol:g}", prepare_casadi, "casadi"))
    for rtol in settings["rtols_casadi_fd"]:
        def prepare_casadi_fd(rtol=rtol):
            start = time.perf_counter()
            loss = CasadiLoss(rtol, v_data)
            setup, L = time.perf_counter() - start, loss.value(c)
            return setup, lambda: (L, central_differences(loss.value, c), 0)

        methods.append(("central differences of CasADi cvodes (log v)", f"rtol = {rtol:g}", prepare_casadi_fd, "fd"))
    diffrax_exe = {}
    for rtol in settings["rtols_diffrax"]:
        def prepare_diffrax(rtol=rtol):
            if "exe" not in diffrax_exe:  # rtol is traced: one compilation serves every rtol
                diffrax_exe["setup"], diffrax_exe["exe"] = jit_compiled(jax.value_and_grad(diffrax_loss), c_jax, 1e-8)
            setup, exe = diffrax_exe["setup"], diffrax_exe["exe"]

            def call():
                L, g = jax.block_until_ready(exe(c_jax, rtol))
                return float(L), np.asarray(g), 0

            return setup, call

        methods.append(("diffrax Kvaerno5, RecursiveCheckpointAdjoint (y)", f"rtol = {rtol:g}", prepare_diffrax,
                        "diffrax"))  # fmt: skip

    rows = []
    for name, setting, prepare, family in methods:
        row = {"name": name, "setting": setting, "family": family, "times": []}
        try:
            row["setup"], row["call"] = prepare()
            start = time.perf_counter()
            L, g, status = row["call"]()  # warm-up; its answer is the one checked
            row["first"] = time.perf_counter() - start
            if status != 0 or not (np.isfinite(L) and np.all(np.isfinite(g))):
                row["status"] = f"stopped (status {status})" if status else "non-finite loss or gradient"
            else:
                row["status"], row["L"], row["g"], row["error"] = "ok", L, g, _scaled_error(g, g_ref, c)
        except Exception as error:  # noqa: BLE001 (a failing method is reported)
            inner = re.search(r"EquinoxRuntimeError: ([^\n.]*)", str(error))  # equinox's runtime checks
            row["status"] = f"failed: {inner.group(1).strip()}" if inner else f"failed: {_one_line(error)}"
        rows.append(row)
        print(f"  [P4 {name} {setting}: {row['status']} {row.get('error', '')}]", file=sys.stderr, flush=True)
    for _ in range(repeats):
        for row in rows:
            if row["status"] == "ok":
                start = time.perf_counter()
                row["call"]()
                row["times"].append(time.perf_counter() - start)
    for row in rows:
        if row["times"]:
            row["median"] = float(np.median(row["times"]))
            row["overhead"] = row["setup"] + row["first"] - row["median"]
    base_row = rows[0]
    base = base_row.get("median", math.nan)
    emit("| method | setting | status | L | gradient error | median s | first-call overhead s | time / peeljax's |")
    emit("|---|---|---|---:|---:|---:|---:|---:|")
    for r in rows:
        L = f"{r['L']:.4e}" if "L" in r else "–"
        error = f"{r['error']:.1e}" if "error" in r else "–"
        median = f"{r['median']:.4f}" if "median" in r else "–"
        overhead = f"{r['overhead']:.1f}" if "overhead" in r else f"{r['setup']:.1f}" if "setup" in r else "–"
        ratio = f"{r['median'] / base:.2f}" if "median" in r else "–"
        emit(f"| {r['name']} | {r['setting']} | {r['status']} | {L} | {error} | {median} | {overhead} | {ratio} |")
    if not settings["rtols_diffrax"]:
        emit("| diffrax Kvaerno5, RecursiveCheckpointAdjoint (y) | – | not run in this mode (full mode only: its "
             "compilation alone takes ~1 min) | – | – | – | – | – |")  # fmt: skip
    emit()
    emit(f"Medians of {repeats} round-robin runs after a warm-up call. First-call overhead: compile (JAX's lower + "
         "compile) or construction (CasADi's integrator and derivative functions, built lazily) plus the first call, "
         "minus the median (diffrax: rtol is traced, so its one compilation is listed on each of its rows; failed "
         "rows: the compile or construction time alone).")  # fmt: skip
    fd_row = next((r for r in rows if r["family"] == "fd" and r["name"].endswith("peeljax") and "g" in r), None)
    if "g" in base_row and fd_row is not None:
        emit(f"peeljax's reverse-mode gradient and its own central differences (same N) differ by "
             f"{_scaled_error(base_row['g'], fd_row['g'], c):.1e} (the same measure): the reverse mode is the exact "
             "gradient of the discrete loss; its error against g_ref is the discretization error of the α-method.")
    emit()
    # Equal accuracy: for each peeljax setting, the cheapest setting of each other family whose error is ≤ its own.
    families = (("casadi", "CasADi forward sensitivities"), ("fd", "finite differences (any)"),
                ("diffrax", "diffrax adjoint"), ("peeljax", "peeljax uniform mesh"),
                ("adaptive", "peeljax adaptive α"))  # fmt: skip
    emit("Time of the cheapest setting of each peer with a gradient error ≤ peeljax's (within 5 %), divided by "
         "peeljax's time (> 1: peeljax faster), for each setting of peeljax on the uniform mesh and of the adaptive "
         "α-method:")  # fmt: skip
    emit()
    emit("| peeljax setting | gradient error | median s | " + " | ".join(label for _, label in families) + " |")
    emit("|---|---:|---:|" + "---|" * len(families))
    verdicts = []
    for p_row in (r for r in rows if r["family"] in ("peeljax", "adaptive") and "median" in r):
        cells = []
        for family, label in families:
            if family == p_row["family"]:
                cells.append("–")
                continue
            timed = [r for r in rows if r["family"] == family and "median" in r]
            if not timed:
                cells.append("not run")
                continue
            equal = [r for r in timed if r["error"] <= 1.05 * p_row["error"]]
            if not equal:
                cells.append("none as accurate")
                verdicts.append((p_row, label, None))
                continue
            best = min(equal, key=lambda r: r["median"])
            ratio = best["median"] / p_row["median"]
            cells.append(f"{ratio:.2f} ({best['setting']}{', ' + best['name'].split(' of ')[-1] if family == 'fd' else ''})")
            verdicts.append((p_row, label, ratio))
        label = p_row["setting"] if p_row["family"] == "peeljax" else f"adaptive α, {p_row['setting']}"
        emit(f"| {label} | {p_row['error']:.1e} | {p_row['median']:.4f} | " + " | ".join(cells) + " |")
    emit()
    lines = []
    for p_row in (r for r in rows if r["family"] == "peeljax" and "median" in r):
        for label in ("CasADi forward sensitivities", "finite differences (any)"):
            found = [v[2] for v in verdicts if v[0] is p_row and v[1] == label]
            if not found:
                state = "not run"
            elif found[0] is None:
                state = "no peer setting tried is as accurate"
            else:
                state = f"{'met' if found[0] > 1 else 'missed'} ({found[0]:.2f}×)"
            lines.append(f"{p_row['setting'].split(' (')[0]}: faster than {label.split(' (')[0]}: {state}")
    emit("Targets (issue 6), at equal gradient error: " + "; ".join(lines)
         + f". P4 time: {time.perf_counter() - started:.0f} s.")  # fmt: skip
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
    except NotRun as error:  # an optional peer whose dependency is missing here
        return [{"setting": None, "status": f"not run here: {error}"}]
    except Exception as error:  # noqa: BLE001 (a missing optional peer is reported, not fatal)
        return [{"setting": None, "status": f"unavailable: {_one_line(error)}"}]
    scale = np.max(np.abs(v_ref))
    for setting in peer.settings:
        try:
            started = time.perf_counter()
            v = peer.run(setting)
            first = time.perf_counter() - started
        except Exception as error:  # noqa: BLE001 (a failing setting is reported)
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
        except Exception:  # noqa: BLE001
            out.append(f"{module} missing")
    return ", ".join(out)


def work_precision_plot(results, path):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    taus = sorted(results)
    fig = Figure(figsize=(5.5 * len(taus), 4.5), layout="constrained")
    axes = fig.subplots(1, len(taus), squeeze=False)[0]
    palette = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:gray",
               "tab:olive", "tab:cyan", "black", "gold")  # fmt: skip
    for ax, tau in zip(axes, taus):
        for i, (name, rows) in enumerate(results[tau].items()):
            pts = sorted((r["error"], r["median_s"]) for r in rows if r.get("status") == "ok")
            if pts:
                errors, times = zip(*pts)
                marker = "o-" if i < 10 else "s--"  # more peers than tab10 has colours
                ax.loglog(errors, times, marker, color=palette[i % len(palette)], label=name, lw=1.2, ms=4)
        ax.axvline(TARGET, color="0.6", ls=":", lw=1)
        ax.set_xlabel("max |v − v_ref| over 301 times [m/s]")
        ax.set_ylabel("wall time per run [s]")
        ax.set_title(f"V = {V} m/s, τ = {tau} s, t ∈ [0, {T_FINAL:g}] s")
        ax.grid(True, which="both", alpha=0.3)
    axes[-1].legend(fontsize=8)
    FigureCanvasAgg(fig).print_figure(path, dpi=120)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer τ, settings, repeats; P3 on 16 trajectories")
    parser.add_argument("--repeats", type=int, default=None, help="timed runs per setting (default 5, quick 3)")
    parser.add_argument("--smoke", action="store_true", help="one setting per peer, one repeat: checks the script runs")
    parser.add_argument("--only", nargs="+", choices=("P1", "P3", "P4", "P5"), default=("P1", "P3", "P4", "P5"),
                        help="run only these problems (P1 includes P2)")  # fmt: skip
    parser.add_argument("--out", default=None, help="markdown output (default results/latest[_quick].md)")
    args = parser.parse_args(argv)
    repeats = args.repeats or (1 if args.smoke else 3 if args.quick else 5)
    taus = (0.01,) if (args.quick or args.smoke) else (0.01, 0.1)
    adaptive_rtols = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)  # ~1-15 ms a run: the whole ladder in every mode
    if args.smoke:
        steps, rtols = (300,), (1e-4,)
        adaptive_rtols, petsc_rtols = (1e-5,), (1e-3,)
        p3 = {"n_tau": 2, "per_v": 2, "radau_count": 2, "repeats": 1, "settings": {
            "rtols_adaptive": (1e-4,), "steps": (300,), "rtols_diffrax": (1e-3,), "rtols_loop": (1e-4,),
            "rtols_radau": (1e-5,)}}
        p4 = {"repeats": 1, "settings": {
            "steps": (82,), "rtols_casadi": (1e-6,), "rtols_casadi_fd": (1e-8,), "rtols_diffrax": (),
            "rtols_adaptive": (1e-6,)}}
    elif args.quick:
        steps, rtols = (300, 1200, 4800, 9600), (1e-3, 1e-5, 1e-7)
        petsc_rtols = (1e-2, 1e-3, 1e-4, 1e-5)
        p3 = {"n_tau": 4, "per_v": 4, "radau_count": 4, "repeats": 2, "settings": {
            "rtols_adaptive": P3_ADAPTIVE_RTOLS, "steps": (9600,), "rtols_diffrax": (1e-3, 1e-4, 1e-5),
            "rtols_loop": (1e-4, 1e-5, 1e-6),
            "rtols_radau": (1e-5, 1e-7)}}
        p4 = {"repeats": 3, "settings": {
            "steps": (82,), "rtols_casadi": (1e-4, 1e-6, 1e-8), "rtols_casadi_fd": (1e-8,), "rtols_diffrax": (),
            "rtols_adaptive": (1e-4, 1e-6, 1e-8)}}
    else:
        steps, rtols = (300, 600, 1200, 2400, 4800, 9600, 19200, 38400), (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9)
        petsc_rtols = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6)  # 1e-7 takes ~10 s a run (ψ and its Jacobian in Python)
        p3 = {"n_tau": 256, "per_v": 8, "radau_count": 8, "repeats": 1, "settings": {
            "rtols_adaptive": P3_ADAPTIVE_RTOLS, "steps": (4800, 9600, 19200),
            "rtols_diffrax": (1e-2, 1e-3, 1e-4, 1e-5, 1e-6),
            "rtols_loop": (1e-3, 1e-4, 1e-5, 1e-6, 1e-7), "rtols_radau": (1e-5, 1e-6, 1e-7)}}
        p4 = {"repeats": 5, "settings": {
            "steps": (82, 820, 8200), "rtols_casadi": (1e-4, 1e-6, 1e-8), "rtols_casadi_fd": (1e-6, 1e-8),
            "rtols_diffrax": (1e-6, 1e-8, 1e-10), "rtols_adaptive": (1e-4, 1e-6, 1e-8)}}
    started = time.perf_counter()

    out = []

    def emit(line=""):
        print(line, flush=True)
        out.append(line)

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    emit("# peeljax against its peers (issue 6: P1–P5)")
    emit()
    emit(f"- CPU: {cpu_model()}, {os.cpu_count()} logical cores; load average at start {load:.2f}")
    emit(f"- {versions()}")
    emit(f"- problem: V = {V}, t ∈ [0, {T_FINAL:g}] s, paper geometry and initial data; error = max over the")
    emit(f"  301 times 0, 0.01, …, 3 s of |v − v_ref|, v_ref = diffrax Kvaerno5 at rtol {REF_RTOL:g}, atol {REF_ATOL:g}")
    emit(f"- medians of {repeats} runs after a warm-up run; adaptive peers use atol = 1e-2·rtol, "
         f"peeljax adaptive α atol = {ADAPTIVE_ALPHA_ATOL:g}·rtol")
    emit()

    results = {}
    for tau in taus if "P1" in args.only else ():
        v_ref = reference(tau)
        peers = [
            PeeljaxAlpha(tau, steps),
            PeeljaxAdaptive(tau, adaptive_rtols),
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
            PetscAlphaPeer(tau, petsc_rtols),
        ]
        adaptive = next(peer for peer in peers if isinstance(peer, PeeljaxAdaptive))
        results[tau] = {}
        for peer in peers:
            results[tau][peer.name] = check(peer, v_ref)
            print(f"  [τ = {tau}: {peer.name} checked]", file=sys.stderr, flush=True)
        time_round_robin(peers, results[tau], repeats)
        for peer in peers:
            if hasattr(peer, "close"):
                peer.close()

        emit(f"## τ = {tau}")
        emit()
        emit(f"### (P1) the cheapest setting with error ≤ {TARGET:g}")
        emit()
        base = cheapest_at(results[tau]["peeljax α-method"], TARGET)
        base_adaptive = cheapest_at(results[tau][PeeljaxAdaptive.name], TARGET)
        emit("| method | setting | error | median s | time / peeljax's | time / peeljax adaptive α's |")
        emit("|---|---:|---:|---:|---:|---:|")
        for peer in peers:
            best = cheapest_at(results[tau][peer.name], TARGET)
            if best is None:
                statuses = sorted({r["status"] for r in results[tau][peer.name] if r.get("status") != "ok"})
                emit(f"| {peer.name} | – | – | – | not reached ({'; '.join(statuses) or 'error above target'}) | – |")
                continue
            ratio = best["median_s"] / base["median_s"] if base else math.nan
            ratio_adaptive = best["median_s"] / base_adaptive["median_s"] if base_adaptive else math.nan
            emit(
                f"| {peer.name} | {peer.setting_name} = {best['setting']:g} | {best['error']:.1e} "
                f"| {best['median_s']:.4f} | {ratio:.2f} | {ratio_adaptive:.2f} |"
            )
        emit()
        emit("Both ratios are of medians measured round-robin in this run (> 1: that peeljax method is faster).")
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
        for peer in peers:
            if hasattr(peer, "describe") and getattr(peer, "stats", None):
                what = ("accepted/rejected steps, Newton iterations" if isinstance(peer, PeeljaxAdaptive)
                        else f"PETSc {getattr(peer, 'version', '?')}, ρ∞ = {getattr(peer, 'radius', math.nan):g}, "
                             f"first step {PETSC_DT0:g} s: steps/rejected, SNES iterations")  # fmt: skip
                emit(f"- {peer.name} ({what}): "
                     + "; ".join(f"rtol {rtol:g}: {peer.describe(rtol)}" for rtol in peer.settings if rtol in peer.stats))
        adaptive_ok = [r for r in results[tau][PeeljaxAdaptive.name] if r.get("status") == "ok"]
        if len(adaptive_ok) >= 3:
            steps_taken = np.array([int(adaptive.stats[r["setting"]]["accepted_steps"]) for r in adaptive_ok], float)
            slope = np.polyfit(np.log(steps_taken), np.log([r["error"] for r in adaptive_ok]), 1)[0]
            emit(f"- {PeeljaxAdaptive.name}: error ∝ (accepted steps)^{slope:.2f} over rtol "
                 f"{adaptive_ok[0]['setting']:g} … {adaptive_ok[-1]['setting']:g} (least squares; −2 for a second-order method)")
        emit()

    if "P3" in args.only:
        batch_table(emit, p3["n_tau"], p3["per_v"], p3["settings"], args.repeats or p3["repeats"], p3["radau_count"])
    if "P4" in args.only:
        gradient_table(emit, p4["settings"], args.repeats or p4["repeats"])
    if "P5" in args.only:
        direct_dae_table(emit, (1.1,) if args.smoke else (1.1, 2.0, 4.0), (1e-6,) if args.smoke else (1e-4, 1e-6, 1e-8))

    results_dir = HERE / "results"
    results_dir.mkdir(exist_ok=True)
    suffix = "_quick" if args.quick else "_smoke" if args.smoke else ""
    path = Path(args.out) if args.out else results_dir / f"latest{suffix}.md"
    plot_path = path.parent / f"work_precision{suffix}.png"
    if results:
        work_precision_plot(results, plot_path)
        emit(f"Work-precision plot: `{plot_path.name}`.")
    emit(f"Total benchmark time: {time.perf_counter() - started:.0f} s.")
    path.write_text("\n".join(out) + "\n")
    print(f"(written to {path})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
