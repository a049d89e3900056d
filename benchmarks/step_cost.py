"""Cost per α-method step of peeljax, beside a compiled scalar loop and diffrax Kvaerno5.

For V = 1.1, τ = 0.01, t ∈ [0, 3] and h = 1/82, 1/820, 1/8200 (``--quick``: the first two) it
prints one row per h:

* peeljax: compile time (first call minus a steady call), Newton iterations per step, the
  median µs per step of one trajectory after compilation (``jax.jit`` of
  ``peeljax.integrate_alpha`` over the array leaves of the ODE and the solver, with the
  defaults of ``peeljax.simulate``; ``time.perf_counter`` around the call and
  ``block_until_ready``), and its error in v: max over the grid of |v − v_ref|, v_ref from
  ``peeljax.simulate_reference`` (Kvaerno5, rtol = 1e-12, atol = 1e-14);
* numba: the same algorithm as a compiled loop (``benchmarks/compiled_loop.py``), timed
  round-robin with peeljax so that load on the machine hits both alike;
* diffrax Kvaerno5 (``peeljax.integrate_reference``, i.e. ``simulate_reference``, output on the
  same grid): the loosest rtol in 1e-1 … 1e-12 (atol = 1e-2·rtol) whose error in v on the grid
  is at most the α-method's, its median time per run and per α-method step, and the ratio of
  its run time to peeljax's.

Before timing, the compiled loop is checked against ``peeljax.simulate`` at h = 1/820 (abort if
the largest relative difference in v exceeds 1e-6). Speed is reported, never asserted.

    python benchmarks/step_cost.py            # ~3-5 min on 2 cores
    python benchmarks/step_cost.py --quick    # ~1 min: h = 1/82 and 1/820, fewer repeats
    python benchmarks/step_cost.py --default-xla-flags   # without peeljax's XLA:CPU flag

Importing peeljax adds ``--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=
1000000000`` to ``XLA_FLAGS`` (XLA:CPU then compiles each while loop into one function instead
of dispatching every kernel of its body separately); ``--default-xla-flags`` sets
``PEELJAX_KEEP_XLA_FLAGS=1`` to measure without it. diffrax runs in the same process, so it
gets the same flags. The table goes to
``benchmarks/results/step_cost[_quick][_default_xla_flags].md``.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
V, TAU, T_FINAL = 1.1, 0.01, 3.0
REF_RTOL, REF_ATOL = 1e-12, 1e-14
CHECK_LIMIT = 1e-6


def median(values):
    import numpy as np

    return float(np.median(np.asarray(values)))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="h = 1/82 and 1/820 only, fewer repeats (~1 min)")
    parser.add_argument("--repeats", type=int, default=None, help="timed runs per measurement (default 11, quick 5)")
    parser.add_argument(
        "--default-xla-flags", action="store_true", help="keep XLA_FLAGS as they are (no small-while-loop flag)"
    )
    args = parser.parse_args()
    if args.default_xla_flags:
        os.environ["PEELJAX_KEEP_XLA_FLAGS"] = "1"
    repeats = args.repeats or (5 if args.quick else 11)
    denominators = (82, 820) if args.quick else (82, 820, 8200)
    started = time.perf_counter()

    sys.path.insert(0, str(HERE))
    from machine import cpu_model
    import diffrax
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import jaxlib
    import numba
    import numpy as np
    from compiled_loop import check_jacobian, compare_with_peeljax, initial_state, integrate, options_of, parameters

    import peeljax

    out = []

    def emit(line=""):
        print(line, flush=True)
        out.append(line)

    load = os.getloadavg() if hasattr(os, "getloadavg") else ("?",)
    emit("# Cost per α-method step: peeljax vs a compiled loop (numba) vs diffrax Kvaerno5")
    emit()
    emit(f"- CPU: {cpu_model()}, {os.cpu_count()} logical cores; load average at start {load[0]:.2f}")
    emit(
        f"- python {platform.python_version()}, jax {jax.__version__}, jaxlib {jaxlib.__version__}"
        f", diffrax {diffrax.__version__}, equinox {eqx.__version__}, numba {numba.__version__}, numpy {np.__version__}"
    )
    emit(f"- XLA_FLAGS: `{os.environ.get('XLA_FLAGS', '')}`")
    emit(
        f"- problem: V = {V}, τ = {TAU}, t ∈ [0, {T_FINAL}], paper geometry; mode: {'quick' if args.quick else 'full'}, "
        f"{repeats} timed runs per median"
    )
    solver = peeljax.AlphaMethod()
    options = options_of(solver)
    emit(f"- AlphaMethod() defaults used by both: {options}")
    emit()

    # ------------------------------------------------------------------ correctness
    jac_err = check_jacobian()
    check = compare_with_peeljax(V, TAU, 1 / 820, T_FINAL, solver=solver)
    emit("## Correctness check (h = 1/820): compiled loop vs `peeljax.simulate`")
    emit()
    emit(
        f"- ψ and ψ' of the compiled loop vs `jax.jacfwd` of `HomogenizedODE` at 20 random states: max rel. difference {jac_err:.1e}"
    )
    emit(
        f"- max over the grid of |v_numba − v_peeljax|/|v_peeljax|: {check['max_rel_dv']:.2e} (limit {CHECK_LIMIT:g}); "
        f"max |Δy| {check['max_abs_dy']:.1e}"
    )
    emit(
        f"- Newton iterations: peeljax {check['newton_peeljax']}, numba {check['newton_numba']}; steps that differ: "
        f"{check['steps_with_different_iterations']} (max difference {check['max_step_iteration_difference']})"
    )
    emit(f"- status (peeljax, numba): {check['status']}; subdivided steps: {check['subdivided']}")
    emit()
    if not check["max_rel_dv"] <= CHECK_LIMIT:
        emit(f"ABORT: the compiled loop differs from peeljax by {check['max_rel_dv']:.2e} > {CHECK_LIMIT:g} in v")
        sys.exit(1)

    # ------------------------------------------------------------------ peeljax and numba
    ode = peeljax.HomogenizedODE(peeljax.PeelingModel(), V, TAU)
    y0 = ode.model.initial_state(ode.V)
    dynamic, static = eqx.partition((ode, solver), eqx.is_array)
    p = parameters(V, TAU)
    y0n = initial_state(p)
    integrate(y0n, p, T_FINAL / 10, 10, **options)  # numba: compile (or load the cache)

    rows = {}
    for den in denominators:
        n = round(T_FINAL * den)
        run = jax.jit(lambda d, y, n=n: peeljax.integrate_alpha(*eqx.combine(d, static), y, 0.0, T_FINAL, n))
        t = time.perf_counter()
        sol = jax.block_until_ready(run(dynamic, y0))
        first = time.perf_counter() - t
        jax.block_until_ready(run(dynamic, y0))  # warm-up
        integrate(y0n, p, T_FINAL / n, n, **options)
        t_pj, t_nb = [], []
        for _ in range(repeats):
            t = time.perf_counter()
            jax.block_until_ready(run(dynamic, y0))
            t_pj.append(time.perf_counter() - t)
            t = time.perf_counter()
            integrate(y0n, p, T_FINAL / n, n, **options)
            t_nb.append(time.perf_counter() - t)
        rows[den] = {
            "n": n,
            "compile": first - median(t_pj),
            "its": int(sol.stats["newton_iterations"]) / n,
            "subdivided": int(sol.stats["subdivided_steps"]),
            "status": int(sol.status),
            "pj_run": median(t_pj),
            "nb_run": median(t_nb),
            "v": np.asarray(sol.ys)[:, 3],
        }
        print(
            f"  [h = 1/{den}: peeljax {rows[den]['pj_run'] / n * 1e6:.2f} µs/step, numba "
            f"{rows[den]['nb_run'] / n * 1e6:.2f} µs/step, compile {rows[den]['compile']:.1f} s]",
            flush=True,
        )

    # simulate() end to end (validation + dispatch + the same compiled integrator) at h = 1/820
    jax.block_until_ready(peeljax.simulate(V=V, tau=TAU, dt=1 / 820, t_final=T_FINAL).ys)
    t_sim = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(peeljax.simulate(V=V, tau=TAU, dt=1 / 820, t_final=T_FINAL).ys)
        t_sim.append(time.perf_counter() - t)

    # ------------------------------------------------------------------ diffrax
    # One compiled diffrax run per output grid (quick: only the finest grid, coarser grids are
    # its subsets; the diffrax steps do not depend on the output grid, only the saving does).
    rtols = [10.0**-k for k in range(1, 13)]
    grid_dens = (denominators[-1],) if args.quick else denominators

    def make_reference_run(den):
        n = round(T_FINAL * den)
        ts = jnp.linspace(0.0, T_FINAL, n + 1)
        fn = jax.jit(
            lambda ode, rtol, atol: peeljax.integrate_reference(
                ode, y0, ts, solver=diffrax.Kvaerno5(), rtol=rtol, atol=atol, dtmin=1e-12 * T_FINAL, max_steps=200_000
            )
        )
        return fn

    diffrax_runs = {}
    sweep = {}  # (grid den, rtol) -> (steps, v on that grid, one run's time)
    reference = None
    for gden in grid_dens:
        fn = make_reference_run(gden)
        t = time.perf_counter()
        jax.block_until_ready(fn(ode, jnp.asarray(rtols[0]), jnp.asarray(rtols[0] * 1e-2)))
        diffrax_compile = time.perf_counter() - t
        diffrax_runs[gden] = (fn, diffrax_compile)
        if gden == grid_dens[-1]:
            ref = jax.block_until_ready(fn(ode, jnp.asarray(REF_RTOL), jnp.asarray(REF_ATOL)))
            assert int(ref.status) == 0, "the reference run failed"
            reference = np.asarray(ref.ys)[:, 3]
        for rtol in rtols:
            t = time.perf_counter()
            s = jax.block_until_ready(fn(ode, jnp.asarray(rtol), jnp.asarray(rtol * 1e-2)))
            elapsed = time.perf_counter() - t
            ok = int(s.status) == 0
            sweep[gden, rtol] = (int(s.stats["steps"]), np.asarray(s.ys)[:, 3] if ok else None, elapsed)
        print(f"  [diffrax grid 1/{gden}: compile {diffrax_compile:.1f} s, sweep done]", flush=True)
    round(T_FINAL * grid_dens[-1])

    def on_grid(values_fine_or_own, den, own_den):
        """Values at the points of grid 1/den from values on grid 1/own_den (a refinement)."""
        stride = round(T_FINAL * own_den) // round(T_FINAL * den)
        return values_fine_or_own[::stride]

    for den in denominators:
        r = rows[den]
        r["err"] = float(np.max(np.abs(r["v"] - on_grid(reference, den, grid_dens[-1]))))
        gden = den if den in grid_dens else grid_dens[-1]
        chosen = None
        errs = {}
        for rtol in rtols:
            steps, v, _ = sweep[gden, rtol]
            if v is None:
                errs[rtol] = (steps, np.inf)
                continue
            e = float(np.max(np.abs(on_grid(v, den, gden) - on_grid(reference, den, grid_dens[-1]))))
            errs[rtol] = (steps, e)
            if chosen is None and e <= r["err"]:
                chosen = rtol
        r["sweep"] = errs
        r["diffrax_grid"] = gden
        if chosen is None:
            r["diffrax"] = None
            continue
        fn, _ = diffrax_runs[gden]
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            jax.block_until_ready(fn(ode, jnp.asarray(chosen), jnp.asarray(chosen * 1e-2)))
            times.append(time.perf_counter() - t)
        r["diffrax"] = {"rtol": chosen, "steps": errs[chosen][0], "err": errs[chosen][1], "run": median(times)}

    # ------------------------------------------------------------------ tables
    emit("## Cost per step")
    emit()
    emit(
        "| h | steps | peeljax compile s | Newton it/step | subdivided steps | peeljax µs/step | numba µs/step | "
        "peeljax/numba | peeljax max\\|Δv\\| | diffrax rtol | diffrax steps | diffrax max\\|Δv\\| | diffrax ms/run | "
        "diffrax µs per α-step | diffrax/peeljax per run |"
    )
    emit("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for den in denominators:
        r = rows[den]
        n = r["n"]
        pj, nb = r["pj_run"] / n * 1e6, r["nb_run"] / n * 1e6
        d = r["diffrax"]
        if d is None:
            dcols = "none ≤ 1e-12 | – | – | – | – | –"
        else:
            dcols = (
                f"{d['rtol']:.0e} | {d['steps']} | {d['err']:.1e} | {d['run'] * 1e3:.1f} | {d['run'] / n * 1e6:.2f} | "
                f"{d['run'] / r['pj_run']:.1f}"
            )
        emit(
            f"| 1/{den} | {n} | {r['compile']:.1f} | {r['its']:.2f} | {r['subdivided']} | {pj:.2f} | {nb:.2f} | "
            f"{pj / nb:.1f} | {r['err']:.1e} | {dcols} |"
        )
    emit()
    emit(
        "Columns: compile = first call minus the median steady call; µs/step = median run time / steps (one "
        "trajectory, after compilation, dispatch included); max|Δv| = max over the grid of |v − v_ref|, v_ref = "
        f"Kvaerno5 at rtol {REF_RTOL:g}, atol {REF_ATOL:g}; diffrax rtol = loosest of 1e-1 … 1e-12 (atol = 1e-2·rtol) "
        "with max|Δv| ≤ peeljax's; diffrax steps = accepted + rejected; diffrax µs per α-step = its run time / the "
        "α-method's number of steps."
    )
    sim_us = median(t_sim) / round(T_FINAL * 820) * 1e6
    emit(
        f"`peeljax.simulate(dt=1/820)` end to end (input checks, `filter_jit` dispatch, same compiled integrator): "
        f"{median(t_sim) * 1e3:.2f} ms per call = {sim_us:.2f} µs/step."
    )
    if args.quick:
        emit(
            f"Quick mode: diffrax saved on the 1/{grid_dens[-1]} grid for every row (its error on a coarser grid "
            "is read at that grid's points, its run time includes saving on the finer grid)."
        )
    statuses = {den: rows[den]["status"] for den in denominators}
    if any(statuses.values()):
        emit(f"WARNING: peeljax status not 0: {statuses}")
    emit()
    emit("### diffrax Kvaerno5 tolerance sweep: max|Δv| on each grid (steps)")
    emit()
    emit("| rtol | " + " | ".join(f"h = 1/{den}" for den in denominators) + " | one run, s |")
    emit("|---:|" + "---:|" * len(denominators) + "---:|")
    for rtol in rtols:
        cells = []
        for den in denominators:
            steps, e = rows[den]["sweep"][rtol]
            cells.append(f"{e:.1e} ({steps})")
        emit(f"| {rtol:.0e} | " + " | ".join(cells) + f" | {sweep[grid_dens[-1], rtol][2]:.3f} |")
    emit()
    emit(
        "diffrax compile time (first call, at rtol 1e-1, which runs in milliseconds) per output grid: "
        + ", ".join(f"1/{g}: {diffrax_runs[g][1]:.1f} s" for g in grid_dens)
    )
    emit(f"Total benchmark time: {time.perf_counter() - started:.0f} s.")

    results = HERE / "results"
    results.mkdir(exist_ok=True)
    name = (
        "step_cost"
        + ("_quick" if args.quick else "")
        + ("_default_xla_flags" if args.default_xla_flags else "")
        + ".md"
    )
    (results / name).write_text("\n".join(out) + "\n")
    print(f"(written to {results / name})")


if __name__ == "__main__":
    main()
