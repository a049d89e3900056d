"""Throughput of ``peeljax.sweep`` at equal accuracy, beside the alternatives.

Problem: V = 1.1, τ log-spaced in [0.005, 0.5] (one τ per trajectory; B = 1: τ = 0.05),
t ∈ [0, 3], paper initial data; every engine keeps v at the 301 times 0, 0.01, …, 3.

Equal accuracy, not equal dt: the error of a setting is the max over the calibration τ
(5 log-spaced over the range, 0.05 among them) of max over the 301 times |v − v_ref| / max|v_ref|,
v_ref = diffrax Kvaerno5 at rtol 1e-12, atol 1e-14; each engine runs at the cheapest of its
settings (tried loose to tight) whose error is ≤ 1e-3:

* (a) error control: ``peeljax.sweep`` (default: the α-method with a step size per trajectory),
  rtol ∈ {1e-3, 3e-4, …, 1e-7}, atol = 1e-3·rtol, ``save_dt = 0.01``; its default devices
  (on a CPU one JAX device per core) and lane_batch (1 on a CPU, the chunk on a GPU);
* (b) uniform mesh: ``peeljax.sweep(dt=3/N)``, N ∈ {600, 1200, …, 19200}, ``save_every = N/300``;
* (c) numba: ``compiled_loop.integrate_adaptive``, (a)'s algorithm step for step as a compiled
  scalar loop, called once per trajectory at (a)'s rtol (one core);
* (d) diffrax Kvaerno5 under ``jax.vmap`` (``peeljax.integrate_reference``), rtol ∈ {1e-2, …,
  1e-8}, atol = 1e-2·rtol (``--no-diffrax`` skips it).

For each batch size B it prints the run time, µs per trajectory, trajectories per second, mean
accepted steps per trajectory and the compile time, with each time divided by (a)'s; then two
tables on one batch (B = 1024, ``--quick`` 256): (a) with lane_batch = 1, 8, 64, B (the lanes
a device ``vmap``s together), and (a) on one device against all of them.

Times are medians of repeated runs after a first (compiling) call, measured round-robin over
the engines so that load on a shared machine hits them alike (a single run for B > 1024); the
sweeps run each batch as one chunk (``--chunk`` caps it); the numba loop over batches larger
than 1024 is timed on 1024 τ spread over the batch and scaled to B, and diffrax is skipped above
``--diffrax-max-batch`` (—). Speed is reported, never asserted.

    python benchmarks/studies/sweep_throughput.py --quick   # B = 1, 64, 256, 2 timed runs: a few minutes on 2 cores
    python benchmarks/studies/sweep_throughput.py           # B = 1, 64, 1024, 4096
    python benchmarks/studies/sweep_throughput.py --batches 1 10000 100000 1000000 --chunk 100000   # e.g. on a GPU

The tables go to ``benchmarks/studies/results/sweep_throughput[_quick].md``.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # benchmarks/: machine, compare_problems, peers
from machine import cpu_model, write_result

V, T_FINAL, SAVE_DT = 1.1, 3.0, 0.01
GRID = np.linspace(0.0, T_FINAL, 301)
TAU_RANGE = (0.005, 0.5)
CALIBRATION_TAUS = np.geomspace(*TAU_RANGE, 5)  # 0.005, 0.0158, 0.05, 0.158, 0.5
TARGET = 1e-3
REF_RTOL, REF_ATOL = 1e-12, 1e-14
ADAPTIVE_RTOLS = (1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 3e-6, 1e-6, 3e-7, 1e-7)  # atol = 1e-3·rtol
UNIFORM_STEPS = (600, 1200, 2400, 4800, 9600, 19200)
DIFFRAX_RTOLS = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)  # atol = 1e-2·rtol
LOOP_CAP = 1024  # the numba loop over larger batches is timed on this many τ and scaled


def taus_of(B):
    return np.geomspace(*TAU_RANGE, B) if B > 1 else np.array([0.05])


def relative_errors(v, v_ref):
    """Per trajectory: max over the grid of |v − v_ref| / max|v_ref| (inf where v stopped)."""
    error = np.max(np.abs(v - v_ref), axis=1) / np.max(np.abs(v_ref), axis=1)
    return np.where(np.all(np.isfinite(v), axis=1), error, np.inf)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="B = 1, 64, 256; 2 timed runs; the small tables on 256")
    parser.add_argument("--batches", type=int, nargs="+", default=None, help="batch sizes (default 1 64 1024 4096)")
    parser.add_argument("--table-batch", type=int, default=None, help="B of the lane_batch and devices tables")
    parser.add_argument("--chunk", type=int, default=None, help="the sweeps' chunk (default: the whole batch)")
    parser.add_argument("--diffrax-max-batch", type=int, default=4096, help="skip diffrax on larger batches")
    parser.add_argument("--no-diffrax", action="store_true")
    args = parser.parse_args()
    batches = args.batches or ([1, 64, 256] if args.quick else [1, 64, 1024, 4096])
    table_batch = args.table_batch or (256 if args.quick else 1024)
    repeats = 2 if args.quick else 3

    import diffrax
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import numba
    from peers.compiled_loop import adaptive_options_of, initial_state, integrate_adaptive, parameters

    import peeljax
    from peeljax.integrators.dense import output_times

    if not np.array_equal(output_times(SAVE_DT, T_FINAL), GRID):
        raise RuntimeError(f"output_times({SAVE_DT}, {T_FINAL}) is not the 301-point grid the engines are compared on")
    model, solver = peeljax.PeelingModel(), peeljax.AlphaMethod()
    devices = jax.devices()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = []

    def emit(text=""):
        print(text, flush=True)
        lines.append(text)

    def note(text):
        print(f"  [{text}]", file=sys.stderr, flush=True)

    # ------------------------------------------------------------------ the engines
    def chunk_of(B):
        return min(B, args.chunk) if args.chunk else B

    def error_control(tau, rtol, devices=None, lane_batch=None):
        r = peeljax.sweep(
            model, V, tau, None, T_FINAL, rtol=rtol, atol=1e-3 * rtol, save_dt=SAVE_DT, chunk=chunk_of(len(tau)),
            progress=False, devices=devices, lane_batch=lane_batch,
        )  # fmt: skip
        return r.ys[:, :, 3], r.status == 0, r.accepted_steps

    def uniform_mesh(tau, n):
        r = peeljax.sweep(
            model, V, tau, T_FINAL / n, T_FINAL, save_every=n // (GRID.size - 1), chunk=chunk_of(len(tau)),
            progress=False,
        )  # fmt: skip
        return r.ys[:, :, 3], r.status == 0, np.full(len(tau), n)

    def numba_loop(tau, rtol):
        options = adaptive_options_of(solver, peeljax.PIController(rtol=rtol, atol=1e-3 * rtol))
        v, done, steps = np.empty((len(tau), GRID.size)), np.empty(len(tau), bool), np.empty(len(tau))
        for i, t in enumerate(tau):
            p = parameters(V, float(t))
            ys, status, _, counts, _ = integrate_adaptive(initial_state(p), p, T_FINAL, GRID, **options)
            v[i], done[i], steps[i] = ys[:, 3], status == 0, counts[0]
        return v, done, steps

    def one_diffrax(tau, rtol, atol):
        sol = peeljax.integrate_reference(
            peeljax.HomogenizedODE(model, V, tau), model.initial_state(jnp.asarray(V)), jnp.asarray(GRID),
            solver=diffrax.Kvaerno5(), rtol=rtol, atol=atol, dtmin=1e-12 * T_FINAL, max_steps=200_000,
        )  # fmt: skip
        return sol.ys[:, 3], sol.status, sol.stats["accepted_steps"]

    vmapped_diffrax = jax.jit(jax.vmap(one_diffrax, in_axes=(0, None, None)))

    def diffrax_vmap(tau, rtol, atol=None):
        atol = 1e-2 * rtol if atol is None else atol
        v, status, steps = jax.block_until_ready(
            vmapped_diffrax(jnp.asarray(tau), jnp.asarray(rtol), jnp.asarray(atol))
        )
        return np.asarray(v), np.asarray(status) == 0, np.asarray(steps)

    # ------------------------------------------------------------------ calibration: equal accuracy
    started = time.perf_counter()
    v_ref, ref_ok, _ = diffrax_vmap(CALIBRATION_TAUS, REF_RTOL, REF_ATOL)
    if not ref_ok.all():
        raise RuntimeError(f"the reference stopped at τ = {CALIBRATION_TAUS[~ref_ok]}")
    note(f"reference on {CALIBRATION_TAUS.size} τ: {time.perf_counter() - started:.0f} s")
    calibration = {}

    def calibrate(name, values, run):
        """The first setting (loose to tight) whose max error over the calibration τ is ≤ TARGET."""
        tried = []
        for setting in values:
            try:
                v, _, steps = run(CALIBRATION_TAUS, setting)
                tried.append((setting, float(np.max(relative_errors(v, v_ref))), float(np.mean(steps))))
            except Exception as error:  # noqa: BLE001 (a failing setting is reported)
                tried.append((setting, math.inf, f"failed: {str(error).splitlines()[0][:80]}"))
            if tried[-1][1] <= TARGET:
                break
        calibration[name] = tried
        note(f"{name}: {tried}")
        ok = [t for t in tried if t[1] <= TARGET]
        return (ok[0] if ok else min(tried, key=lambda t: t[1]))[0], bool(ok)

    rtol_a, met_a = calibrate("(a) error control, rtol", ADAPTIVE_RTOLS, error_control)
    n_b, met_b = calibrate("(b) uniform mesh, N", UNIFORM_STEPS, uniform_mesh)
    rtol_c, met_c = calibrate("(c) numba, rtol (that of (a))", (rtol_a,), numba_loop)
    rtol_d, met_d = (None, False)
    if not args.no_diffrax:
        rtol_d, met_d = calibrate("(d) diffrax Kvaerno5, rtol", DIFFRAX_RTOLS, diffrax_vmap)
    calibration_s = time.perf_counter() - started

    engines = {
        "a": ("(a) peeljax.sweep, error control", f"rtol = {rtol_a:g}", met_a, lambda tau: error_control(tau, rtol_a)),
        "b": ("(b) peeljax.sweep, uniform mesh", f"N = {n_b} (dt = 1/{n_b / T_FINAL:g})", met_b,
              lambda tau: uniform_mesh(tau, n_b)),
        "c": ("(c) numba integrate_adaptive, looped", f"rtol = {rtol_c:g}", met_c, lambda tau: numba_loop(tau, rtol_c)),
    }  # fmt: skip
    if rtol_d is not None:
        engines["d"] = ("(d) diffrax Kvaerno5 under jax.vmap", f"rtol = {rtol_d:g}", met_d,
                        lambda tau: diffrax_vmap(tau, rtol_d))  # fmt: skip

    # ------------------------------------------------------------------ throughput by batch size
    rows = []
    for B in batches:
        tau = taus_of(B)
        inputs = {key: tau for key in engines}
        scale = {key: 1.0 for key in engines}
        if B > LOOP_CAP:
            inputs["c"] = tau[np.linspace(0, B - 1, LOOP_CAP).round().astype(int)]
            scale["c"] = B / LOOP_CAP
        keys = [k for k in engines if not (k == "d" and B > args.diffrax_max_batch)]
        first, info = {}, {}
        for key in keys:  # first (compiling) calls
            start = time.perf_counter()
            _, done, steps = engines[key][3](inputs[key])
            first[key] = time.perf_counter() - start
            info[key] = (int(done.sum()), done.size, float(np.mean(steps)))
        times = {key: [] for key in keys}
        for _ in range(repeats if B <= 1024 else 1):
            for key in keys:
                start = time.perf_counter()
                engines[key][3](inputs[key])
                times[key].append(time.perf_counter() - start)
        median = {key: float(np.median(t)) * scale[key] for key, t in times.items()}
        note(f"B = {B}: " + ", ".join(f"{k} {1e6 * t / B:.0f} µs/traj" for k, t in median.items()))
        for key in engines:
            rows.append((B, key, median.get(key), first.get(key), info.get(key), scale[key], median["a"]))

    # ------------------------------------------------------------------ lane_batch and devices, on one batch
    tau = taus_of(table_batch)

    def timed_sweep(**kwargs):
        start = time.perf_counter()
        _, done, _ = error_control(tau, rtol_a, **kwargs)
        first = time.perf_counter() - start
        runs = []
        for _ in range(repeats):
            start = time.perf_counter()
            error_control(tau, rtol_a, **kwargs)
            runs.append(time.perf_counter() - start)
        return float(np.median(runs)), first, int(done.sum())

    lane_rows = []
    for lane_batch in sorted({lb for lb in (1, 8, 64, table_batch) if lb <= table_batch}):
        lane_rows.append((lane_batch, *timed_sweep(lane_batch=lane_batch)))
        note(f"lane_batch = {lane_batch}: {lane_rows[-1][1]:.2f} s")
    device_rows = [(len(devices), *timed_sweep())]
    if len(devices) > 1:
        device_rows.insert(0, (1, *timed_sweep(devices=devices[:1])))

    # ------------------------------------------------------------------ report
    emit("# Sweep throughput at equal accuracy: peeljax.sweep (error control, uniform mesh), numba, diffrax (vmap)")
    emit()
    emit(f"- JAX devices: {len(devices)} × {devices[0].device_kind} (platform {devices[0].platform}); CPU {cpu_model()}, "
         f"{os.cpu_count()} logical cores; load average at start {load:.2f}")  # fmt: skip
    emit(
        f"- jax {jax.__version__}, diffrax {diffrax.__version__}, equinox {eqx.__version__}, numba {numba.__version__}"
    )
    emit(f"- V = {V}, τ log-spaced in {list(TAU_RANGE)} (B = 1: τ = 0.05), t ∈ [0, {T_FINAL:g}], v kept at the "
         f"{GRID.size} times 0, {SAVE_DT:g}, …, {T_FINAL:g}; mode: {'quick' if args.quick else 'full'}, median of "
         f"{repeats} timed runs (1 for B > 1024); sweeps: one chunk per batch"
         f"{'' if not args.chunk else f' of at most {args.chunk}'}, default devices and lane_batch")  # fmt: skip
    emit(f"- accuracy: error = max over the calibration τ {np.round(CALIBRATION_TAUS, 4).tolist()} of max over the "
         f"grid |v − v_ref| / max|v_ref|, v_ref = diffrax Kvaerno5 at rtol {REF_RTOL:g}, atol {REF_ATOL:g}; each "
         f"engine at the cheapest setting tried with error ≤ {TARGET:g} (calibration: {calibration_s:.0f} s)")  # fmt: skip
    emit()
    emit("| B | engine | setting | completed | compile s | run s | µs / trajectory | trajectories / s "
         "| mean accepted steps | time / (a)'s |")  # fmt: skip
    emit("|---:|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for B, key, run, first, info, scale, base in rows:
        name, setting, met, _ = engines[key]
        setting += "" if met else " (target not reached)"
        if run is None:
            emit(f"| {B} | {name} | {setting} | – | – | – | – | – | – | — |")
            continue
        compile_s = "–" if key == "c" else f"{first - run / scale:.1f}"
        sampled = "" if scale == 1 else f" (timed on {info[1]}, × {scale:g})"
        emit(f"| {B} | {name} | {setting} | {info[0]}/{info[1]} | {compile_s} | {run:.3f}{sampled} | "
             f"{1e6 * run / B:.1f} | {B / run:.1f} | {info[2]:.0f} | {run / base:.2f} |")  # fmt: skip
    emit()
    emit("run s: median wall time for the whole batch (returned to the host); compile s = first call − median "
         "(the numba loop is compiled or loaded from its cache beforehand); time / (a)'s > 1: the error-controlled "
         "sweep is faster. Mean accepted steps: per trajectory (the uniform mesh: N).")  # fmt: skip
    emit()
    emit("Settings tried on the calibration τ (setting: max error, mean accepted steps):")
    emit()
    for name, tried in calibration.items():
        emit(f"- {name}: " + "; ".join(
            f"{s:g}: {e:.1e}, {c:.0f}" if not isinstance(c, str) else f"{s:g}: {c}" for s, e, c in tried))  # fmt: skip
    if args.no_diffrax:
        emit("- (d) diffrax: not run (--no-diffrax)")
    emit()
    emit(f"## lane_batch: (a) on B = {table_batch}, {len(devices)} device(s) ({devices[0].platform})")
    emit()
    emit("| lane_batch | completed | compile s | run s | µs / trajectory | time / lane_batch = 1's |")
    emit("|---:|---:|---:|---:|---:|---:|")
    for lane_batch, run, first, done in lane_rows:
        label = f"{lane_batch} (= B)" if lane_batch == table_batch else f"{lane_batch}"
        emit(f"| {label} | {done}/{table_batch} | {first - run:.1f} | {run:.3f} | {1e6 * run / table_batch:.1f} | "
             f"{run / lane_rows[0][1]:.2f} |")  # fmt: skip
    emit()
    emit(
        "lane_batch: lanes a device runs together under vmap (groups of lanes in order of τ, one group after "
        "another); each device holds B / devices lanes, so a lane_batch ≥ that is one vmap over all of them. "
        "Compile s ≈ 0: compiled by an earlier run of the same shapes (lane_batch = 1 is the CPU default)."
    )
    emit()
    emit(f"## devices: (a) on B = {table_batch}, default lane_batch")
    emit()
    emit("| devices | completed | compile s | run s | µs / trajectory | speed-up over 1 device |")
    emit("|---:|---:|---:|---:|---:|---:|")
    for count, run, first, done in device_rows:
        emit(f"| {count} | {done}/{table_batch} | {first - run:.1f} | {run:.3f} | {1e6 * run / table_batch:.1f} | "
             f"{device_rows[0][1] / run:.2f} |")  # fmt: skip
    emit()
    if len(devices) == 1:
        emit("(one JAX device only: nothing to compare)")
    else:
        emit(
            f"devices=jax.devices()[:1] against all {len(devices)}; each device runs its share of the lanes, so the "
            "speed-up is at most the device count (on a CPU: the cores left free by other processes)."
        )
    emit()
    emit(f"Total time: {time.perf_counter() - started:.0f} s.")
    out = HERE / "results" / f"sweep_throughput{'_quick' if args.quick else ''}.md"
    write_result(out, "\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
