"""Throughput of the batched α-method (``peeljax.sweep``'s engine) beside the alternatives.

Problem: V = 1.1, τ log-spaced in [0.005, 0.5] (one τ per trajectory), h = 1/820,
t ∈ [0, 3] (2460 steps), the defaults of ``peeljax.simulate``. For batches of B trajectories
it prints µs per trajectory-step (run time / (B·2460)) and trajectories per second for:

* peeljax batched: ``peeljax.sweeps.run_batch`` (the compiled ``vmap``ped scan with on-the-fly
  summaries that ``peeljax.sweep`` runs per chunk), one call on all B lanes;
* peeljax loop: the compiled single-trajectory run (batch 1) called once per trajectory;
* numba: the same algorithm as a compiled loop (``benchmarks/compiled_loop.py``), looped;
* diffrax Kvaerno5 under ``jax.vmap`` (``peeljax.integrate_reference``, output on the
  α-method's grid) at the loosest rtol in 1e-2 … 1e-10 (atol = 1e-2·rtol) whose max|Δv| over
  the grid, on calibration τ values, is at most the α-method's (both against Kvaerno5 at
  rtol 1e-12, atol 1e-14).

Times are medians of repeated runs after compilation (``block_until_ready``); loops over
large batches are timed on an evenly spread subset of the τ values and scaled to B (said in
the table). Speed is reported, never asserted.

    python benchmarks/sweep_throughput.py --quick   # ~2-4 min on 2 busy cores: B = 1, 64, 1024
    python benchmarks/sweep_throughput.py           # B = 1, 64, 1024, 4096
    python benchmarks/sweep_throughput.py --batches 1 64 10000 100000   # e.g. on a GPU

The table goes to ``benchmarks/results/sweep_throughput[_quick].md``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from machine import cpu_model  # noqa: E402
V, T_FINAL, DEN = 1.1, 3.0, 820
TAU_RANGE = (0.005, 0.5)


def median(values):
    import numpy as np

    return float(np.median(values))


def timed(fn, repeats):
    out, times = None, []
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return out, median(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--batches", type=int, nargs="+", default=None)
    parser.add_argument("--no-diffrax", action="store_true")
    args = parser.parse_args()
    batches = args.batches or ([1, 64, 1024] if args.quick else [1, 64, 1024, 4096])
    loop_subset = 16 if args.quick else 64
    repeats = 2 if args.quick else 3

    import diffrax
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import numpy as np
    from compiled_loop import initial_state, integrate, options_of, parameters

    import peeljax
    from peeljax.sweeps import run_batch

    n = round(T_FINAL * DEN)
    model, solver = peeljax.PeelingModel(), peeljax.AlphaMethod()
    t_final, window = jnp.asarray(T_FINAL), jnp.asarray([0.5, 1.0])
    lines = []

    def emit(text=""):
        print(text, flush=True)
        lines.append(text)

    emit("# Sweep throughput: batched α-method vs looped runs, numba, diffrax Kvaerno5 (vmap)")
    emit()
    emit(f"- device: {jax.devices()[0].device_kind} x {len(jax.devices())}; CPU {cpu_model()}, "
         f"{os.cpu_count()} logical cores, load average at start {os.getloadavg()[0]:.2f}")  # fmt: skip
    emit(f"- jax {jax.__version__}, diffrax {diffrax.__version__}, equinox {eqx.__version__}")
    emit(f"- V = {V}, τ log-spaced in {list(TAU_RANGE)}, h = 1/{DEN}, t ∈ [0, {T_FINAL}] ({n} steps); "
         f"mode: {'quick' if args.quick else 'full'}, {repeats} timed runs per median")  # fmt: skip
    emit()

    def taus(B):
        return np.geomspace(*TAU_RANGE, B) if B > 1 else np.array([0.05])

    # ------------------------------------------------------------------ peeljax batched
    rows = {}
    for B in batches:
        Vb, tb = jnp.full(B, V), jnp.asarray(taus(B))
        call = lambda Vb=Vb, tb=tb: jax.block_until_ready(
            run_batch(model, solver, Vb, tb, {}, t_final, window, n, None, None)
        )
        start = time.perf_counter()
        summary = call()
        first = time.perf_counter() - start
        _, run = timed(call, repeats if B <= 1024 else 1)
        rows[B] = {"compile": first - run, "batched": run, "completed": int(np.sum(np.asarray(summary.status) == 0)),
                   "newton": float(np.mean(np.asarray(summary.newton_iterations))) / n}  # fmt: skip
        print(f"  [B = {B}: batched {run / (B * n) * 1e6:.3f} µs/traj-step, compile {first - run:.1f} s]", flush=True)

    # ------------------------------------------------------------------ loops: peeljax single, numba
    single = lambda V_, tau_: run_batch(model, solver, V_, tau_, {}, t_final, window, n, None, None)
    jax.block_until_ready(single(jnp.full(1, V), jnp.full(1, 0.05)))
    options = options_of(solver)
    p0 = parameters(V, 0.05)
    integrate(initial_state(p0), p0, T_FINAL / 10, 10, **options)  # compile or load the numba cache
    for B in batches:
        sample = taus(B)[np.linspace(0, B - 1, min(B, loop_subset)).round().astype(int)]

        def loop_peeljax(sample=sample):
            for tau in sample:
                jax.block_until_ready(single(jnp.full(1, V), jnp.full(1, tau)))

        def loop_numba(sample=sample):
            for tau in sample:
                p = parameters(V, float(tau))
                integrate(initial_state(p), p, T_FINAL / n, n, **options)

        _, t_loop = timed(loop_peeljax, repeats)
        _, t_numba = timed(loop_numba, repeats)
        rows[B]["loop"] = t_loop * B / sample.size
        rows[B]["numba"] = t_numba * B / sample.size
        rows[B]["subset"] = sample.size

    # ------------------------------------------------------------------ diffrax at equal error
    diffrax_note = "not run (--no-diffrax)"
    if not args.no_diffrax:
        ts = jnp.linspace(0.0, T_FINAL, n + 1)
        calib = np.geomspace(*TAU_RANGE, 4)

        run_ref = jax.jit(jax.vmap(lambda tau, rtol, atol: peeljax.integrate_reference(
            peeljax.HomogenizedODE(model, V, tau), model.initial_state(jnp.asarray(V)), ts, solver=diffrax.Kvaerno5(),
            rtol=rtol, atol=atol, dtmin=1e-12 * T_FINAL, max_steps=200_000), in_axes=(0, None, None)))  # fmt: skip
        ref = run_ref(jnp.asarray(calib), jnp.asarray(1e-12), jnp.asarray(1e-14))
        v_ref = np.asarray(ref.ys)[:, :, 3]
        alpha = jax.vmap(lambda tau: peeljax.integrate_alpha(peeljax.HomogenizedODE(model, V, tau), solver,
                                                             model.initial_state(jnp.asarray(V)), 0.0, T_FINAL, n))(
            jnp.asarray(calib))  # fmt: skip
        err_alpha = float(np.nanmax(np.abs(np.asarray(alpha.ys)[:, :, 3] - v_ref)))
        chosen, errs = None, {}
        for k in range(2, 11):
            rtol = 10.0**-k
            s = run_ref(jnp.asarray(calib), jnp.asarray(rtol), jnp.asarray(rtol * 1e-2))
            ok = np.all(np.asarray(s.status) == 0)
            errs[rtol] = float(np.nanmax(np.abs(np.asarray(s.ys)[:, :, 3] - v_ref))) if ok else np.inf
            if errs[rtol] <= err_alpha:
                chosen = rtol
                break
        diffrax_note = (f"α-method max|Δv| on the calibration τ {np.round(calib, 4).tolist()}: {err_alpha:.2e}; "
                        f"Kvaerno5 errors by rtol: " + ", ".join(f"{r:.0e}: {e:.1e}" for r, e in errs.items())
                        + f"; chosen rtol {chosen}")  # fmt: skip
        if chosen is not None:
            for B in batches:
                if B > (64 if args.quick else 1024):
                    continue
                tb = jnp.asarray(taus(B))
                call = lambda tb=tb: jax.block_until_ready(run_ref(tb, jnp.asarray(chosen), jnp.asarray(chosen * 1e-2)))
                call()
                _, rows[B]["diffrax"] = timed(call, repeats)

    # ------------------------------------------------------------------ table
    emit("| B | completed | Newton it/step | compile s | batched µs/traj-step | batched traj/s | loop µs/traj-step | "
         "numba µs/traj-step | diffrax vmap µs/traj-step | batched/numba | diffrax/batched |")  # fmt: skip
    emit("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for B, r in rows.items():
        per = lambda t, B=B: t / (B * n) * 1e6
        d = r.get("diffrax")
        emit(f"| {B} | {r['completed']}/{B} | {r['newton']:.2f} | {r['compile']:.1f} | {per(r['batched']):.3f} | "
             f"{B / r['batched']:.1f} | {per(r['loop']):.3f} | {per(r['numba']):.3f} | "
             f"{'—' if d is None else format(per(d), '.3f')} | {r['batched'] / r['numba']:.2f} | "
             f"{'—' if d is None else format(d / r['batched'], '.1f')} |")  # fmt: skip
    emit()
    emit(
        "µs/traj-step = run time / (B × steps); loops (peeljax single-trajectory run, numba) timed on "
        f"{min(batches[-1], loop_subset)} τ spread over the batch's and scaled to B; diffrax column: "
        "Kvaerno5 under vmap, output on the α-method's grid, at the rtol below (— : batch not run)."
    )
    emit()
    emit(f"diffrax calibration: {diffrax_note}")
    out = HERE / "results" / f"sweep_throughput{'_quick' if args.quick else ''}.md"
    out.parent.mkdir(exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
