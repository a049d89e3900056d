"""Why a peeljax α-step costs what it does: timed variants of a copy of the step.

Each XLA configuration runs in its own process (XLA_FLAGS is read once, when JAX's CPU backend
starts). In each process every variant of ``benchmarks/step_variants.py`` is compiled, then all
variants, ``peeljax.integrate_alpha`` itself and the numba loop are timed round-robin (so that
load on the machine hits them alike), and the median per step is reported with its ratio to
the copied baseline under default flags and to the numba loop of the same process.

    python benchmarks/step_experiments.py            # h = 1/820, all variants (~4 min on 2 cores)
    python benchmarks/step_experiments.py --quick    # fewer variants and repeats (~1.5 min)

Also prints the optimized-HLO size of one trajectory (fusions per Newton iteration body).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SMALL_LOOPS = "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000000"
FLAG_SETS = {
    "default": "",
    "small-while-loops": SMALL_LOOPS,
    "thunk-runtime=false": "--xla_cpu_use_thunk_runtime=false",
}


def variants(quick):
    from step_variants import Variant

    full = [
        Variant(),
        Variant(predictor=True),
        Variant(reuse=True),
        Variant(predictor=True, reuse=True),
        Variant(psi="semi"),
        Variant(psi="semi", predictor=True, reuse=True),
        Variant(psi="analytic"),
        Variant(psi="analytic", predictor=True),
        Variant(psi="analytic", reuse=True),
        Variant(psi="analytic", predictor=True, reuse=True),
        Variant(psi="analytic", predictor=True, reuse=True, no_cond=True),
        Variant(psi="analytic", predictor=True, reuse=True, unroll=4),
    ]
    if quick:
        return [full[0], full[6], full[9]]
    return full


def hlo_summary(fn, args):
    """Instruction counts of the compiled trajectory: fusions in each while body."""
    import jax

    text = jax.jit(fn).lower(*args).compile().as_text()
    blocks = {
        m.group(1).lstrip("%"): m.group(2) for m in re.finditer(r"\n(%?[\w.\-]+) \(.*?\{\n(.*?)\n\}", text, re.DOTALL)
    }
    bodies = []
    for m in re.finditer(r"while\(.*?condition=%([\w.\-]+), body=%([\w.\-]+)", text):
        body = blocks.get(m.group(2), "")
        kernels = len(re.findall(r"=\s+\S+\s+(fusion|dot|custom-call|call)\(", body))
        bodies.append(kernels)
    return {
        "hlo_lines": text.count("\n"),
        "while_body_kernels": sorted(bodies, reverse=True),
        "small_calls": text.count("xla_cpu_small_call"),
    }


def child(flag_name, n_steps, repeats, quick):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + FLAG_SETS[flag_name]).strip()
    sys.path.insert(0, str(HERE))
    import equinox as eqx
    import jax
    import numpy as np
    from compiled_loop import initial_state, integrate, options_of, parameters
    from step_variants import build

    import peeljax

    solver = peeljax.AlphaMethod()
    options = options_of(solver)
    p = parameters()
    y0n = initial_state(p)
    ref = integrate(y0n, p, 3.0 / n_steps, n_steps, **options)
    v_ref = ref[0][:, 3]

    entries = []  # (label, fn, args, compile_s, its, maxrel)
    # the library itself
    ode = peeljax.HomogenizedODE(peeljax.PeelingModel(), 1.1, 0.01)
    dyn, static = eqx.partition((ode, solver), eqx.is_array)
    lib = jax.jit(lambda d, y: peeljax.integrate_alpha(*eqx.combine(d, static), y, 0.0, 3.0, n_steps))
    lib_args = (dyn, ode.model.initial_state(ode.V))
    t = time.perf_counter()
    out = jax.block_until_ready(lib(*lib_args))
    entries.append(
        [
            "peeljax.integrate_alpha",
            lib,
            lib_args,
            time.perf_counter() - t,
            int(out.stats["newton_iterations"]),
            float(np.max(np.abs(np.asarray(out.ys)[:, 3] - v_ref) / v_ref)),
        ]
    )
    hlo = hlo_summary(lambda d, y: peeljax.integrate_alpha(*eqx.combine(d, static), y, 0.0, 3.0, n_steps), lib_args)
    for v in variants(quick):
        fn, args = build(v, n_steps, options)
        t = time.perf_counter()
        ys, its, _levels, _status = jax.block_until_ready(fn(*args))
        compile_s = time.perf_counter() - t
        maxrel = float(np.max(np.abs(np.asarray(ys)[:, 3] - v_ref) / v_ref))
        entries.append([v.label(), fn, args, compile_s, int(np.sum(its)), maxrel])
    numba_entry = ["numba (compiled loop)", None, None, 0.0, int(ref[1].sum()), 0.0]
    entries.append(numba_entry)

    times = {e[0]: [] for e in entries}
    for _ in range(repeats):
        for label, fn, args, *_ in entries:
            t = time.perf_counter()
            if fn is None:
                integrate(y0n, p, 3.0 / n_steps, n_steps, **options)
            else:
                jax.block_until_ready(fn(*args))
            times[label].append(time.perf_counter() - t)
    rows = []
    for label, fn, args, compile_s, its, maxrel in entries:
        ts = sorted(times[label])
        rows.append(
            {
                "label": label,
                "compile_s": compile_s,
                "its_per_step": its / n_steps,
                "median_us": float(np.median(ts)) / n_steps * 1e6,
                "min_us": ts[0] / n_steps * 1e6,
                "maxrel_v": maxrel,
            }
        )
    print("RESULT " + json.dumps({"flags": flag_name, "xla_flags": os.environ["XLA_FLAGS"], "rows": rows, "hlo": hlo}))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--steps", type=int, default=2460, help="steps over t in [0, 3] (default 2460: h = 1/820)")
    parser.add_argument("--flags", nargs="*", default=None, help=f"XLA flag sets among {list(FLAG_SETS)}")
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    repeats = 5 if args.quick else 11
    if args.child:
        child(args.child, args.steps, repeats, args.quick)
        return
    flag_names = args.flags or (["default", "small-while-loops"] if args.quick else list(FLAG_SETS))
    results = []
    for name in flag_names:
        cmd = [sys.executable, __file__, "--child", name, "--steps", str(args.steps)] + (
            ["--quick"] if args.quick else []
        )
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        line = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
        if proc.returncode != 0 or not line:
            print(f"[{name}] failed:\n{proc.stderr[-3000:]}")
            continue
        results.append(json.loads(line[0][len("RESULT ") :]))
    if not results:
        sys.exit(1)
    base = next(
        (
            r["median_us"]
            for res in results
            if res["flags"] == "default"
            for r in res["rows"]
            if r["label"] == "autodiff"
        ),
        None,
    )
    lines = [f"h = 3/{args.steps}; medians of {repeats} round-robin runs; times in µs per step", ""]
    for res in results:
        numba = next(r["median_us"] for r in res["rows"] if r["label"].startswith("numba"))
        lines.append(f"### XLA flags: {res['flags']} (`XLA_FLAGS={res['xla_flags']!s}`)")
        lines.append("")
        lines.append(
            f"optimized HLO of peeljax.integrate_alpha: {res['hlo']['hlo_lines']} lines; kernels per while body "
            f"(largest first): {res['hlo']['while_body_kernels']}; while loops compiled as one call: {res['hlo']['small_calls']}"
        )
        lines.append("")
        lines.append(
            "| variant | compile s | Newton it/step | median µs/step | min µs/step | speed-up vs copy (default flags) | ratio to numba | max rel Δv vs numba |"
        )
        lines.append("|---|---:|---:|---:|---:|---:|---:|---:|")
        for r in res["rows"]:
            speed = f"{base / r['median_us']:.2f}×" if base else "–"
            lines.append(
                f"| {r['label']} | {r['compile_s']:.1f} | {r['its_per_step']:.3f} | {r['median_us']:.2f} | {r['min_us']:.2f} | "
                f"{speed} | {r['median_us'] / numba:.2f} | {r['maxrel_v']:.1e} |"
            )
        lines.append("")
    text = "\n".join(lines)
    print(text)
    out = HERE / "results"
    out.mkdir(exist_ok=True)
    (out / ("step_experiments_quick.md" if args.quick else "step_experiments.md")).write_text(text + "\n")


if __name__ == "__main__":
    main()
