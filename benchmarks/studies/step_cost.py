"""Cost per α-method step of peeljax, beside a compiled scalar loop and diffrax Kvaerno5.

For V = 1.1, τ = 0.01, t ∈ [0, 3] and h = 1/82, 1/820, 1/8200 (``--quick``: the first two) it
prints one row per h:

* peeljax: compile time (first call minus a steady call), Newton iterations per step, the
  median µs per step of one trajectory after compilation (``jax.jit`` of
  ``peeljax.integrate_alpha`` over the array leaves of the ODE and the solver, with the
  defaults of ``peeljax.simulate``; ``time.perf_counter`` around the call and
  ``block_until_ready``), and its error in v: max over the grid of |v − v_ref|, v_ref from
  ``peeljax.simulate_reference`` (Kvaerno5, rtol = 1e-12, atol = 1e-14);
* numba: the same algorithm as a compiled loop (``benchmarks/peers/compiled_loop.py``), timed
  round-robin with peeljax so that load on the machine hits both alike;
* diffrax Kvaerno5 (``peeljax.integrate_reference``, i.e. ``simulate_reference``, output on the
  same grid): the loosest rtol in 1e-1 … 1e-12 (atol = 1e-2·rtol) whose error in v on the grid
  is at most the α-method's, its median time per run and per α-method step, and the ratio of
  its run time to peeljax's.

Before timing, the compiled loop is checked against ``peeljax.simulate`` at h = 1/820 (abort if
the largest relative difference in v exceeds 1e-6). Speed is reported, never asserted.

``--adaptive``: the error-controlled mode instead (``peeljax.simulate`` with ``dt=None``), at
rtol = 1e-4 and 1e-6 (atol = 1e-3·rtol), output at 301 equispaced times: median µs per run and
per attempt (accepted + rejected step) of ``peeljax.simulate``, of ``jax.jit`` of
``peeljax.integrators.adaptive.integrate_alpha_adaptive`` called directly (adjoint "reverse",
simulate's default, and, full mode only, "forward") and of ``compiled_loop.integrate_adaptive``
(the same algorithm, step for step), timed round-robin. Before timing, both are run at
τ = 0.01 (and 0.1, full mode) and must agree (v at the output times within 1e-6 relative; the
accepted/rejected/Newton/Jacobian counts are printed side by side). Full mode also gives the
error in v at the output times against Kvaerno5 at rtol 1e-12. The table goes to
``benchmarks/studies/results/step_cost_adaptive[_quick].md``.

    python benchmarks/studies/step_cost.py            # ~3-5 min on 2 cores
    python benchmarks/studies/step_cost.py --quick    # ~1 min: h = 1/82 and 1/820, fewer repeats
    python benchmarks/studies/step_cost.py --default-xla-flags   # without peeljax's XLA:CPU flag
    python benchmarks/studies/step_cost.py --adaptive [--quick]  # error control (~25 s; quick ~15 s)

Importing peeljax adds ``--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=
1000000000`` to ``XLA_FLAGS`` (XLA:CPU then compiles each while loop into one function instead
of dispatching every kernel of its body separately); ``--default-xla-flags`` sets
``PEELJAX_KEEP_XLA_FLAGS=1`` to measure without it. diffrax runs in the same process, so it
gets the same flags. The table goes to
``benchmarks/studies/results/step_cost[_quick][_default_xla_flags].md``.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # benchmarks/: machine, peers
from machine import write_result  # noqa: E402

V, TAU, T_FINAL = 1.1, 0.01, 3.0
REF_RTOL, REF_ATOL = 1e-12, 1e-14
CHECK_LIMIT = 1e-6


def _report(title):
    """The lines of a results file, an ``emit`` that prints and keeps them, and the load average:
    the title, then the machine and the versions that the figures depend on."""
    import diffrax
    import equinox as eqx
    import jax
    import jaxlib
    import numba
    import numpy as np
    from machine import cpu_model

    out = []

    def emit(line=""):
        print(line, flush=True)
        out.append(line)

    load = os.getloadavg() if hasattr(os, "getloadavg") else ("?",)
    emit(title)
    emit()
    emit(f"- CPU: {cpu_model()}, {os.cpu_count()} logical cores; load average at start {load[0]:.2f}")
    emit(
        f"- python {platform.python_version()}, jax {jax.__version__}, jaxlib {jaxlib.__version__}"
        f", diffrax {diffrax.__version__}, equinox {eqx.__version__}, numba {numba.__version__}, numpy {np.__version__}"
    )
    emit(f"- XLA_FLAGS: `{os.environ.get('XLA_FLAGS', '')}`")
    return out, emit, load


def median(values):
    import numpy as np

    return float(np.median(np.asarray(values)))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="h = 1/82 and 1/820 only, fewer repeats (~1 min)")
    parser.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="timed runs per measurement (default 11, quick 5; --adaptive: 31, quick 11)",
    )
    parser.add_argument(
        "--default-xla-flags", action="store_true", help="keep XLA_FLAGS as they are (no small-while-loop flag)"
    )
    parser.add_argument(
        "--adaptive",
        action="store_true",
        help="the error-controlled mode (rtol 1e-4, 1e-6) instead of the uniform mesh",
    )
    args = parser.parse_args()
    if args.default_xla_flags:
        os.environ["PEELJAX_KEEP_XLA_FLAGS"] = "1"
    if args.adaptive:
        return adaptive_main(args)
    repeats = args.repeats or (5 if args.quick else 11)
    denominators = (82, 820) if args.quick else (82, 820, 8200)
    started = time.perf_counter()

    import diffrax
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import numpy as np
    from peers.compiled_loop import check_jacobian, compare_with_peeljax, initial_state, integrate, options_of, parameters

    import peeljax

    out, emit, load = _report("# Cost per α-method step: peeljax vs a compiled loop (numba) vs diffrax Kvaerno5")
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
    name = (
        "step_cost"
        + ("_quick" if args.quick else "")
        + ("_default_xla_flags" if args.default_xla_flags else "")
        + ".md"
    )
    write_result(results / name, "\n".join(out) + "\n")
    print(f"(written to {results / name})")


ADAPTIVE_RTOLS = (1e-4, 1e-6)
ADAPTIVE_ATOL = 1e-3  # atol = ADAPTIVE_ATOL·rtol
N_OUT = 301


def adaptive_main(args):
    """``--adaptive``: cost per attempt of the error-controlled α-method, peeljax vs numba."""
    repeats = args.repeats or (11 if args.quick else 31)  # a run takes milliseconds
    started = time.perf_counter()

    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import numpy as np
    from peers.compiled_loop import (
        adaptive_options_of,
        compare_adaptive_with_peeljax,
        initial_state,
        integrate_adaptive,
        parameters,
    )

    import peeljax
    from peeljax.integrators.adaptive import integrate_alpha_adaptive
    from peeljax.integrators.controller import PIController

    out, emit, load = _report("# Cost per attempt of the error-controlled α-method: peeljax vs a compiled loop (numba)")
    emit(
        f"- problem: V = {V}, τ = {TAU}, t ∈ [0, {T_FINAL}], paper geometry, output at {N_OUT} equispaced times; "
        f"rtol ∈ {{{', '.join(f'{r:g}' for r in ADAPTIVE_RTOLS)}}}, atol = {ADAPTIVE_ATOL:g}·rtol; mode: "
        f"{'quick' if args.quick else 'full'}, {repeats} timed runs per median (round-robin)"
    )
    solver = peeljax.AlphaMethod()
    emit(
        "- settings read by both from `AlphaMethod()` and `PIController`: "
        f"{adaptive_options_of(solver, PIController(rtol=ADAPTIVE_RTOLS[0], atol=ADAPTIVE_ATOL * ADAPTIVE_RTOLS[0]))}"
    )
    emit()

    # ------------------------------------------------------------------ correctness
    emit("## Agreement: `compiled_loop.integrate_adaptive` vs `peeljax.simulate` (error control)")
    emit()
    emit(
        "| τ | rtol | status (pj, nb) | accepted (pj, nb) | rejected | Newton it | Jacobian evals | "
        "max\\|Δv\\|/\\|v\\| at the output times | max rel. Δ of the accepted step times |"
    )
    emit("|---:|---:|---|---|---|---|---|---:|---:|")
    worst = 0.0
    for tau in (TAU,) if args.quick else (TAU, 0.1):
        for rtol in ADAPTIVE_RTOLS:
            c = compare_adaptive_with_peeljax(V, tau, rtol, ADAPTIVE_ATOL * rtol, T_FINAL, N_OUT, solver=solver)
            pj, nb = c["counts_peeljax"], c["counts_numba"]
            cells = " | ".join(f"{pj[i]}, {nb[i]}" for i in range(4))
            emit(
                f"| {tau:g} | {rtol:g} | {c['status'][0]}, {c['status'][1]} | {cells} | {c['max_rel_dv']:.1e} | "
                f"{c['max_rel_dt_steps']:.1e} |"
            )
            worst = max(worst, c["max_rel_dv"]) if c["max_rel_dv"] == c["max_rel_dv"] else float("inf")
            if c["valid_points"][0] != c["valid_points"][1]:
                worst = float("inf")
    emit()
    emit(
        "The accepted step times part at the last-bit level in the first five steps and by up to ~1e-8 (rtol 1e-4) "
        "to ~1e-5 (rtol 1e-6) relative from the sixth on, with the same decisions: at the start (v0 = 1e-10·V, "
        "ω0 = v0/R) the slip ω − v/R cancels and a_{n+1} − a_n is 1e6–1e8 times smaller than a_n, so the first "
        "steps' error norms (1e-18 … 1e-8, growth clipped at 10×) are rounding noise and differ between the two "
        "implementations' last bits of ψ; the PI term ‖e‖_prev^(1/15) carries that into the first unclipped step."
    )
    emit()
    if not worst <= CHECK_LIMIT:
        emit(f"ABORT: the compiled loop differs from peeljax by {worst:.2e} > {CHECK_LIMIT:g} in v")
        sys.exit(1)

    # ------------------------------------------------------------------ timing
    ode = peeljax.HomogenizedODE(peeljax.PeelingModel(), V, TAU)
    y0 = ode.model.initial_state(ode.V)
    ts_np = np.linspace(0.0, T_FINAL, N_OUT)
    ts = jnp.asarray(ts_np)
    p = parameters(V, TAU)
    y0n = initial_state(p)
    dtmin = 1e-12 * T_FINAL
    variants = ("reverse",) if args.quick else ("reverse", "forward")

    def direct(adjoint):
        controller0 = PIController(rtol=ADAPTIVE_RTOLS[0], atol=ADAPTIVE_ATOL * ADAPTIVE_RTOLS[0])
        _, static = eqx.partition((ode, solver, controller0), eqx.is_array)

        def fn(d, y, ts):
            o, s, c = eqx.combine(d, static)
            return integrate_alpha_adaptive(o, s, y, 0.0, T_FINAL, controller=c, ts=ts, dtmin=dtmin, adjoint=adjoint)

        return jax.jit(fn)

    runs = {a: direct(a) for a in variants}
    compile_s = {}
    rows = {}
    for rtol in ADAPTIVE_RTOLS:
        atol = ADAPTIVE_ATOL * rtol
        controller = PIController(rtol=rtol, atol=atol)
        dynamic, _ = eqx.partition((ode, solver, controller), eqx.is_array)
        options = adaptive_options_of(solver, controller)

        def simulate(rtol=rtol, atol=atol):
            return peeljax.simulate(V=V, tau=TAU, t_final=T_FINAL, rtol=rtol, atol=atol, ts=ts_np)

        timed = {"simulate": lambda: jax.block_until_ready(simulate().ys)}
        for a in variants:
            timed[f"direct {a}"] = lambda a=a, dynamic=dynamic: jax.block_until_ready(runs[a](dynamic, y0, ts).ys)
        timed["numba"] = lambda options=options: integrate_adaptive(y0n, p, T_FINAL, ts_np, **options)
        for name, fn in timed.items():  # compile (first rtol) and warm up
            t = time.perf_counter()
            fn()
            if name not in compile_s:
                compile_s[name] = time.perf_counter() - t
            fn()
        times = {name: [] for name in timed}
        for _ in range(repeats):
            for name, fn in timed.items():
                t = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t)
        sol = simulate()
        direct_sol = runs[variants[0]](dynamic, y0, ts)
        _, status, _, counts, _ = integrate_adaptive(y0n, p, T_FINAL, ts_np, **options)
        st = sol.stats
        pj_counts = [
            int(st[k]) for k in ("accepted_steps", "rejected_steps", "newton_iterations", "jacobian_evaluations")
        ]
        same = all(
            int(direct_sol.stats[k]) == v
            for k, v in zip(
                ("accepted_steps", "rejected_steps", "newton_iterations", "jacobian_evaluations"), pj_counts
            )
        )
        rows[rtol] = {
            "pj": pj_counts,
            "nb": [int(c) for c in counts[:4]],
            "status": (int(sol.status), int(status)),
            "direct_same": same,
            "median": {name: median(v) for name, v in times.items()},
            "v": np.asarray(sol.ys)[:, 3],
        }
        m = rows[rtol]["median"]
        print(
            f"  [rtol {rtol:g}: "
            + ", ".join(f"{name} {m[name] * 1e3:.2f} ms" for name in timed)
            + f"; attempts {pj_counts[0] + pj_counts[1]}]",
            flush=True,
        )
    for name in compile_s:  # compile = first call minus the steady call (first rtol)
        compile_s[name] -= rows[ADAPTIVE_RTOLS[0]]["median"][name]

    # For comparison on the same machine: the uniform mesh at h = 1/820 (Newton with a fresh
    # autodiff Jacobian every iteration), as in the table without --adaptive.
    from peers.compiled_loop import integrate, options_of

    n_uniform = round(T_FINAL * 820)
    dyn_u, static_u = eqx.partition((ode, solver), eqx.is_array)
    run_u = jax.jit(lambda d, y: peeljax.integrate_alpha(*eqx.combine(d, static_u), y, 0.0, T_FINAL, n_uniform))
    uniform_options = options_of(solver)
    uniform = {
        "peeljax": lambda: jax.block_until_ready(run_u(dyn_u, y0).ys),
        "numba": lambda: integrate(y0n, p, T_FINAL / n_uniform, n_uniform, **uniform_options),
    }
    for fn in uniform.values():
        fn()
        fn()
    t_uniform = {name: [] for name in uniform}
    for _ in range(repeats):
        for name, fn in uniform.items():
            t = time.perf_counter()
            fn()
            t_uniform[name].append(time.perf_counter() - t)
    t_uniform = {name: median(v) / n_uniform * 1e6 for name, v in t_uniform.items()}

    reference = None
    if not args.quick:  # the error in v at the output times
        ref = peeljax.simulate_reference(V=V, tau=TAU, dt=None, t_final=T_FINAL, ts=ts_np, rtol=REF_RTOL, atol=REF_ATOL)
        if int(ref.status) == 0:
            reference = np.asarray(ref.ys)[:, 3]

    # ------------------------------------------------------------------ table
    emit("## Cost per attempt (accepted + rejected step)")
    emit()
    names = ["simulate"] + [f"direct {a}" for a in variants]
    label = {
        "simulate": "`simulate`",
        "direct reverse": "direct, reverse",
        "direct forward": "direct, forward",
    }
    head = (
        "| rtol | accepted + rejected | Newton it/attempt | Jacobian evals | run | ms/run | µs/attempt | "
        "÷ numba |" + (" max\\|Δv\\| |" if reference is not None else "")
    )
    emit(head)
    emit("|---:|---:|---:|---:|---|---:|---:|---:|" + ("---:|" if reference is not None else ""))
    for rtol in ADAPTIVE_RTOLS:
        r = rows[rtol]
        acc, rej, newton, jevals = r["pj"]
        attempts = acc + rej
        nb_attempts = r["nb"][0] + r["nb"][1]
        m = r["median"]
        nb_us = m["numba"] / nb_attempts * 1e6
        err = f" {np.max(np.abs(r['v'] - reference)):.1e} |" if reference is not None else ""
        lead = f"| {rtol:g} | {acc} + {rej} | {newton / attempts:.2f} | {jevals} |"
        for i, n in enumerate(names):
            us = m[n] / attempts * 1e6
            emit(
                (lead if i == 0 else "| | | | |")
                + f" peeljax {label[n]} | {m[n] * 1e3:.2f} | {us:.2f} | {us / nb_us:.1f} |"
                + (err if i == 0 else (" |" if reference is not None else ""))
            )
        emit(
            "| | | | | numba `integrate_adaptive` | "
            f"{m['numba'] * 1e3:.2f} | {nb_us:.2f} | 1 |" + (" |" if reference is not None else "")
        )
    emit()
    emit(
        "Columns: counts are peeljax's (the numba loop's: "
        + "; ".join(f"rtol {rtol:g}: {rows[rtol]['nb']}" for rtol in ADAPTIVE_RTOLS)
        + ", as [accepted, rejected, Newton, Jacobian]); ms/run = median wall time of one run after "
        "compilation, dispatch and output at the 301 times included; µs/attempt = ms/run / (accepted + rejected); "
        "`simulate` = `peeljax.simulate(V=1.1, tau=0.01, t_final=3, rtol=…, atol=…, ts=…)` (input checks and "
        "`jax.jit` dispatch included); direct = `jax.jit` of `integrate_alpha_adaptive` over the array leaves of "
        "(ODE, AlphaMethod, PIController), adjoint \"reverse\" (equinox's checkpointed while loop, simulate's "
        'default) or "forward" (`lax.while_loop`); numba = `compiled_loop.integrate_adaptive`'
        + (
            f"; max|Δv| = max over the output times of |v − v_ref|, v_ref = Kvaerno5 at rtol {REF_RTOL:g}"
            if reference is not None
            else ""
        )
        + "."
    )
    emit(
        f"For comparison, the uniform mesh at h = 1/820 ({n_uniform} steps, Newton with a fresh Jacobian every "
        f"iteration) on this machine in this run: peeljax {t_uniform['peeljax']:.2f} µs/step, numba "
        f"{t_uniform['numba']:.2f} µs/step, ratio {t_uniform['peeljax'] / t_uniform['numba']:.1f}."
    )
    emit(
        "Compile time (first call minus a steady call): "
        + ", ".join(f"{label[n]} {compile_s[n]:.1f} s" for n in names if n != "simulate")
        + " (`simulate` was compiled by the agreement check; numba: cached or compiled on first use)."
    )
    statuses = {rtol: rows[rtol]["status"] for rtol in ADAPTIVE_RTOLS}
    if any(any(s) for s in statuses.values()):
        emit(f"WARNING: status not 0 (peeljax, numba): {statuses}")
    if not all(rows[rtol]["direct_same"] for rtol in ADAPTIVE_RTOLS):
        emit("WARNING: the direct call's counts differ from simulate's")
    emit(
        f"Load average at the end {os.getloadavg()[0]:.2f}. Total benchmark time: {time.perf_counter() - started:.0f} s."
    )

    results = HERE / "results"
    name = (
        "step_cost_adaptive"
        + ("_quick" if args.quick else "")
        + ("_default_xla_flags" if args.default_xla_flags else "")
        + ".md"
    )
    write_result(results / name, "\n".join(out) + "\n")
    print(f"(written to {results / name})")


if __name__ == "__main__":
    main()
