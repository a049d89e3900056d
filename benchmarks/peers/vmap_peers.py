"""The per-lane peers of ``vmap_lane_cost.py``: one trajectory of the V-map (τ = 0, jumps at φ's folds) per call.

Every peer's ``run(V, rtol)`` returns the jump times over [0, ``T_FINAL``] at pull velocity V
(stick → slip and slip → stick alternating, the first stick → slip); ``prepare(rtols)`` builds
what the runs at those tolerances need (compilation, solver objects), outside the timed calls.
atol = ``ATOL_RATIO``·rtol throughout.

* :class:`PeeljaxSimulate`: ``peeljax.simulate(V, tau=0, rtol=…)``, one compiled program (V is
  traced) called once per V: the step's cost without the sweep's batching;
* :class:`ScipyLoop`: ``jump_peers.scipy_events_run`` (``solve_ivp`` LSODA with a terminal
  event at the fold, restarted after each jump, plain-Python right-hand side);
* :class:`CvodeEvents`: SUNDIALS CVODE through scikit-sundae with its rootfinding
  (``eventsfn``, ``num_events``): one solver object per rtol, built once; per V the host
  re-initializes it (``init_step``) at t = 0 and after each jump, with the branch and the law
  of V in its (mutable) ``userdata``; the right-hand side and the branch root are the same
  plain-Python ones as the scipy peer's;
* :class:`CasadiEventsV`: CasADi cvodes with CasADi 3.8's experimental events, as
  ``jump_peers.CasadiEvents`` (all jumps in one call, the branch flipped by a ``transition``
  function), but with V and the fold values as parameters, so one integrator per rtol serves
  every V (built once, outside the timed calls).
"""

from __future__ import annotations

import math
import os
import time
from typing import ClassVar

import numpy as np

from peers.jump_peers import (
    ATOL_RATIO,
    T_FINAL,
    _Branch,
    _scalar_law,
    casadi_event_model,
    jump_reference,
    read_jump_register,
    scipy_events_run,
)


def reference_jumps(V, rtol, atol):
    """The reference's jump times at V (``tests/jump_reference.py``; a function a process pool can call)."""
    return jump_reference().reference_jump_run(float(V), T_FINAL, rtol=rtol, atol=atol, method="LSODA")["jump_t"]


class LanePeer:
    """A per-V method with a ladder of rtol; ``run(V, rtol)`` returns the jump times of one lane."""

    name = ""

    def __init__(self, settings):
        self.settings = list(settings)
        self._setup = {}  # rtol -> seconds of its one-time set-up

    def prepare(self, rtols) -> None:
        """Build or compile what runs at these tolerances need (outside the timed region)."""

    def run(self, V, rtol) -> np.ndarray:
        raise NotImplementedError

    def setup_seconds(self, rtol) -> float:
        """The one-time set-up the runs at ``rtol`` needed (compilation, solver objects)."""
        return self._setup.get(rtol, 0.0)

    def close(self) -> None:
        """Release what ``prepare`` started."""


# --------------------------------------------------------------------------- peeljax
class PeeljaxSimulate(LanePeer):
    """``peeljax.simulate(V, tau=0, rtol, atol, ts=[0, T])``: one compiled program, called per V (one core)."""

    name = "peeljax.simulate loop"

    def __init__(self, settings, max_steps=400_000, max_jumps=8192):
        super().__init__(settings)
        self.max_steps, self.max_jumps = max_steps, max_jumps

    def prepare(self, rtols):
        import peeljax

        self._pj = peeljax
        self._ts = np.array([0.0, T_FINAL])
        # the compilation: the first call minus a warm one (V and the tolerances are traced: one
        # program for every rung, checked by timing a first call at each)
        for rtol in rtols:
            started = time.perf_counter()
            self.run(8.0, rtol)
            first = time.perf_counter() - started
            started = time.perf_counter()
            self.run(8.0, rtol)
            self._setup[rtol] = max(first - (time.perf_counter() - started), 0.0)
        compiled = max(self._setup.values(), default=0.0)
        self._setup = dict.fromkeys(self._setup, compiled)  # one program serves every rung

    def run(self, V, rtol):
        sol = self._pj.simulate(
            V=float(V), tau=0, t_final=T_FINAL, rtol=rtol, atol=ATOL_RATIO * rtol, ts=self._ts,
            max_steps=self.max_steps, max_jumps=self.max_jumps,
        )  # fmt: skip
        if sol.status_name != "completed":
            raise RuntimeError(f"stopped at t = {float(sol.t_stop):.6g}: {sol.reason}")
        return np.asarray(sol.jumps.as_numpy()["jump_t"])


# --------------------------------------------------------------------------- scipy
class ScipyLoop(LanePeer):
    """``solve_ivp`` (LSODA) with a terminal event at the fold, restarted after each jump (``scipy_events_run``)."""

    def __init__(self, settings, method="LSODA"):
        super().__init__(settings)
        self.method = method
        self.name = f"scipy {method} events loop"

    def run(self, V, rtol):
        return scipy_events_run(float(V), rtol, ATOL_RATIO * rtol, self.method)[0]


# --------------------------------------------------------------------------- SUNDIALS CVODE
class _Lane:
    """What CVODE's callbacks read (its ``userdata``): the branch in use and its end values."""

    __slots__ = ("I", "K", "R", "V", "branch", "limit", "sticking")


def _rhs(_, y, yp, lane):
    K, R = lane.K, lane.R
    s = math.sin(y[0])
    v = lane.branch.velocity((1.0 + s) * K * y[2])
    slip_rate = y[1] - v / R
    yp[0] = slip_rate
    yp[1] = -R * s * K * y[2] / lane.I
    yp[2] = R * s * slip_rate + lane.V - v


def _fold_function():
    """A new events function (scikit-sundae keeps each one's record of events on it: one per solver)."""

    def fold(_, y, events, lane):
        """G − φ(v̂) on the stick branch, φ(v̌) − G on the slip branch: both rise through 0 at the fold."""
        G = (1.0 + math.sin(y[0])) * lane.K * y[2]
        events[0] = G - lane.limit if lane.sticking else lane.limit - G

    fold.terminal, fold.direction = [True], [1]
    return fold


def _forget_events(fold):
    """Empty scikit-sundae's record of the events found so far (kept on the events function).

    scikit-sundae 1.2 appends every event to lists on the events function and converts the whole
    lists to arrays at each ``step`` (it never empties them, ``init_step`` included): without this,
    a run with thousands of jumps pays O(jumps) per segment, O(jumps²) in all, and the cost grows
    from one lane to the next.
    """
    fold._i.clear()
    fold._t.clear()
    fold._y.clear()
    fold._i_cnt[:] = 0


class CvodeEvents(LanePeer):
    """SUNDIALS CVODE (scikit-sundae) with rootfinding at the fold, re-initialized on the host after each jump.

    One solver object per rtol (built in ``prepare``); its ``userdata`` holds the lane's V, the
    branch in use (``jump_peers._Branch``: v(G) by safeguarded Newton in log v, warm-started)
    and the fold value the event looks for. Each segment is ``init_step(t, x)`` then
    ``step(T_FINAL)`` (output at the end or at the event only, no stored steps); at an event
    the host flips the branch (x kept, v jumps) and starts the next segment.
    """

    def __init__(self, settings, method="BDF"):
        super().__init__(settings)
        self.method = method
        self.name = f"SUNDIALS CVODE ({method}) + rootfinding loop"
        self._solvers = {}

    def prepare(self, rtols):
        from sksundae.cvode import CVODE

        ref = jump_reference()
        self._ref = ref
        for rtol in rtols:
            started = time.perf_counter()
            lane = _Lane()
            lane.R, lane.I, lane.K = ref.R, ref.I, ref.K_OVER_L
            fold = _fold_function()
            solver = CVODE(
                _rhs, userdata=lane, eventsfn=fold, num_events=1, method=self.method, rtol=rtol,
                atol=ATOL_RATIO * rtol, max_num_steps=1_000_000,
            )  # fmt: skip
            self._solvers[rtol] = (solver, lane, fold)
            self._setup[rtol] = time.perf_counter() - started

    def run(self, V, rtol):
        ref = self._ref
        solver, lane, fold = self._solvers[rtol]
        V = float(V)
        law = _scalar_law(V)
        v_hat, v_min = ref.fold_velocities(V)
        folds = not math.isnan(v_hat)
        stick = _Branch(law, 0.0, v_hat if folds else math.inf)
        slip = _Branch(law, v_min, math.inf) if folds else None
        lane.V, lane.sticking, lane.branch = V, True, stick
        lane.limit = stick.phi_hi if folds else math.inf
        t, x, jumps = 0.0, ref.initial_state(V)[:3], []
        while True:
            _forget_events(fold)
            solver.init_step(t, x)
            sol = solver.step(T_FINAL)
            if not sol.success:
                raise RuntimeError(f"CVODE failed at t = {float(sol.t[-1]):.9g}: {sol.message}")
            t, x = float(np.ravel(sol.t)[-1]), np.array(sol.y).reshape(-1)[-3:].copy()
            if sol.status != 2 or t >= T_FINAL:  # 2: an event
                break
            jumps.append(t)
            lane.sticking = not lane.sticking
            lane.branch = stick if lane.sticking else slip
            lane.limit = stick.phi_hi if lane.sticking else slip.phi_lo
            lane.branch.velocity((1.0 + math.sin(x[0])) * lane.K * x[2])  # warm start on the landing branch
        return np.array(jumps)


# --------------------------------------------------------------------------- CasADi
class CasadiEventsV(LanePeer):
    """CasADi cvodes + CasADi 3.8's experimental events, V a parameter: one integrator per rtol for every V.

    As ``jump_peers.CasadiEvents``: state X = (α, ω, u, b, n, s1 … s_R), b the branch, n the
    jump count, s the last ``REGISTER`` jump times (CasADi reports no event times; they are
    read back from the states on ``OUTPUTS`` output times); v(x) on branch b by ``BISECTIONS``
    bisections in log v and two Newton steps; zero function φ(v̂, V) − G on the stick branch,
    G − φ(v̌, V) on the slip branch (CasADi fires on + → − crossings only). The parameters
    p = (V, log v̂, log v̌, φ(v̂, V), φ(v̌, V)); without a fold (V ≳ 5.3 m/s) the stick branch
    spans (0, 100] and φ(v̂) is 1e30, so no event fires.
    """

    REGISTER, OUTPUTS, BISECTIONS = 8, 12_000, 56
    OPTIONS: ClassVar[dict] = {
        "event_tol": 1e-14,
        "max_event_iter": 100,
        "max_events": 100_000,
        "max_num_steps": 1_000_000,
    }

    def __init__(self, settings):
        super().__init__(settings)
        self.name = "CasADi cvodes + events loop"
        self._integrators = {}

    def prepare(self, rtols):
        import casadi as ca

        ref = jump_reference()
        self._ref, self._ca = ref, ca
        P = ca.SX.sym("p", 5)
        X, ode, zero, post, t, index = casadi_event_model(
            ca, ref, P[0], (P[1], P[2], P[3], P[4]), self.REGISTER, self.BISECTIONS,
            dphi_dw=lambda w: _dphi_dw(ca, ref.PAPER, P[0], w),
        )  # fmt: skip
        empty = ca.SX(0, 1)
        transition = ca.Function(
            "transition", [index, t, X, empty, P, empty], [post, empty], ca.event_in(), ca.event_out()
        )
        dae = {"x": X, "p": P, "ode": ode, "zero": zero}
        grid = np.linspace(0.0, T_FINAL, self.OUTPUTS + 1)[1:]
        for rtol in rtols:
            started = time.perf_counter()
            options = {"transition": transition, "reltol": rtol, "abstol": ATOL_RATIO * rtol, **self.OPTIONS}
            self._integrators[rtol] = ca.integrator("F", "cvodes", dae, 0.0, grid, options)
            self._setup[rtol] = time.perf_counter() - started

    def run(self, V, rtol):
        ref = self._ref
        V = float(V)
        v_hat, v_min = ref.fold_velocities(V)
        if math.isnan(v_hat):
            p = [V, math.log(100.0), math.log(100.0), 1e30, -1e30]
        else:
            p = [V, math.log(v_hat), math.log(v_min), float(ref.phi(v_hat, V)), float(ref.phi(v_min, V))]
        x0 = np.concatenate([ref.initial_state(V)[:3], [0.0, 0.0], np.full(self.REGISTER, -1.0)])
        return read_jump_register(np.asarray(self._integrators[rtol](x0=x0, p=p)["xf"]), self.REGISTER)


def _dphi_dw(ca, c, V, w):
    """dφ/d(log v) = v·∂φ/∂v at v = exp(w), symbolic in V and w (this peer's measured form: CasADi's own
    derivative of the same φ differs in rounding, and CVODES's experimental events then stop at V = 1.1)."""
    v = ca.exp(w)
    c9 = c["c6"] - c["c7"] * V ** c["p7"] - c["c8"] * V ** c["p8"]
    return (
        c["c1"] * c["p1"] * v ** c["p1"]
        + c["c2"] * c["p2"] * v ** c["p2"]
        + c["c3"] * v / c["c4"] * ca.exp(v / c["c4"])
        - c9 * c["p9"] * v ** c["p9"]
    )


# --------------------------------------------------------------------------- a peer in a worker process
LANE_PEERS = {"casadi": CasadiEventsV}


def _serve(connection, kind, rtols):
    """The worker: prepare the peer, then answer ``(Vs, rtol)`` with the jump lists and the loop's own wall and CPU s."""
    devnull = os.open(os.devnull, os.O_WRONLY)  # CasADi's and CVODES's messages: the errors come back in the reply
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)
    peer = LANE_PEERS[kind]([])
    peer.prepare(rtols)
    connection.send({rtol: peer.setup_seconds(rtol) for rtol in rtols})
    while True:
        request = connection.recv()
        if request is None:
            return
        Vs, rtol = request
        wall, cpu = time.perf_counter(), time.process_time()
        jumps = []
        try:
            for V in Vs:
                jumps.append(peer.run(V, rtol))
        except Exception as error:  # noqa: BLE001 (sent back, raised there)
            text = " ".join(str(error).split())
            cause = text.find("CVode returned")  # CasADi's message: its last line says what CVODES said
            text = text[cause:] if cause >= 0 else text[:300]
            where = f"V = {Vs[len(jumps)]:g}: " if len(Vs) > 1 else ""
            connection.send(("error", f"{where}{type(error).__name__}: {text}"))
            continue
        connection.send(("ok", jumps, time.perf_counter() - wall, time.process_time() - cpu))


class WorkerFailed(RuntimeError):
    """A call failed in the worker (the message names the exception raised there)."""


class Isolated(LanePeer):
    """A peer of ``LANE_PEERS`` run in a worker process, each call under a time limit.

    A call past ``call_limit`` seconds is taken as hung: the worker is killed and started again
    (its set-up is not counted again) and the call raises ``TimeoutError``. ``run_many`` times the
    loop in the worker (no inter-process traffic in the figures).
    """

    def __init__(self, kind, settings, call_limit=30.0):
        super().__init__(settings)
        self.kind, self.call_limit = kind, call_limit
        self.name = LANE_PEERS[kind]([]).name
        self._process = self._connection = None

    def prepare(self, rtols):
        import multiprocessing

        self._rtols = list(rtols)
        context = multiprocessing.get_context("spawn")
        self._connection, child = context.Pipe()
        self._process = context.Process(target=_serve, args=(child, self.kind, self._rtols), daemon=True)
        self._process.start()
        child.close()
        if not self._connection.poll(300):
            raise TimeoutError(f"{self.kind}: the worker did not start")
        setup = self._connection.recv()
        if not self._setup:
            self._setup = setup

    def run_many(self, Vs, rtol):
        """(jump lists, the loop's wall s, its CPU s), measured in the worker."""
        if self._process is None or not self._process.is_alive():
            self.prepare(self._rtols)
        self._connection.send(([float(V) for V in Vs], rtol))
        if not self._connection.poll(self.call_limit * max(len(Vs), 1)):
            self._process.kill()
            self._process.join()
            self._process = None
            raise TimeoutError(f"no answer in {self.call_limit * max(len(Vs), 1):g} s (killed)")
        reply = self._connection.recv()
        if reply[0] == "error":
            raise WorkerFailed(reply[1])
        return reply[1], reply[2], reply[3]

    def run(self, V, rtol):
        return self.run_many([V], rtol)[0][0]

    def close(self):
        if self._process is not None and self._process.is_alive():
            self._connection.send(None)
            self._process.join(10)
            if self._process.is_alive():
                self._process.kill()
        self._process = None
