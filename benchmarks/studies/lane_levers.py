"""What makes a sweep lane cost what it does (issue 22): each lever of the error-controlled α-method, measured on P3.

Problem: ``compare.py``'s P3, the batch of 1024 trajectories (V ∈ {1.1, 2, 4, 8} × 256 τ log-spaced in
[0.005, 0.5] s, t ∈ [0, 3 s], v at the 301 times ``GRID``), or with ``--quick`` its 64-lane slice (16 τ per
V). Error: max over 32 checked trajectories (``compare_problems.p3_subsample``, 8 τ per V) of
``relative_errors`` (max |v − v_ref| / max |v_ref| over the 301 times) against diffrax Kvaerno5 at
rtol 1e-11 (``peers.diffrax_peer.diffrax_vmap``), target 1e-3.

Equal error: every error-controlled method (each peeljax variant, CasADi) is calibrated on the checked
trajectories on the same ladder, 1, 2, 5 per decade from 2e-3 to 1e-7, and runs at its loosest rung with
error ≤ 1e-3 (``compare_problems.calibrate``). A rung is a factor 2–2.5 in rtol, ~1.3× in steps, which is
as large as some levers, so each peeljax variant also gets its step attempts at error exactly 1e-3,
interpolated (log-log) between the last rung that misses and the first that meets the target.

Levers (``peeljax.sweep(..., dt=None, save_dt=0.01, grid="pairs")`` unless said otherwise):

1. ρ (``sweep(rho=…)``): 0 (the default), 0.25, 0.5, 0.75; the error constant C = error_constant(ρ) of the
   estimate C·h²·(a_{n+1} − a_n) is 1/3 at ρ = 0, 1/9 at ρ = 0.5. And ρ on the stick-slip runs:
   ``peeljax.simulate(V=1.1, tau=0, t_final=3, rho=ρ, rtol=…)``, jump count and max |Δt| against
   ``tests/jump_reference.py`` (210 jumps, rtol 1e-12), since ρ > 0 damps less.
2. What a step pays besides the step, at the default's rtol (the same steps): ``save_dt=None`` (no dense
   output, only the window statistics, which every sweep lane computes), ``fold="stop"`` (no fold-event
   search: P3's lanes have no jump, so the same answer), both, and a bare loop (``ErrorControl.observe``
   with no observer and no events, under the sweep's ``lax.map`` + ``shard_map``, built here).
3. The controller and Newton settings (``PIController``: pcoeff/icoeff, safety, factormax; atol/rtol;
   ``AlphaMethod``: newton_kappa, jacobian_max_age), each at equal error. ``sweep`` takes an
   ``AlphaMethod`` (``solver=``) but builds its ``PIController`` itself from rtol/atol, so the gains are
   set here by replacing ``peeljax.integrators.select._controller`` for the call (nothing in peeljax is
   edited). The first step (Hairer's h0) is not an option of ``sweep``: it is measured on the numba loop
   (``compiled_loop.integrate_adaptive(dt0=…)``, the same algorithm step for step).
4. The per-attempt cost of the lane against ``compiled_loop.integrate_adaptive`` on the same lanes and
   settings (one core), and (unless ``--no-step-cost``) ``step_cost.py --adaptive --quick`` in a
   subprocess, the single-trajectory breakdown, whose table is copied into the report.

Peers at equal error, side by side: CasADi cvodes on (α, ω, u, log v) (``peers.casadi_peer.CasadiBatch``,
integrator built outside the timing) looped on one core, and the same spread over the cores: a
``multiprocessing`` pool (spawn) of one worker per core, each looping its share of the lanes
(4 interleaved shares per worker), integrators built in the workers' initializer; the numba loop looped
and spread the same way. Every timed run's error is taken from its own output on the checked lanes.

Timing: a first (compiling) call of everything, then ``--repeats`` (default 5) round-robin rounds,
so that load on the shared machine hits every row alike, each round starting at another place in the list
(the first call after the pool's work ran ~10 % slower) and each call after ``gc.collect()``; medians.
Columns: wall s; CPU s (``time.process_time`` of this process, all JAX threads included, plus the
workers' own); core-s = wall × cores the method holds (JAX devices: one per core; a loop: 1; a pool: its
workers); µs·core/attempt = core-s / step attempts (accepted + rejected). On a shared machine a two-core
figure is only as good as the second core the other jobs leave: compare it with the one-device row.

    python benchmarks/studies/lane_levers.py            # P3, 1024 lanes: 6-7 min on 2 shared cores (load 2-3)
    python benchmarks/studies/lane_levers.py --quick    # the 64-lane slice: ~3 min

Writes ``benchmarks/studies/results/lane_levers[_quick].md``. Speed is reported, never asserted.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import gc
import itertools
import math
import multiprocessing as mp
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # benchmarks/: machine, compare_problems, peers
from compare_problems import (
    GRID,
    P3_SAVE_DT,
    REF_ATOL,
    REF_RTOL,
    T_FINAL,
    TARGET,
    p3_grid,
    p3_subsample,
    relative_errors,
)
from machine import cpu_model, write_result

LADDER = tuple(float(f"{m}e{e}") for e in range(-3, -8, -1) for m in (5, 2, 1))[1:]  # 2e-3 … 1e-7
PER_V = 8  # checked trajectories per V
CHUNK = 256  # sweep's default chunk
STICK_V, STICK_REF_RTOL, STICK_REF_ATOL = 1.1, 1e-12, 1e-14


def log(message):
    print(f"  [{message}]", file=sys.stderr, flush=True)


def load():
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


def cores():
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


# --------------------------------------------------------------------------- the variants
@dataclasses.dataclass(frozen=True)
class Lane:
    """One peeljax configuration of the P3 sweep."""

    key: str
    label: str
    lever: str
    rho: float = 0.0
    atol_ratio: float = 1e-3
    fold: str | None = None  # None: sweep's default under error control ("jump")
    save: bool = True  # save_dt = 0.01 (the output P3 needs)
    bare: bool = False  # no observer, no events: the loop alone
    gains: tuple = ()  # PIController fields, (name, value) pairs
    method: tuple = ()  # AlphaMethod fields, (name, value) pairs
    same_as: str | None = None  # not calibrated: runs at that variant's rtol (the same steps)
    one_device: bool = False  # sweep(devices=jax.devices()[:1]): one core

    def cores(self, n_devices):
        return 1 if self.one_device else n_devices

    @property
    def calibrated(self):
        return self.same_as is None


COMBINED = (("safety", 0.8),)
LANES = (
    Lane("base", "ρ = 0 (default; compare.py's P3 call)", "1 ρ"),
    Lane("rho25", "ρ = 0.25", "1 ρ", rho=0.25),
    Lane("rho50", "ρ = 0.5", "1 ρ", rho=0.5),
    Lane("rho75", "ρ = 0.75", "1 ρ", rho=0.75),
    Lane("nosave", "save_dt=None (window statistics only)", "2 output", save=False, same_as="base"),
    Lane("stop", 'fold="stop" (no fold-event search)', "2 output", fold="stop", same_as="base"),
    Lane("stop_nosave", 'fold="stop", save_dt=None', "2 output", fold="stop", save=False, same_as="base"),
    Lane("bare", "bare loop: no observer, no events", "2 output", fold="stop", save=False, bare=True, same_as="base"),
    Lane("I", "I controller (pcoeff 0, icoeff 1)", "3 controller", gains=(("pcoeff", 0.0), ("icoeff", 1.0))),
    Lane("PI43", "PI (pcoeff 0.4, icoeff 0.3)", "3 controller", gains=(("pcoeff", 0.4), ("icoeff", 0.3))),
    Lane("safety80", "safety 0.8", "3 controller", gains=(("safety", 0.8),)),
    Lane("safety95", "safety 0.95", "3 controller", gains=(("safety", 0.95),)),
    Lane("fmax5", "factormax 5", "3 controller", gains=(("factormax", 5.0),)),
    Lane("atol2", "atol = 1e-2·rtol", "3 controller", atol_ratio=1e-2),
    Lane("kappa", "newton_kappa 0.1", "3 controller", method=(("newton_kappa", 0.1),)),
    Lane("age50", "jacobian_max_age 50", "3 controller", method=(("jacobian_max_age", 50),)),
    Lane(
        "best50",
        'ρ = 0.5, atol = 1e-2·rtol, safety 0.8, fold="stop"',
        "combined",
        rho=0.5,
        atol_ratio=1e-2,
        fold="stop",
        gains=COMBINED,
    ),
    Lane(
        "best75",
        'ρ = 0.75, atol = 1e-2·rtol, safety 0.8, fold="stop"',
        "combined",
        rho=0.75,
        atol_ratio=1e-2,
        fold="stop",
        gains=COMBINED,
    ),
)
LANES += tuple(
    dataclasses.replace(lane, key=f"{lane.key}_1dev", label=f"{lane.label}, one JAX device", lever="side",
                        same_as=lane.key, one_device=True)
    for lane in LANES
    if lane.key in ("base", "best50", "best75")
)  # fmt: skip
BY_KEY = {lane.key: lane for lane in LANES}
NUMBA_MIRRORS = ("base", "best50", "best75")  # the numba loop at these variants' settings
POOLED = ("best50", "best75")  # … and spread over the cores


@contextlib.contextmanager
def controller_gains(gains):
    """``sweep``'s ``PIController(rtol, atol)`` with ``gains`` for the duration (nothing when empty).

    ``integrator_for`` builds the controller by ``select._controller(rtol, atol)`` when a solver is given."""
    if not gains:
        yield
        return
    from peeljax.integrators import select
    from peeljax.integrators.controller import PIController

    original = select._controller
    select._controller = lambda rtol, atol: PIController(rtol=rtol, atol=atol, **dict(gains))
    try:
        yield
    finally:
        select._controller = original


@dataclasses.dataclass
class Run:
    v: np.ndarray | None  # (B, 301), None without saving
    accepted: np.ndarray
    rejected: np.ndarray
    newton: np.ndarray
    status: np.ndarray
    jumps: np.ndarray | None = None  # jump count per lane where folds are located

    @property
    def attempts(self):
        return int(np.sum(self.accepted) + np.sum(self.rejected))


def run_sweep(lane: Lane, Vs, taus, rtol) -> Run:
    import peeljax

    kwargs = {
        "rtol": rtol, "atol": lane.atol_ratio * rtol, "save_dt": P3_SAVE_DT if lane.save else None,
        "grid": "pairs", "progress": False, "fold": lane.fold,
    }  # fmt: skip
    if lane.gains or lane.method:
        kwargs["solver"] = peeljax.AlphaMethod(rho=lane.rho, **dict(lane.method))
    else:
        kwargs["rho"] = lane.rho
    if lane.one_device:
        import jax

        kwargs["devices"] = jax.devices()[:1]
    with controller_gains(lane.gains):
        r = peeljax.sweep(None, Vs, taus, None, T_FINAL, **kwargs)
    v = np.asarray(r.ys[:, :, 3]) if lane.save else None
    jumps = None if r.jumps is None else np.asarray(r.jumps["jump_count"])
    return Run(v, np.asarray(r.accepted_steps), np.asarray(r.rejected_steps), np.asarray(r.newton_iterations),
               np.asarray(r.status), jumps)  # fmt: skip


def bare_runner():
    """The sweep's lanes with nothing but the loop: ``ErrorControl.observe`` with no observer, fold="stop"
    (no events at τ > 0), one lane at a time (``lax.map``, in order of τ) on each device (``shard_map``),
    chunks of 256 dealt to the devices as ``sweep`` does. Returns run(Vs, taus, rho, rtol, atol) -> Run."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    import peeljax
    from peeljax.integrators import Observers, integrator_for
    from peeljax.sweeps.devices import batch_mesh, deal, put_lanes

    devices = jax.devices()
    mesh = batch_mesh(devices)
    model = peeljax.PeelingModel()

    @eqx.filter_jit
    def chunk_run(model, integrator, V, tau, t_final, mesh):
        arrays, static = eqx.partition((model, integrator, t_final), eqx.is_array)

        def per_device(arrays, V, tau):
            model, integrator, t_final = eqx.combine(arrays, static)

            def one(lane):
                ode = peeljax.HomogenizedODE(model, lane[0], lane[1])
                run = integrator.observe(ode, model.initial_state(ode.V), 0.0, t_final, Observers(()))
                return run.accepted_steps, run.rejected_steps, run.newton_iterations, run.status

            order = jnp.argsort(tau)
            out = jax.lax.map(one, (V[order], tau[order]))
            inverse = jnp.argsort(order)
            return jax.tree_util.tree_map(lambda x: x[inverse], out)

        if mesh is None:
            return per_device(arrays, V, tau)
        P = jax.sharding.PartitionSpec
        sharded = jax.shard_map(
            per_device, mesh=mesh, in_specs=(P(), P("batch"), P("batch")), out_specs=P("batch"), check_vma=False
        )
        return sharded(arrays, V, tau)

    def run(Vs, taus, rho, rtol, atol):
        integrator = integrator_for(None, rho=rho, t_final=T_FINAL, rtol=rtol, atol=atol, adjoint="forward",
                                    fold="stop")  # fmt: skip
        n, n_dev = Vs.size, len(devices)
        chunk = -(-min(CHUNK, n) // n_dev) * n_dev
        out = [np.empty(n, int) for _ in range(4)]
        for start in range(0, n, chunk):
            lanes = deal(np.arange(start, start + chunk).clip(max=n - 1), n_dev)  # padded with the last lane
            V, tau = put_lanes((Vs[lanes], taus[lanes]), devices)
            host = [np.asarray(a) for a in chunk_run(model, integrator, V, tau, jnp.asarray(T_FINAL), mesh)]
            for i in range(4):
                out[i][lanes] = host[i]  # a padded slot repeats the last lane's own result
        return Run(None, out[0], out[1], out[2], out[3])

    return run


# --------------------------------------------------------------------------- the numba loop and CasADi
def numba_options(lane: Lane, rtol):
    """``compiled_loop.integrate_adaptive``'s keywords for ``lane``'s settings (``adaptive_options_of``)."""
    from peers.compiled_loop import adaptive_options_of

    import peeljax
    from peeljax.integrators.controller import PIController

    solver = peeljax.AlphaMethod(rho=lane.rho, **dict(lane.method))
    controller = PIController(rtol=rtol, atol=lane.atol_ratio * rtol, **dict(lane.gains))
    return adaptive_options_of(solver, controller)


def numba_loop(Vs, taus, options):
    """v (B, 301) and the counts summed over the lanes [accepted, rejected, Newton, Jacobian, attempts]."""
    from peers.compiled_loop import initial_state, integrate_adaptive, parameters

    v = np.empty((len(Vs), GRID.size))
    counts = np.zeros(5, np.int64)
    for i, (Vp, tau) in enumerate(zip(Vs, taus)):
        p = parameters(float(Vp), float(tau))
        ys, _, _, c, _ = integrate_adaptive(initial_state(p), p, T_FINAL, GRID, **options)
        v[i] = ys[:, 3]
        counts += c
    return v, counts


def casadi_build(batch, rtol):
    """Build ``CasadiBatch``'s integrator for ``rtol`` (``setup``; older checkouts: ``integrator``) and call it once."""
    (batch.setup if hasattr(batch, "setup") else batch.integrator)(rtol)
    batch(1.1, 0.05, rtol)


def casadi_loop(batch, Vs, taus, rtol, stats=False):
    """v (B, 301); with ``stats`` also CVODES's steps, error-test and Newton failures summed (an untimed run)."""
    v = np.empty((len(Vs), GRID.size))
    counts = np.zeros(3, np.int64)
    for i, (Vp, tau) in enumerate(zip(Vs, taus)):
        v[i] = batch(float(Vp), float(tau), rtol)
        if stats:
            try:
                s = batch._integrators[rtol].stats()
                counts += [s["nsteps"], s["netfails"], s["nncfails"]]
            except (AttributeError, KeyError, RuntimeError):
                counts[:] = -1
    return (v, counts) if stats else v


_WORKER = {}


def _worker_init(casadi_rtols, numba_sets):
    """Pool worker set-up (outside the timing): CasADi's integrators built and called once; numba loaded."""
    from peers.casadi_peer import CasadiBatch

    batch = CasadiBatch()
    for rtol in casadi_rtols:
        casadi_build(batch, rtol)
    _WORKER["casadi"] = batch
    for options in numba_sets:
        numba_loop(np.array([1.1]), np.array([0.05]), options)


def _pool_task(task):
    kind, Vs, taus, setting = task
    started = time.process_time()
    if kind == "casadi":
        v, counts = casadi_loop(_WORKER["casadi"], Vs, taus, setting), None
    else:
        v, counts = numba_loop(Vs, taus, setting)
    return v, counts, time.process_time() - started


def pooled(pool, workers, kind, Vs, taus, setting):
    """The lanes in 4 interleaved shares per worker; (v, counts summed or None, the workers' CPU seconds)."""
    n_shares = min(len(Vs), 4 * workers)
    shares = [np.arange(i, len(Vs), n_shares) for i in range(n_shares)]
    out = pool.map(_pool_task, [(kind, Vs[s], taus[s], setting) for s in shares], chunksize=1)
    v = np.empty((len(Vs), GRID.size))
    for s, (vs, _, _) in zip(shares, out):
        v[s] = vs
    counts = None if kind == "casadi" else np.sum([c for _, c, _ in out], axis=0)
    return v, counts, float(sum(cpu for _, _, cpu in out))


# --------------------------------------------------------------------------- calibration
def calibrate(run_sub, v_ref):
    """The ladder loose → tight until the max error on the checked lanes is ≤ TARGET.

    ``run_sub(rtol)`` returns (v, attempts per lane, accepted per lane, extra) on the checked lanes.
    Returns (rungs [(rtol, error, attempts, accepted, extra)], the chosen rung or None).
    """
    rungs = []
    for rtol in LADDER:
        v, attempts, accepted, extra = run_sub(rtol)
        rungs.append((rtol, float(np.max(relative_errors(v, v_ref))), attempts, accepted, extra))
        if rungs[-1][1] <= TARGET:
            return rungs, rungs[-1]
    return rungs, None


def at_target(rungs):
    """Attempts per lane at error exactly TARGET, log-log between the rungs around it (None: not bracketed)."""
    for (_, e0, a0, _, _), (_, e1, a1, _, _) in itertools.pairwise(rungs):
        if e0 > TARGET >= e1 > 0 and a1 > 0 and a0 > 0 and e0 != e1:
            slope = math.log(a1 / a0) / math.log(e0 / e1)
            return a0 * (e0 / TARGET) ** slope
    return None


# --------------------------------------------------------------------------- stick-slip (τ = 0) with ρ > 0
def stick_slip_check(rhos, rtols):
    """``simulate(V=1.1, tau=0, rho=ρ, rtol)`` against ``tests/jump_reference.py``: rows of jump counts and errors."""
    import jax
    from peers.jump_peers import jump_reference

    import peeljax

    started = time.perf_counter()
    ref = jump_reference().reference_jump_run(STICK_V, T_FINAL, rtol=STICK_REF_RTOL, atol=STICK_REF_ATOL,
                                              method="LSODA")["jump_t"]  # fmt: skip
    ref_s = time.perf_counter() - started
    ts = np.array([0.0, T_FINAL])
    rows = []
    for rtol in rtols:
        for rho in rhos:

            def call(rho=rho, rtol=rtol):
                sol = peeljax.simulate(V=STICK_V, tau=0, t_final=T_FINAL, rho=rho, rtol=rtol, atol=1e-3 * rtol, ts=ts,
                                       max_steps=1_000_000)  # fmt: skip
                jax.block_until_ready(sol.ys)
                return sol

            sol = call()  # compiles on the first call
            start = time.perf_counter()
            sol = call()
            seconds = time.perf_counter() - start
            jumps = np.asarray(sol.jumps.as_numpy()["jump_t"])
            same = jumps.size == ref.size
            dt = np.abs(jumps - ref) if same else None
            rows.append({
                "rtol": rtol, "rho": rho, "status": sol.status_name, "jumps": int(jumps.size),
                "error": float(np.max(dt)) if same else math.inf, "median_error": float(np.median(dt)) if same else math.inf,
                "accepted": int(sol.stats["accepted_steps"]), "rejected": int(sol.stats["rejected_steps"]),
                "seconds": seconds,
            })  # fmt: skip
            log(f"stick-slip rtol {rtol:g} ρ {rho}: {rows[-1]}")
    return {"reference_jumps": int(ref.size), "reference_s": ref_s, "rows": rows}


# --------------------------------------------------------------------------- step_cost.py --adaptive --quick
def step_cost_table():
    """Run ``step_cost.py --adaptive --quick`` (its own process) and return its report's lines; the file it
    writes is put back as it was (removed if it was not there)."""
    path = HERE / "results" / "step_cost_adaptive_quick.md"
    before = path.read_text() if path.exists() else None
    started = time.perf_counter()
    proc = subprocess.run([sys.executable, str(HERE / "step_cost.py"), "--adaptive", "--quick"], check=False,
                          capture_output=True,
                          text=True, cwd=HERE.parent, env={**os.environ, "PYTHONPATH": str(HERE.parent)})  # fmt: skip
    seconds = time.perf_counter() - started
    text = path.read_text() if path.exists() and proc.returncode == 0 else None
    if before is None:
        path.unlink(missing_ok=True)
    else:
        path.write_text(before)
    if text is None:
        return [f"`step_cost.py --adaptive --quick` failed (exit {proc.returncode}): {proc.stderr[-500:]}"], seconds
    return text.splitlines(), seconds


# --------------------------------------------------------------------------- the measurement
def fmt(x, digits=3):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return f"{x:.{digits}g}"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="the 64-lane slice (16 τ per V) instead of 1024 lanes")
    parser.add_argument("--repeats", type=int, default=None, help="round-robin rounds (medians; default 5)")
    parser.add_argument("--no-step-cost", action="store_true", help="skip step_cost.py --adaptive --quick")
    parser.add_argument("--no-stick-slip", action="store_true", help="skip the ρ check on the stick-slip runs")
    parser.add_argument("--out", type=Path, default=None, help="report path (default results/lane_levers[_quick].md)")
    args = parser.parse_args(argv)
    args.repeats = args.repeats or 5
    started_all = time.perf_counter()
    load_start = load()

    import jax
    from peers.casadi_peer import CasadiBatch
    from peers.diffrax_peer import diffrax_vmap

    from peeljax.integrators.adaptive import error_constant

    n_tau = 16 if args.quick else 256
    Vs, taus = p3_grid(n_tau)
    B = Vs.size
    sub = p3_subsample(n_tau, PER_V)
    devices = jax.devices()
    n_dev = len(devices)
    workers = cores()
    log(f"B = {B}, {sub.size} checked lanes, {n_dev} JAX devices, {workers} cores, load {load_start:.2f}")

    # ---- the reference on the checked lanes
    started = time.perf_counter()
    v_ref, ref_status = diffrax_vmap()(Vs[sub], taus[sub], REF_RTOL, REF_ATOL)
    if np.any(ref_status != 0):
        raise RuntimeError("the reference stopped on a checked lane")
    ref_s = time.perf_counter() - started
    log(f"reference: {ref_s:.0f} s")

    # ---- calibration of every peeljax variant on the checked lanes
    calibration, rtol_of, compile_s = {}, {}, {}
    started = time.perf_counter()
    for lane in LANES:
        if not lane.calibrated:
            continue

        def run_sub(rtol, lane=lane):
            r = run_sweep(lane, Vs[sub], taus[sub], rtol)
            att = (r.accepted + r.rejected).mean()
            return r.v, float(att), float(r.accepted.mean()), {"rejected": float(r.rejected.mean()),
                                                               "newton": float(r.newton.sum() / max(r.attempts, 1))}  # fmt: skip

        rungs, chosen = calibrate(run_sub, v_ref)
        calibration[lane.key] = rungs
        rtol_of[lane.key] = chosen[0] if chosen else rungs[-1][0]
        log(f"{lane.key}: rtol {rtol_of[lane.key]:g}, error {fmt(chosen[1] if chosen else rungs[-1][1])}, "
            f"attempts@1e-3 {fmt(at_target(rungs), 4)}")  # fmt: skip
    for lane in LANES:
        if not lane.calibrated:
            rtol_of[lane.key] = rtol_of[lane.same_as]
    calibration_s = time.perf_counter() - started

    casadi = CasadiBatch()
    casadi_rungs = []
    for rtol in LADDER:
        casadi_build(casadi, rtol)
        v, counts = casadi_loop(casadi, Vs[sub], taus[sub], rtol, stats=True)
        casadi_rungs.append((rtol, float(np.max(relative_errors(v, v_ref))), float(counts.sum() / sub.size),
                             float(counts[0] / sub.size), {"netfails": float(counts[1] / sub.size)}))  # fmt: skip
        if casadi_rungs[-1][1] <= TARGET:
            break
    rtol_casadi = casadi_rungs[-1][0]
    log(f"casadi: rtol {rtol_casadi:g}, error {casadi_rungs[-1][1]:.3g}")

    # ---- first calls on the whole batch (compilation, set-up), checks of the same-step variants
    bare = bare_runner()

    def peeljax_call(lane):
        rtol = rtol_of[lane.key]
        if lane.bare:
            return lambda: bare(Vs, taus, lane.rho, rtol, lane.atol_ratio * rtol)
        return lambda: run_sweep(lane, Vs, taus, rtol)

    first = {}
    for lane in LANES:
        start = time.perf_counter()
        first[lane.key] = peeljax_call(lane)()
        compile_s[lane.key] = time.perf_counter() - start
    base_run = first["base"]
    jump_count = None if base_run.jumps is None else int(np.sum(base_run.jumps))
    for lane in LANES:
        if lane.same_as and not np.array_equal(first[lane.key].accepted, first[lane.same_as].accepted):
            log(f"WARNING: {lane.key} took other steps than {lane.same_as}")
    numba_sets = {key: numba_options(BY_KEY[key], rtol_of[key]) for key in NUMBA_MIRRORS}
    numba_first = {key: numba_loop(Vs, taus, numba_sets[key]) for key in NUMBA_MIRRORS}
    casadi_first = casadi_loop(casadi, Vs, taus, rtol_casadi, stats=True)
    ctx = mp.get_context("spawn")
    start = time.perf_counter()
    pool = ctx.Pool(workers, initializer=_worker_init, initargs=([rtol_casadi], [numba_sets[k] for k in POOLED]))
    pool.map(_pool_task, [("numba", Vs[:1], taus[:1], numba_sets[POOLED[0]])] * workers, chunksize=1)
    pool_setup_s = time.perf_counter() - start

    # ---- round-robin timing
    items = {lane.key: peeljax_call(lane) for lane in LANES}
    items["casadi_loop"] = lambda: (casadi_loop(casadi, Vs, taus, rtol_casadi), None, 0.0)
    items["casadi_pool"] = lambda: pooled(pool, workers, "casadi", Vs, taus, rtol_casadi)
    for key in NUMBA_MIRRORS:
        items[f"numba_loop_{key}"] = lambda key=key: (*numba_loop(Vs, taus, numba_sets[key]), 0.0)
    for key in POOLED:
        items[f"numba_pool_{key}"] = lambda key=key: pooled(pool, workers, "numba", Vs, taus, numba_sets[key])
    walls = {k: [] for k in items}
    cpus = {k: [] for k in items}
    outputs = {}
    loads = []
    keys = list(items)
    for round_ in range(args.repeats):
        # Each round starts elsewhere in the list: the first call after the pool's work ran ~10 % slower.
        offset = round_ * len(keys) // args.repeats
        for key in keys[offset:] + keys[:offset]:
            call = items[key]
            gc.collect()
            w0, c0 = time.perf_counter(), time.process_time()
            out = call()
            walls[key].append(time.perf_counter() - w0)
            extra = out[2] if isinstance(out, tuple) else 0.0
            cpus[key].append(time.process_time() - c0 + extra)
            outputs[key] = out
        loads.append(load())
        log(f"round {round_ + 1}: " + ", ".join(f"{k} {walls[k][-1]:.2f}" for k in items) + f"; load {loads[-1]:.2f}")
    pool.close()
    pool.join()
    med = {k: float(np.median(walls[k])) for k in items}
    med_cpu = {k: float(np.median(cpus[k])) for k in items}

    # ---- first-step rule, on the numba loop (sweep does not take dt0)
    first_step = []
    for key in ("base", "best75"):
        lane = BY_KEY[key]
        for dt0 in (-1.0, 1e-8, 1e-6, 1e-4):
            options = {**numba_options(lane, rtol_of[key]), "dt0": dt0}
            v, counts = numba_loop(Vs[sub], taus[sub], options)
            first_step.append((key, dt0, float(np.max(relative_errors(v, v_ref))), counts[0] / sub.size,
                               counts[1] / sub.size))  # fmt: skip

    stick = (
        None
        if args.no_stick_slip
        else stick_slip_check((0.0, 0.25, 0.5, 0.75), (1e-4, 1e-6) if args.quick else (1e-4, 1e-6, 1e-8))
    )
    step_cost_lines, step_cost_s = ([], 0.0) if args.no_step_cost else step_cost_table()
    load_end = load()
    total_s = time.perf_counter() - started_all

    # ---------------------------------------------------------------- the report
    out = []

    def emit(line=""):
        print(line, flush=True)
        out.append(line)

    emit(f"# What a sweep lane costs: the levers of the error-controlled α-method on P3 ({B} lanes)")
    emit()
    emit(f"{time.strftime('%Y-%m-%d %H:%M')}; the whole run took "
         f"{total_s / 60:.1f} min (reference {ref_s:.0f} s, calibration {calibration_s:.0f} s, step_cost {step_cost_s:.0f} s).")  # fmt: skip
    emit()
    emit(f"- machine: {cpu_model()}, {workers} cores (shared with other jobs), {n_dev} JAX devices "
         f"({devices[0].platform}); load average {load_start:.2f} at the start, "
         f"{', '.join(f'{x:.2f}' for x in loads)} after each timed round, {load_end:.2f} at the end")  # fmt: skip
    import casadi as ca
    import diffrax
    import numba

    emit(f"- python {platform.python_version()}, jax {jax.__version__}, diffrax {diffrax.__version__}, casadi "
         f"{ca.__version__}, numba {numba.__version__}, numpy {np.__version__}; XLA_FLAGS: `{os.environ.get('XLA_FLAGS', '')}`")  # fmt: skip
    emit(f"- problem: P3{' (the 64-lane slice, 16 τ per V)' if args.quick else ''}: V ∈ {{1.1, 2, 4, 8}} × {n_tau} τ "
         f"log-spaced in [0.005, 0.5] s, t ∈ [0, 3] s, v at the 301 times 0, 0.01, …, 3; error = max over {sub.size} "
         f"checked lanes of max|v − v_ref|/max|v_ref|, v_ref = diffrax Kvaerno5 at rtol {REF_RTOL:g}; target {TARGET:g}")  # fmt: skip
    emit(f"- ladder for every method: {', '.join(f'{r:g}' for r in LADDER)} (loosest rung meeting the target); "
         f"medians of {args.repeats} round-robin rounds after a first call")  # fmt: skip
    emit()

    def lane_stats(key):
        r = outputs[key] if isinstance(outputs[key], Run) else first[key]
        return r

    base_wall = med["base"]
    numba_base_attempts = int(numba_first["base"][1][4])

    def peeljax_row(lane, with_interp=True):
        r = lane_stats(lane.key)
        att = r.attempts
        err = float(np.max(relative_errors(r.v[sub], v_ref))) if r.v is not None else None
        cal = calibration.get(lane.key if lane.calibrated else lane.same_as)
        interp = at_target(cal) if cal else None
        core_s = med[lane.key] * lane.cores(n_dev)
        cells = [
            lane.label, f"{rtol_of[lane.key]:g}", fmt(err, 2) if err is not None else "= base's (same steps)",
            f"{r.accepted.mean():.0f} + {r.rejected.mean():.0f}", f"{r.newton.sum() / max(att, 1):.2f}",
        ]  # fmt: skip
        if with_interp:
            cells.append(fmt(interp, 4) if interp else "–")
        cells += [f"{med[lane.key]:.3f}", f"{med_cpu[lane.key]:.3f}", f"{core_s:.3f}", f"{core_s / att * 1e6:.2f}",
                  f"{med[lane.key] / base_wall:.2f}"]  # fmt: skip
        return "| " + " | ".join(cells) + " |"

    header = ("| variant | rtol | error | accepted + rejected per lane | Newton it/attempt | attempts per lane at error "
              "1e-3 (interp., checked lanes) | wall s | CPU s | core-s | µs·core/attempt | wall / base's |")  # fmt: skip
    rule = "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"

    emit("## Summary: each lever against the default (ρ = 0, compare.py's call), at equal error")
    emit()
    emit("Attempts = accepted + rejected steps per lane; interp. = at error exactly 1e-3 on the checked lanes; "
         "CPU s is the less load-sensitive time (see the limits at the end).")  # fmt: skip
    emit()
    emit(
        "| lever | variant | attempts per lane (interp.) | ÷ default | CPU s (batch) | ÷ default | wall s | ÷ default |"
    )
    emit("|---|---|---:|---:|---:|---:|---:|---:|")
    base_interp = at_target(calibration["base"])
    for lane in LANES:
        if lane.lever == "side" or lane.key == "base" or lane.bare:
            continue
        interp = at_target(calibration[lane.key]) if lane.calibrated else base_interp
        emit(f"| {lane.lever} | {lane.label} | {fmt(interp, 4)} | {fmt(interp / base_interp if interp else None, 2)} | "
             f"{med_cpu[lane.key]:.3f} | {med_cpu[lane.key] / med_cpu['base']:.2f} | {med[lane.key]:.3f} | "
             f"{med[lane.key] / base_wall:.2f} |")  # fmt: skip
    one = min(("base_1dev", "best50_1dev", "best75_1dev"), key=lambda k: med[k])
    two = min(("base", "best50", "best75"), key=lambda k: med[k])
    emit()
    emit(f"Per core at equal error, in the same rounds: peeljax on one JAX device, {BY_KEY[one].label}: "
         f"{med[one]:.3f} s wall, {med_cpu[one]:.3f} CPU s, against CasADi cvodes looped on one core "
         f"{med['casadi_loop']:.3f} s, {med_cpu['casadi_loop']:.3f} CPU s: ×{med[one] / med['casadi_loop']:.2f} "
         f"the wall time (default settings on one device: ×{med['base_1dev'] / med['casadi_loop']:.2f}). Spread over "
         f"the {workers} cores: peeljax.sweep, {BY_KEY[two].label}, {med[two]:.3f} s against CasADi's pool "
         f"{med['casadi_pool']:.3f} s: ×{med[two] / med['casadi_pool']:.2f} (default settings: "
         f"×{med['base'] / med['casadi_pool']:.2f}); with the cores shared, a spread time is only as good as the "
         "core the other jobs leave (compare each spread time with its one-core time).")  # fmt: skip
    emit()

    emit("## 1. ρ at equal error")
    emit()
    emit(
        "C = error_constant(ρ): "
        + ", ".join(f"ρ = {r:g}: {float(error_constant(r)):.4f}" for r in (0, 0.25, 0.5, 0.75))
    )
    emit()
    emit(header)
    emit(rule)
    for lane in LANES:
        if lane.lever == "1 ρ":
            emit(peeljax_row(lane))
    emit()

    if stick is not None:
        emit("### ρ on the stick-slip runs (τ = 0, jumps at the folds)")
        emit()
        emit(f"`peeljax.simulate(V={STICK_V}, tau=0, t_final=3, rho=ρ, rtol, atol=1e-3·rtol, ts=[0, 3])` against "
             f"`tests/jump_reference.py` (LSODA events with the arclength refinement, rtol {STICK_REF_RTOL:g}: "
             f"{stick['reference_jumps']} jumps, {stick['reference_s']:.1f} s); error = max over all jumps of |t − t_ref| "
             "(– when the count differs); time: one run after the compiling one")  # fmt: skip
        emit()
        emit("| rtol | ρ | status | jumps | max \\|Δt\\| (s) | median \\|Δt\\| (s) | accepted + rejected | s/run |")
        emit("|---:|---:|---|---:|---:|---:|---:|---:|")
        for row in stick["rows"]:
            emit(f"| {row['rtol']:g} | {row['rho']:g} | {row['status']} | {row['jumps']} | {fmt(row['error'], 2)} | "
                 f"{fmt(row['median_error'], 2)} | {row['accepted']} + {row['rejected']} | {row['seconds']:.3f} |")  # fmt: skip
        emit()

    emit("## 2. What a step pays besides the step (the base's rtol: the same steps), and 4. against numba")
    emit()
    emit("| variant | cores | attempts per lane | wall s | CPU s | core-s | µs·core/attempt | CPU µs/attempt | "
         "÷ bare loop (CPU) | ÷ numba (CPU) |")  # fmt: skip
    emit("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    bare_cpu = med_cpu["bare"] / lane_stats("bare").attempts
    numba_cpu = med_cpu["numba_loop_base"] / numba_base_attempts

    def cost_row(label, n_cores, attempts, key):
        emit(f"| {label} | {n_cores} | {attempts / B:.0f} | {med[key]:.3f} | {med_cpu[key]:.3f} | "
             f"{med[key] * n_cores:.3f} | {med[key] * n_cores / attempts * 1e6:.2f} | {med_cpu[key] / attempts * 1e6:.2f} | "
             f"{med_cpu[key] / attempts / bare_cpu:.2f} | {med_cpu[key] / attempts / numba_cpu:.2f} |")  # fmt: skip

    for key in ("base", "base_1dev", "nosave", "stop", "stop_nosave", "bare"):
        cost_row(BY_KEY[key].label, BY_KEY[key].cores(n_dev), lane_stats(key).attempts, key)
    cost_row("numba `integrate_adaptive` looped (dense output at the 301 times; no window statistics, no events)", 1,
             numba_base_attempts, "numba_loop_base")  # fmt: skip
    emit()
    emit(
        f"The numba loop's attempts on these lanes: {numba_base_attempts} (peeljax's: {base_run.attempts}); "
        f"its error {fmt(float(np.max(relative_errors(numba_first['base'][0][sub], v_ref))), 2)}."
    )
    emit()

    emit("## 3. Controller, tolerance and Newton settings at equal error (ρ = 0)")
    emit()
    emit(header)
    emit(rule)
    emit(peeljax_row(BY_KEY["base"]))
    for lane in LANES:
        if lane.lever == "3 controller":
            emit(peeljax_row(lane))
    emit()
    emit("First step (Hairer's h0 = 0.01·min(1/‖ψ0‖, 1/√‖a0‖) in the error weights, then growth ≤ factormax per step): "
         "not an option of `sweep`; on the numba loop (the same algorithm) over the checked lanes:")  # fmt: skip
    emit()
    emit("| settings | dt0 | error | accepted + rejected per lane |")
    emit("|---|---:|---:|---:|")
    for key, dt0, err, acc, rej in first_step:
        emit(f"| {BY_KEY[key].label}, rtol {rtol_of[key]:g} | {'Hairer (default)' if dt0 < 0 else f'{dt0:g} s'} | "
             f"{err:.3g} | {acc:.1f} + {rej:.1f} |")  # fmt: skip
    emit()

    emit("## Equal error, side by side: the best combinations against CasADi and the numba loop")
    emit()
    casadi_steps = casadi_first[1]
    casadi_err = float(np.max(relative_errors(outputs["casadi_loop"][0][sub], v_ref)))
    casadi_pool_err = float(np.max(relative_errors(outputs["casadi_pool"][0][sub], v_ref)))
    casadi_core = med["casadi_loop"]
    casadi_cpu = med_cpu["casadi_loop"]
    emit("| method | rtol | error | attempts per lane | cores | wall s | CPU s | core-s | core-s / CasADi loop's | "
         "CPU s / CasADi loop's | wall / CasADi pool's |")  # fmt: skip
    emit("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")

    def side_row(label, key, rtol, err, attempts, n_cores):
        emit(f"| {label} | {rtol:g} | {fmt(err, 2)} | {attempts} | {n_cores} | {med[key]:.3f} | {med_cpu[key]:.3f} | "
             f"{med[key] * n_cores:.3f} | {med[key] * n_cores / casadi_core:.2f} | {med_cpu[key] / casadi_cpu:.2f} | "
             f"{med[key] / med['casadi_pool']:.2f} |")  # fmt: skip

    for key in ("base", "base_1dev", "rho50", "rho75", "best50", "best50_1dev", "best75", "best75_1dev"):
        r, lane = lane_stats(key), BY_KEY[key]
        side_row(f"peeljax.sweep, {lane.label}", key, rtol_of[key], float(np.max(relative_errors(r.v[sub], v_ref))),
                 f"{r.attempts / B:.0f}", lane.cores(n_dev))  # fmt: skip
    steps_cell = (f"{casadi_steps.sum() / B:.0f} ({casadi_steps[0] / B:.0f} steps + {casadi_steps[1] / B:.0f} error-test "
                  f"+ {casadi_steps[2] / B:.0f} Newton failures)") if casadi_steps[0] >= 0 else "?"  # fmt: skip
    side_row("CasADi cvodes (log v), looped", "casadi_loop", rtol_casadi, casadi_err, steps_cell, 1)
    side_row(
        f"CasADi cvodes (log v), pool of {workers}", "casadi_pool", rtol_casadi, casadi_pool_err, steps_cell, workers
    )
    for key in NUMBA_MIRRORS:
        v, counts = outputs[f"numba_loop_{key}"][:2]
        side_row(f"numba loop at {BY_KEY[key].label}", f"numba_loop_{key}", rtol_of[key],
                 float(np.max(relative_errors(v[sub], v_ref))), f"{counts[4] / B:.0f}", 1)  # fmt: skip
    for key in POOLED:
        v, counts = outputs[f"numba_pool_{key}"][:2]
        side_row(f"numba pool of {workers} at {BY_KEY[key].label}", f"numba_pool_{key}", rtol_of[key],
                 float(np.max(relative_errors(v[sub], v_ref))), f"{counts[4] / B:.0f}", workers)  # fmt: skip
    emit()
    emit("CasADi's ladder on the checked lanes (rtol: error, attempts per lane): "
         + "; ".join(f"{r:g}: {e:.3g}, {a:.0f}" for r, e, a, _, _ in casadi_rungs))  # fmt: skip
    emit()

    emit("## Calibration ladders of the peeljax variants (checked lanes; rtol: error, attempts per lane)")
    emit()
    for key, rungs in calibration.items():
        emit(f"- {BY_KEY[key].label}: " + "; ".join(f"{r:g}: {e:.3g}, {a:.0f}" for r, e, a, _, _ in rungs))
    emit()
    emit("First calls (compilation included where the shapes or static settings were new), s: "
         + ", ".join(f"{k} {v:.1f}" for k, v in compile_s.items()) + f"; pool start {pool_setup_s:.1f} s.")  # fmt: skip
    emit()
    if step_cost_lines:
        emit("## 4. One trajectory: `step_cost.py --adaptive --quick` (run by this script)")
        emit()
        keep = False
        for line in step_cost_lines:
            if line.startswith("## Cost per attempt"):
                keep = True
                continue
            if keep:
                emit(line)
        emit()
    emit("## What limits each figure")
    emit()
    emit(
        "- Equal error is the loosest rung of one ladder (1, 2, 5 per decade) for every method; a rung is ~1.3× in "
        "steps, so the interpolated attempts at error 1e-3 are the fairer measure of a step-count lever. Errors are "
        f"max over {sub.size} checked lanes, not all {B}."
    )
    emit(
        "- The machine is shared: wall times move with the other jobs' load (listed per round); the CPU s column "
        "(this process's threads plus the pool workers') is less sensitive to it but includes time lost to "
        "contention. core-s charges the cores a method holds, busy or not; with 2 JAX devices a chunk waits for "
        "its slower device."
    )
    emit(
        "- Same-step variants (lever 2) give the same answer by construction (checked: identical accepted steps); "
        f'fold="stop" is only equivalent here because no P3 lane reaches a fold (jumps over all lanes with the default '
        f'fold="jump": {jump_count}).'
    )
    emit(
        "- The controller gains are set by replacing `select._controller` for the call (sweep does not take a "
        "controller); the first-step rule is measured on the numba loop only."
    )
    emit(
        "- CasADi's spread: a spawn pool (set-up and integrator builds outside the timing), 4 interleaved shares "
        "per worker, results pickled back (included in the wall time)."
    )
    path = args.out or HERE / "results" / f"lane_levers{'_quick' if args.quick else ''}.md"
    write_result(path, "\n".join(out) + "\n")
    print(f"(written to {path}; total {total_s:.0f} s)")


if __name__ == "__main__":
    main()
