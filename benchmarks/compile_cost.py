"""Compile time of the gradient through the paper's uniform mesh, before and after its steps are rematerialized.

The run: V = 1.1 m/s, τ = 0.1 s, t ∈ [0, 1] s on the paper's mesh (h = 1/82, 82 steps), the
loss mean(v² + α) over the valid points; the gradient is with respect to φ's 14 coefficients
(``jax.value_and_grad``, reverse mode). Each measurement is a fresh process (nothing cached)
that traces, lowers and compiles the forward run and then the gradient, and times their runs
(median of 20 calls after the first): wall and CPU seconds of each phase (XLA:CPU compiles on
several threads, so its CPU time can exceed its wall time; on a loaded machine the CPU time is
the steadier measure).

* ``before``: each step's linearization stored for the reverse pass (``uniform_mesh._REMAT_STEPS
  = False``, what peeljax did before);
* ``after``: each step rematerialized (the default, :mod:`peeljax.integrators.uniform_mesh`).

The variants run round-robin (``--repeats`` rounds) so that both share the machine's load, which
is stated with the table; then one process compiles both gradients and calls them in turn (the
run times' ratio under the same load); the gradients of both are compared (largest relative
difference).

    python benchmarks/compile_cost.py [--repeats 2]     # writes results/compile_cost.md
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import cpu_model, write_result  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
V, TAU, T_FINAL, N_STEPS = 1.1, 0.1, 1.0, 82


def measure(variant: str) -> dict:
    """One fresh-process measurement (runs in the child)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import peeljax as pj
    from peeljax.integrators import uniform_mesh

    uniform_mesh._REMAT_STEPS = variant == "after"

    def loss(law):
        model = pj.PeelingModel(adhesion=law)
        ode = pj.HomogenizedODE(model, V, TAU)
        sol = uniform_mesh.integrate_alpha(ode, pj.AlphaMethod(), model.initial_state(V), 0.0, T_FINAL, N_STEPS)
        ys = jnp.where(sol.valid[:, None], sol.ys, 0.0)
        return jnp.sum(ys[:, 3] ** 2 + ys[:, 0]) / jnp.sum(sol.valid)

    law = pj.AdhesionLaw()
    row = {"variant": variant}
    for name, fn in (("forward", loss), ("gradient", jax.value_and_grad(loss))):
        wall, cpu = time.perf_counter(), time.process_time()
        lowered = jax.jit(fn).trace(law).lower()
        row[f"{name}_trace"] = (time.perf_counter() - wall, time.process_time() - cpu)
        wall, cpu = time.perf_counter(), time.process_time()
        compiled = lowered.compile()
        row[f"{name}_compile"] = (time.perf_counter() - wall, time.process_time() - cpu)
        out = jax.block_until_ready(compiled(law))
        times = []
        for _ in range(20):
            began = time.perf_counter()
            jax.block_until_ready(compiled(law))
            times.append(time.perf_counter() - began)
        row[f"{name}_run_ms"] = 1e3 * statistics.median(times)
    row["gradient"] = np.concatenate([np.ravel(leaf) for leaf in jax.tree_util.tree_leaves(out[1])]).tolist()
    row["value"] = float(out[0])
    return row


def run_ratio(calls: int = 300) -> dict:
    """Both gradients compiled in one process and called in turn (they share the load): medians."""
    import jax
    import jax.numpy as jnp

    import peeljax as pj
    from peeljax.integrators import uniform_mesh

    def loss(law):
        model = pj.PeelingModel(adhesion=law)
        ode = pj.HomogenizedODE(model, V, TAU)
        sol = uniform_mesh.integrate_alpha(ode, pj.AlphaMethod(), model.initial_state(V), 0.0, T_FINAL, N_STEPS)
        ys = jnp.where(sol.valid[:, None], sol.ys, 0.0)
        return jnp.sum(ys[:, 3] ** 2 + ys[:, 0]) / jnp.sum(sol.valid)

    law = pj.AdhesionLaw()
    compiled = {}
    for variant in ("before", "after"):
        uniform_mesh._REMAT_STEPS = variant == "after"
        compiled[variant] = jax.jit(jax.value_and_grad(loss)).lower(law).compile()
        jax.block_until_ready(compiled[variant](law))
    times = {"before": [], "after": []}
    for _ in range(calls):
        for variant, fn in compiled.items():
            began = time.perf_counter()
            jax.block_until_ready(fn(law))
            times[variant].append(time.perf_counter() - began)
    return {variant: 1e3 * statistics.median(t) for variant, t in times.items()}


def child(variant: str) -> dict:
    result = subprocess.run(
        [sys.executable, __file__, "--child", variant], check=True, capture_output=True, text=True, timeout=1800
    )
    return json.loads(result.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2, help="rounds of (before, after)")
    parser.add_argument("--child", choices=("before", "after", "ratio"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(run_ratio() if args.child == "ratio" else measure(args.child)))
        return
    rows = []
    loads = [os.getloadavg()[0]]
    for _ in range(args.repeats):
        for variant in ("before", "after"):
            rows.append(child(variant))
            loads.append(os.getloadavg()[0])
            print({k: v for k, v in rows[-1].items() if k != "gradient"}, flush=True)
    ratio = child("ratio")
    loads.append(os.getloadavg()[0])
    import numpy as np

    grads = {row["variant"]: np.asarray(row["gradient"]) for row in rows}
    difference = float(np.max(np.abs(grads["after"] - grads["before"]) / np.maximum(np.abs(grads["before"]), 1e-300)))

    def med(variant, key, index=None):
        values = [row[key] if index is None else row[key][index] for row in rows if row["variant"] == variant]
        return statistics.median(values)

    lines = [
        "| | forward: trace+lower [s] | forward: compile wall / CPU [s] | forward run [ms] | gradient: trace+lower [s] "
        "| gradient: compile wall / CPU [s] | first call wall [s] | gradient run [ms] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for variant in ("before", "after"):
        first = med(variant, "gradient_trace", 0) + med(variant, "gradient_compile", 0)
        lines.append(
            f"| {variant} | {med(variant, 'forward_trace', 0):.2f} | {med(variant, 'forward_compile', 0):.2f} / "
            f"{med(variant, 'forward_compile', 1):.2f} | {med(variant, 'forward_run_ms'):.3f} | "
            f"{med(variant, 'gradient_trace', 0):.2f} | {med(variant, 'gradient_compile', 0):.2f} / "
            f"{med(variant, 'gradient_compile', 1):.2f} | {first:.1f} | {med(variant, 'gradient_run_ms'):.3f} |"
        )
    text = "\n".join([
        "# Compile time of the gradient on the paper's mesh (before / after rematerialized steps)",
        "",
        f"V = {V} m/s, tau = {TAU} s, [0, {T_FINAL:g}] s, {N_STEPS} steps (h = 1/82); gradient w.r.t. phi's 14 "
        f"coefficients. Fresh process per measurement, medians of {args.repeats} round-robin rounds. "
        f"{cpu_model()}, {os.cpu_count()} cores; load average {min(loads):.1f}–{max(loads):.1f} during the runs "
        "(wall times grow with the load; CPU times much less).",
        "",
        *lines,
        "",
        f"Gradient run, both compiled in one process and called in turn 300 times (medians): before "
        f"{ratio['before']:.3f} ms, after {ratio['after']:.3f} ms (after/before {ratio['after'] / ratio['before']:.2f}).",
        "",
        f"Largest relative difference between the two gradients: {difference:.1e}.",
        "",
    ])  # fmt: skip
    out = write_result(RESULTS / "compile_cost.md", text)
    print(text)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
