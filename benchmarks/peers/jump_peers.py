"""The peers of ``stick_slip.py`` (P6): the DAE (τ = 0) carried through φ's folds by jumps.

Each peer's ``run(rtol)`` returns the jump times over [0, ``T_FINAL``] at V = ``V`` (the
stick → slip and slip → stick jumps of v at fixed x, in order); ``prepare()`` builds or
compiles what the runs need, outside the timed region. Every peer uses atol = ``ATOL_RATIO``·rtol.

The peers (each class's docstring says how it runs): :class:`PeeljaxDAE` (``peeljax.simulate``, the
fold located inside the compiled loop), :class:`ScipyEvents` (``solve_ivp`` with a terminal event,
restarted after each jump; ``refine=True``: ``tests/jump_reference.py``'s algorithm), :class:`DiffraxEvents`
and :class:`DiffraxWhileLoop` (``diffrax.Event`` on ``peeljax.ConstrainedDAE``, restarted on the host
or inside one ``jax.lax.while_loop``), :class:`CasadiEvents` (cvodes with CasADi's experimental
events) and :class:`InertialModel` (m·v̇ = G − φ; its jumps: v crossing √(v̂·v̌)).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import ClassVar

import numpy as np

from peers import Peer

V = 1.1
T_FINAL = 3.0
ATOL_RATIO = 1e-3
TESTS = Path(__file__).resolve().parents[2] / "tests"


def jump_reference():
    """``tests/jump_reference.py`` (the independent scipy implementation with the arclength refinement)."""
    if str(TESTS) not in sys.path:
        sys.path.insert(0, str(TESTS))
    import jump_reference

    return jump_reference


class JumpPeer(Peer):
    """A peer of P6 (τ = 0): ``run_stats`` gives the counts its last run kept in ``_last`` (None before one)."""

    _last = None

    def run_stats(self, rtol):
        return self._last


# --------------------------------------------------------------------------- peeljax
SOLVERS = {"alpha": "AlphaMethod", "tsit5": "Tsit5", "dopri5": "Dopri5", "dopri8": "Dopri8", "kvaerno5": "Kvaerno5"}


def check_solver(name):
    if name is not None and name not in SOLVERS:
        raise ValueError(f"unknown solver {name!r}: one of {', '.join(SOLVERS)}")


def solver_named(name):
    """``peeljax.AlphaMethod()`` for "alpha", else the diffrax solver of that name (:data:`SOLVERS`); None → None."""
    check_solver(name)
    if name is None:
        return None
    if name == "alpha":
        import peeljax

        return peeljax.AlphaMethod()
    import diffrax

    return getattr(diffrax, SOLVERS[name])()


class PeeljaxDAE(JumpPeer):
    """``peeljax.simulate(V, tau=0, rtol, atol, solver=…)``: output at [0, t_final] only (``ts``), so no step buffer.

    ``solver``: None (peeljax's default) or a name of :data:`SOLVERS` (:func:`solver_named`); ``in_time``:
    that Runge–Kutta solver on the DAE in time (v solved at every evaluation), not in pseudo-time.
    """

    def __init__(self, settings, V=V, max_steps=1_000_000, solver=None, in_time=False):
        super().__init__(0.0, settings)
        self.V, self.max_steps, self.solver, self.in_time = V, max_steps, solver, in_time
        check_solver(solver)
        if in_time and solver in (None, "alpha"):
            raise ValueError("in_time applies to a Runge-Kutta solver (the α-method runs in time)")
        what = "" if solver is None else f", {solver}{' in time' if in_time else ''}"
        self.name = f"peeljax simulate(tau=0{what})"

    def prepare(self):
        import peeljax
        from peeljax.integrators import RungeKutta

        self._pj = peeljax
        self._ts = np.array([0.0, T_FINAL])
        self._solver = solver_named(self.solver)
        if self.in_time:  # the DAE in time (v solved from the constraint), not in pseudo-time
            self._solver = RungeKutta(self._solver, ())
        self._last = None

    def run(self, rtol):
        sol = self._pj.simulate(
            V=self.V, tau=0, t_final=T_FINAL, rtol=rtol, atol=ATOL_RATIO * rtol, ts=self._ts,
            max_steps=self.max_steps, solver=self._solver,
        )  # fmt: skip
        if sol.status_name != "completed":
            raise RuntimeError(f"stopped at t = {float(sol.t_stop):.6g}: {sol.reason}")
        if sol.jumps is None:
            raise RuntimeError("no jump record (the folds were not located)")
        self._last = sol.stats
        return sol.jumps.as_numpy()["jump_t"]

    def run_stats(self, rtol):
        if self._last is None:
            return None
        keys = ("accepted_steps", "rejected_steps", "newton_iterations")
        return {key: int(self._last[key]) for key in keys if key in self._last}


# --------------------------------------------------------------------------- scipy
def _scalar_law(V):
    """φ(·, V) and dφ/d(log v) = v·∂φ/∂v as scalar functions of v (the reference's own law)."""
    phi, slope = jump_reference()._scalar_law(V)
    return phi, lambda v: v * slope(v)


class _Branch:
    """An increasing branch [lo, hi] of φ(·, V): v(G) by safeguarded Newton in log v, warm-started."""

    def __init__(self, law, lo, hi):
        self.phi, self.slope = law
        self.lo, self.hi = lo, min(hi, 1e3)
        self.phi_lo, self.phi_hi = self.phi(lo), (self.phi(hi) if math.isfinite(hi) else math.inf)
        self.w = math.log(math.sqrt(max(lo, 1e-6) * self.hi))

    def velocity(self, G):
        if G <= self.phi_lo:
            return self.lo
        if G >= self.phi_hi:
            return self.hi
        a, b = (math.log(self.lo) if self.lo > 0 else -690.0), math.log(self.hi)
        w = min(max(self.w, a), b)
        for _ in range(100):
            v = math.exp(w)
            r = self.phi(v) - G
            if r < 0:
                a = w
            else:
                b = w
            s = self.slope(v)
            new = w - r / s if s > 0 else math.nan
            if not a < new < b:
                new = 0.5 * (a + b)
            done = abs(new - w) <= 1e-13
            w = new
            if done:
                break
        self.w = w
        return math.exp(w)


def scipy_events_run(V, rtol, atol, method="LSODA", t_final=T_FINAL):
    """Jump times by ``solve_ivp`` with a terminal event at the fold, restarted after each jump (no refinement).

    Returns (jump times, right-hand-side evaluations).
    """
    from scipy.integrate import solve_ivp

    ref = jump_reference()
    R, I, K = ref.R, ref.I, ref.K_OVER_L
    law = _scalar_law(V)
    v_hat, v_min = ref.fold_velocities(V)
    folds = not math.isnan(v_hat)
    stick = _Branch(law, 0.0, v_hat if folds else math.inf)
    slip = _Branch(law, v_min, math.inf) if folds else None

    def shear(x):
        return (1.0 + math.sin(x[0])) * K * x[2]

    def rhs(_, x, branch):
        v = branch.velocity(shear(x))
        slip_rate = x[1] - v / R
        s = math.sin(x[0])
        return [slip_rate, -R * s * K * x[2] / I, R * s * slip_rate + V - v]

    def to_slip(_, x, branch):
        return shear(x) - branch.phi_hi

    def to_stick(_, x, branch):
        return shear(x) - branch.phi_lo

    to_slip.terminal = to_stick.terminal = True
    to_slip.direction, to_stick.direction = 1.0, -1.0
    t, x, sticking, jumps, nfev = 0.0, ref.initial_state(V)[:3], True, [], 0
    while t < t_final:
        branch = stick if sticking else slip
        events = None if not folds else (to_slip if sticking else to_stick)
        sol = solve_ivp(rhs, (t, t_final), x, method=method, rtol=rtol, atol=atol, events=events, args=(branch,))
        nfev += sol.nfev
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed at t = {sol.t[-1]:.9g} s: {sol.message}")
        if sol.status != 1:
            break
        t, x = float(sol.t_events[0][0]), sol.y_events[0][0]
        jumps.append(t)
        sticking = not sticking
        (stick if sticking else slip).velocity(shear(x))  # warm start on the landing branch
    return np.array(jumps), nfev


class ScipyEvents(JumpPeer):
    def __init__(self, settings, method="LSODA", refine=False, V=V):
        super().__init__(0.0, settings)
        self.method, self.refine, self.V = method, refine, V
        self.name = f"scipy {method} events" + (" + arclength refinement" if refine else "")

    def prepare(self):
        self._ref = jump_reference()

    def run(self, rtol):
        if self.refine:
            return self._ref.reference_jump_run(self.V, T_FINAL, rtol=rtol, atol=ATOL_RATIO * rtol, method=self.method)[
                "jump_t"
            ]
        jumps, self._last = scipy_events_run(self.V, rtol, ATOL_RATIO * rtol, self.method)
        return jumps

    def run_stats(self, rtol):
        return None if self._last is None or self.refine else {"nfev": self._last}


# --------------------------------------------------------------------------- diffrax
def fold_segment(ode, term, solver, t0, t1, y0, controller, max_steps):
    """One ``diffeqsolve`` from t0 towards t1 stopped by a ``diffrax.Event`` on ``ode.fold_event`` (located by
    ``optimistix.Newton`` on the step's dense output): (t, y after ``ode.jump`` where it hit, hit, solution)."""
    import diffrax
    import jax.numpy as jnp
    import optimistix as optx

    event = diffrax.Event(lambda t, y, args, **kwargs: ode.fold_event(y), root_finder=optx.Newton(rtol=1e-13, atol=1e-13))
    sol = diffrax.diffeqsolve(term, solver, t0, t1, None, y0, saveat=diffrax.SaveAt(t1=True), stepsize_controller=controller,
                              event=event, max_steps=max_steps, throw=False)  # fmt: skip
    t_end, y_end, hit = sol.ts[-1], sol.ys[-1], sol.event_mask
    return t_end, jnp.where(hit, ode.jump(y_end).y, y_end), hit, sol


class DiffraxEvents(JumpPeer):
    """``diffeqsolve`` with ``diffrax.Event`` on ``peeljax.ConstrainedDAE``, restarted on the host after each jump.

    The state is y = (α, ω, u, v) with ψ_v = 0 (``ConstrainedDAE``): v is solved from the
    constraint on the branch y's v lies on at every evaluation; the event is
    ``ConstrainedDAE.fold_event`` (G(x) − φ(v̂, V) on the stick branch, φ(v̌, V) − G(x) on the
    slip branch). The compiled segment (:func:`fold_segment`) also returns the state after the
    jump (v⁺ on the other branch at fixed x), so each restart is one call; the loop is Python.
    """

    def __init__(self, settings, solver_name="Tsit5", V=V, max_steps=1_000_000):
        super().__init__(0.0, settings)
        self.solver_name, self.V, self.max_steps = solver_name, V, max_steps
        self.name = f"diffrax {solver_name} + Event"

    def prepare(self):
        import diffrax
        import equinox as eqx
        import jax.numpy as jnp

        import peeljax

        solver, max_steps = getattr(diffrax, self.solver_name)(), self.max_steps
        self._jnp = jnp
        self._ode = peeljax.ConstrainedDAE(peeljax.PeelingModel(), self.V).with_folds()
        self._y0 = peeljax.PeelingModel().initial_state(self.V)

        @eqx.filter_jit
        def segment(ode, t0, y0, rtol, atol):
            term, controller = diffrax.ODETerm(lambda t, y, args: ode(y)), diffrax.PIDController(rtol=rtol, atol=atol)
            t1, after, hit, sol = fold_segment(ode, term, solver, t0, T_FINAL, y0, controller, max_steps)
            ok = sol.result == diffrax.RESULTS.successful
            return t1, after, hit, ok, sol.stats["num_accepted_steps"], sol.stats["num_rejected_steps"]

        self._segment = segment

    def run(self, rtol):
        jnp = self._jnp
        r, a = jnp.asarray(rtol), jnp.asarray(ATOL_RATIO * rtol)
        t, y, jumps, accepted, rejected = 0.0, self._y0, [], 0, 0
        while True:
            t1, y, hit, ok, n_acc, n_rej = self._segment(self._ode, jnp.asarray(t), y, r, a)
            t, hit = float(t1), bool(hit)
            accepted, rejected = accepted + int(n_acc), rejected + int(n_rej)
            if not hit and not bool(ok):
                raise RuntimeError(f"diffeqsolve stopped at t = {t:.9g} s")
            if not hit or t >= T_FINAL:
                break
            jumps.append(t)
        self._last = {"accepted_steps": accepted, "rejected_steps": rejected, "restarts": len(jumps)}
        return np.array(jumps)


class DiffraxWhileLoop(JumpPeer):
    """The loop diffrax's maintainers recommend for restarting after events (diffrax issue #492).

    One compiled function: a ``jax.lax.while_loop`` whose body runs :func:`fold_segment` (``diffrax.Tsit5()``
    with ``diffrax.PIDController(rtol, atol)``, as :class:`DiffraxEvents`) from the current time, writes the
    event time into a buffer of ``slots`` jump times and restarts from the state after the jump, until
    ``t_final`` (default ``T_FINAL``; or a failed segment, or a full buffer). rtol and
    atol are traced: the program is compiled once, ahead of time, in ``prepare``. The vector
    field is ``ConstrainedDAE.evaluate(y).psi`` on y = (α, ω, u, v) (v solved from the constraint).
    """

    name = "diffrax Tsit5 + Event, one lax.while_loop"

    def __init__(self, settings, V=V, max_steps=1_000_000, slots=512, t_final=T_FINAL):
        super().__init__(0.0, settings)
        self.V, self.max_steps, self.slots, self.t_final = V, max_steps, slots, t_final

    def prepare(self):
        import diffrax
        import jax
        import jax.numpy as jnp

        import peeljax

        solver, max_steps, slots = diffrax.Tsit5(), self.max_steps, self.slots
        model = peeljax.PeelingModel()
        ode = peeljax.ConstrainedDAE(model, self.V).with_folds()
        y0 = jnp.asarray(model.initial_state(self.V))
        t_final = jnp.asarray(self.t_final)
        term = diffrax.ODETerm(lambda t, y, args: ode.evaluate(y).psi)

        def run_all(rtol, atol):
            controller = diffrax.PIDController(rtol=rtol, atol=atol)

            def cond(carry):
                t, _, n, _, _, _, ok = carry
                return ok & (t < t_final) & (n < slots)

            def body(carry):
                t, y, n, buffer, accepted, rejected, _ = carry
                t1, y, hit, sol = fold_segment(ode, term, solver, t, t_final, y, controller, max_steps)
                ok = hit | (sol.result == diffrax.RESULTS.successful)
                buffer = jnp.where(hit, buffer.at[jnp.minimum(n, slots - 1)].set(t1), buffer)
                return (
                    t1, y, n + hit.astype(n.dtype), buffer,
                    accepted + sol.stats["num_accepted_steps"], rejected + sol.stats["num_rejected_steps"], ok,
                )  # fmt: skip

            zero = jnp.zeros((), jnp.int32)
            carry = (jnp.zeros(()), y0, zero, jnp.full(slots, jnp.nan), zero, zero, jnp.asarray(True))
            t, _, n, buffer, accepted, rejected, ok = jax.lax.while_loop(cond, body, carry)
            return t, n, buffer, accepted, rejected, ok

        rtol = jnp.asarray(float(self.settings[0]))
        self._run_all = jax.jit(run_all).lower(rtol, ATOL_RATIO * rtol).compile()
        self._jnp = jnp

    def run(self, rtol):
        jnp = self._jnp
        r = jnp.asarray(float(rtol))
        t, n, buffer, accepted, rejected, ok = self._run_all(r, jnp.asarray(ATOL_RATIO * float(rtol)))
        t, n, ok = float(t), int(n), bool(ok)
        self._last = {"accepted_steps": int(accepted), "rejected_steps": int(rejected), "restarts": n}
        if not ok:
            raise RuntimeError(f"diffeqsolve stopped at t = {t:.9g} s")
        if n >= self.slots and t < self.t_final:
            raise RuntimeError(f"the buffer of {self.slots} jump times is full at t = {t:.9g} s")
        return np.asarray(buffer)[:n]


# --------------------------------------------------------------------------- CasADi
class CasadiEvents(JumpPeer):
    """CasADi cvodes with CasADi 3.8's experimental events (``dae["zero"]`` and the ``transition`` option).

    The model is :func:`casadi_event_model`'s, with a register of the last four jump times: CasADi
    reports no event times, so they are read back from the states at 3000 output times (≤ 4 jumps
    apart). The two Newton steps of v(x) carry the implicit function theorem's derivative into
    CVODES's Jacobian. CasADi only reports zeros crossed from + to − (measured: with the opposite
    signs no event fires). ``event_tol`` 1e-14 and ``max_event_iter`` 100: the defaults leave every
    stick → slip jump ~4e-5 s early.
    """

    REGISTER, OUTPUTS, BISECTIONS = 4, 3000, 56
    OPTIONS: ClassVar[dict] = {
        "event_tol": 1e-14,
        "max_event_iter": 100,
        "max_events": 100_000,
        "max_num_steps": 1_000_000,
    }

    def __init__(self, settings, V=V):
        super().__init__(0.0, settings)
        self.V = V
        self.name = "CasADi cvodes + events (experimental)"
        self._integrators = {}

    def prepare(self):
        import casadi as ca

        ref = jump_reference()
        v_hat, v_min = ref.fold_velocities(self.V)
        bounds = (math.log(v_hat), math.log(v_min), float(ref.phi(v_hat, self.V)), float(ref.phi(v_min, self.V)))
        X, ode, zero, post, t, index = casadi_event_model(ca, ref, self.V, bounds, self.REGISTER, self.BISECTIONS)
        empty = ca.SX(0, 1)
        self._transition = ca.Function(
            "transition", [index, t, X, empty, empty, empty], [post, empty], ca.event_in(), ca.event_out()
        )
        self._dae = {"x": X, "ode": ode, "zero": zero}
        self._x0 = np.concatenate([ref.initial_state(self.V)[:3], [0.0, 0.0], np.full(self.REGISTER, -1.0)])
        self._ca = ca

    def _integrator(self, rtol):
        if rtol not in self._integrators:
            grid = np.linspace(0.0, T_FINAL, self.OUTPUTS + 1)[1:]
            options = {"transition": self._transition, "reltol": rtol, "abstol": ATOL_RATIO * rtol, **self.OPTIONS}
            self._integrators[rtol] = self._ca.integrator("F", "cvodes", self._dae, 0.0, grid, options)
        return self._integrators[rtol]

    def run(self, rtol):
        return read_jump_register(np.asarray(self._integrator(rtol)(x0=self._x0)["xf"]), self.REGISTER)


def casadi_event_model(ca, ref, V, bounds, register, bisections):
    """The DAE with jumps as CasADi symbols, for CVODES with CasADi's events (:class:`CasadiEvents`).

    State X = (α, ω, u, b, n, s1 … s_register): b the branch (0 stick, 1 slip), n the jump
    count, s the last jump times; ``bounds`` = (log v̂, log v̌, φ(v̂, V), φ(v̌, V)). v(x) on branch b:
    ``bisections`` bisections in log v and two Newton steps (CasADi's own derivative of φ in
    w = log v), clamped at the branch's ends.
    Returns (X, ode, zero, post, t, index): the zero function fires on + → − crossings; post is
    the state after a jump at time t (branch flipped, count + 1, t pushed into the register).
    """
    c = ref.PAPER
    log_hat, log_min, phi_max, phi_min = bounds
    offset = c["c5"] * V ** c["p5"]
    c9 = c["c6"] - c["c7"] * V ** c["p7"] - c["c8"] * V ** c["p8"]

    def phi(w):
        v = ca.exp(w)
        return (
            c["c1"] * v ** c["p1"] + c["c2"] * v ** c["p2"] + c["c3"] * ca.exp(v / c["c4"]) - offset - c9 * v ** c["p9"]
        )

    X = ca.SX.sym("X", 5 + register)
    alpha, omega, u, branch, count = X[0], X[1], X[2], X[3], X[4]
    G = (1 + ca.sin(alpha)) * ref.K_OVER_L * u
    slip = branch > 0.5
    lo = ca.if_else(slip, log_min, math.log(1e-100))
    hi = ca.if_else(slip, math.log(100.0), log_hat)
    a, b = lo, hi
    for _ in range(bisections):
        mid = 0.5 * (a + b)
        below = phi(mid) < G
        a, b = ca.if_else(below, mid, a), ca.if_else(below, b, mid)
    ws = ca.SX.sym("w")
    slope = ca.jacobian(phi(ws), ws)
    w = 0.5 * (a + b)
    for _ in range(2):
        w = w - (phi(w) - G) / ca.substitute(slope, ws, w)
    phi_lo = ca.if_else(slip, phi_min, phi(math.log(1e-100)))
    phi_hi = ca.if_else(slip, ca.inf, phi_max)
    v = ca.exp(ca.if_else(G >= phi_hi, hi, ca.if_else(G <= phi_lo, lo, w)))
    slip_rate, s = omega - v / ref.R, ca.sin(alpha)
    ode = ca.vertcat(
        slip_rate,
        -ref.R * s * ref.K_OVER_L * u / ref.I,
        ref.R * s * slip_rate + V - v,
        ca.SX.zeros(2 + register),
    )
    t, index = ca.SX.sym("t"), ca.SX.sym("index")
    post = ca.vertcat(alpha, omega, u, 1 - branch, count + 1, t, X[5 : 4 + register])
    return X, ode, ca.if_else(slip, G - phi_min, phi_max - G), post, t, index


def read_jump_register(xf, register):
    """The jump times from CasADi's states at the output times (count in row 4, the last times after it)."""
    count = np.concatenate([[0], np.round(xf[4]).astype(int)])
    jumps = []
    for k in range(1, count.size):
        new = count[k] - count[k - 1]
        if new > register:
            raise RuntimeError(f"{new} jumps between two output times: the register holds {register}")
        jumps += list(xf[5 : 5 + new, k - 1][::-1])
    return np.array(jumps)


# --------------------------------------------------------------------------- the inertial model
class InertialModel(JumpPeer):
    """``integrate_inertial`` (diffrax Kvaerno5, m·v̇ = G − φ) at mass m; jumps: v crossing √(v̂·v̌).

    The crossing times are interpolated linearly in log v between the saved accepted steps
    (a crossing lasts O(m) and the steps there are shorter still).
    """

    def __init__(self, settings, m, V=V, max_steps=400_000):
        super().__init__(0.0, settings)
        self.m, self.V, self.max_steps = m, V, max_steps
        self.name = f"inertial model m = {m:g} kg (diffrax Kvaerno5)"

    def prepare(self):
        import peeljax
        from peeljax.alternatives.inertial import integrate_inertial

        folds = peeljax.phi_folds(peeljax.PeelingModel(), self.V)
        self._log_split = 0.5 * math.log(float(folds.v_max) * float(folds.v_min))
        self._integrate = integrate_inertial

    def run(self, rtol):
        sol = self._integrate(
            V=self.V, m=self.m, t_final=T_FINAL, rtol=rtol, atol=ATOL_RATIO * rtol, save_steps=True,
            max_steps=self.max_steps,
        )  # fmt: skip
        valid = np.asarray(sol.valid)
        if not bool(sol.completed):
            raise RuntimeError(f"stopped at t = {float(sol.t_stop):.6g} s")
        t, w = np.asarray(sol.ts)[valid], np.log(np.asarray(sol.ys)[valid, 3]) - self._log_split
        i = np.flatnonzero(np.sign(w[:-1]) != np.sign(w[1:]))
        self._last = {"saved_steps": int(valid.sum())}
        return t[i] - w[i] * (t[i + 1] - t[i]) / (w[i + 1] - w[i])
