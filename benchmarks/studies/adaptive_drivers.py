"""The error-controlled α-method: peeljax's own driver against the α-method inside diffrax.

Problem: V = 1.1 m/s, τ = 0.01 and 0.1 s, t ∈ [0, 3 s], output on the 301-point grid, error =
max |Δv| there against diffrax Kvaerno5 at rtol 1e-11. For each rtol (atol = 1e-3·rtol):

* ``peeljax.simulate(..., rtol=…, ts=grid)``: input checks, dispatch and the compiled run;
* the same compiled run called directly (``jax.jit`` of ``integrate_alpha_adaptive``);
* ``diffrax.diffeqsolve`` with ``peeljax.AlphaSolver()`` and ``diffrax.PIDController`` on
  (α, ω, u, log v) (``peeljax.LogTransformedODE``), saving at the grid;

and the fixed cost of a call on a 15-step problem: ``simulate``, its compiled run, and a bound
``peeljax.Simulator`` (options checked and placed on the device once). Medians of round-robin
repeats; ratios are to ``peeljax.simulate`` in the same run.

    python benchmarks/studies/adaptive_drivers.py [--quick]     # writes benchmarks/studies/results/adaptive_drivers.md
    python benchmarks/studies/adaptive_drivers.py --overhead-only   # the fixed cost alone (seconds):
                                                            # writes benchmarks/studies/results/adaptive_drivers_overhead.md
"""

from __future__ import annotations

import argparse
import importlib
import statistics
import sys
import time
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: machine
from machine import cpu_model, write_result  # noqa: E402

import peeljax as pj
from peeljax.homogenized import HomogenizedODE
from peeljax.integrators import integrate_alpha_adaptive, integrator_for

RESULTS = Path(__file__).resolve().parent / "results" / "adaptive_drivers.md"
OVERHEAD_RESULTS = RESULTS.with_name("adaptive_drivers_overhead.md")
V, T_FINAL = 1.1, 3.0
GRID = np.linspace(0.0, T_FINAL, 301)


def _timed(fn, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return times


@jax.jit
def _direct(ode, controller, ts):
    return integrate_alpha_adaptive(
        ode, pj.AlphaMethod(), ode.model.initial_state(ode.V), 0.0, T_FINAL, controller=controller, ts=ts
    )


@jax.jit
def _in_diffrax(ode, rtol, atol, ts):
    log_ode = pj.LogTransformedODE(ode, (3,))
    y0 = ode.model.initial_state(ode.V)
    z0 = y0.at[3].set(jnp.log(y0[3]))
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(lambda t, z, args: log_ode(z)),
        pj.AlphaSolver(),
        0.0,
        T_FINAL,
        1e-6,
        z0,
        saveat=diffrax.SaveAt(ts=ts),
        stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
        max_steps=100_000,
        throw=False,
    )
    return sol.ys[:, 3], sol.stats["num_accepted_steps"], sol.stats["num_rejected_steps"]


def compare(tau, rtols, repeats):
    model = pj.PeelingModel()
    reference = np.asarray(
        pj.simulate_reference(model, V=V, tau=tau, dt=0.01, t_final=T_FINAL, rtol=1e-11, atol=1e-13).v
    )
    ode = HomogenizedODE(model, V, tau)
    ts = jnp.asarray(GRID)
    rows = []
    for rtol in rtols:
        atol = 1e-3 * rtol
        controller = pj.PIController(rtol=rtol, atol=atol)
        runs = {
            "peeljax.simulate": lambda: pj.simulate(
                model, V=V, tau=tau, t_final=T_FINAL, rtol=rtol, atol=atol, ts=GRID
            ),
            "compiled run (jax.jit)": lambda: _direct(ode, controller, ts),
            "diffrax + AlphaSolver": lambda: _in_diffrax(ode, rtol, atol, ts),
        }
        results = {name: jax.block_until_ready(fn()) for name, fn in runs.items()}  # compile, check
        times = {name: [] for name in runs}
        for _ in range(repeats):  # round robin
            for name, fn in runs.items():
                times[name] += _timed(fn, 1)
        own = results["peeljax.simulate"]
        log_v, accepted, rejected = results["diffrax + AlphaSolver"]
        errors = {
            "peeljax.simulate": np.max(np.abs(np.asarray(own.v) - reference)),
            "compiled run (jax.jit)": np.max(np.abs(np.asarray(results["compiled run (jax.jit)"].v) - reference)),
            "diffrax + AlphaSolver": np.max(np.abs(np.exp(np.asarray(log_v)) - reference)),
        }
        steps = {
            "peeljax.simulate": (int(own.stats["accepted_steps"]), int(own.stats["rejected_steps"])),
            "compiled run (jax.jit)": (int(own.stats["accepted_steps"]), int(own.stats["rejected_steps"])),
            "diffrax + AlphaSolver": (int(accepted), int(rejected)),
        }
        base = statistics.median(times["peeljax.simulate"])
        for name in runs:
            median = statistics.median(times[name])
            rows.append((tau, rtol, name, errors[name], *steps[name], median, median / base))
    return rows


def call_overhead(calls):
    """simulate(), its own compiled run and a bound Simulator on a 15-step problem (t_final = 1e-4 s).

    Median time of ``calls`` single calls each (every call waits for its result), the variants
    round robin. A fourth, for reference: simulate's program as an ahead-of-time executable
    called with its packed arguments already on the device (what a bound call runs; it shares
    the compilation).
    """
    simulate_module = importlib.import_module("peeljax.simulate")
    model = pj.PeelingModel()
    ts = np.linspace(0.0, 1e-4, 2)
    ode = HomogenizedODE(model, V, 0.1)
    integrator = integrator_for(t_final=1e-4)  # simulate's: error control at the default tolerances
    args = jax.device_put((integrator, ode, None, np.asarray(1e-4), ts))
    compiled = jax.jit(simulate_module._integrate)
    leaves, treedef = jax.tree_util.tree_flatten((integrator, ode, None, np.asarray(1e-4), ts))
    scalars = tuple(isinstance(leaf, np.ndarray) and leaf.shape == () for leaf in leaves)  # simulate._run's split
    packed = jax.device_put(np.array([leaf for leaf, s in zip(leaves, scalars) if s], dtype=float))
    rest = jax.device_put([leaf for leaf, s in zip(leaves, scalars) if not s])
    runs = {"simulate": lambda: pj.simulate(model, V=V, tau=0.1, t_final=1e-4, ts=ts).ys}
    jax.block_until_ready(runs["simulate"]())  # compiles simulate's program, which the last two share
    executable = simulate_module._packed_jit.lower(packed, rest, treedef=treedef, scalars=scalars).compile()
    bound = pj.Simulator(model, t_final=1e-4, ts=ts).compile()
    runs |= {
        "compiled": lambda: compiled(*args).ys,
        "bound": lambda: bound(V, 0.1).ys,
        "executable": lambda: executable(packed, rest).ys,
    }
    first = {name: np.asarray(jax.block_until_ready(fn())) for name, fn in runs.items()}
    assert all(np.array_equal(ys, first["simulate"]) for ys in first.values()), "the runs differ"
    times = {name: [] for name in runs}
    for _ in range(calls):
        for name, fn in runs.items():
            start = time.perf_counter()
            jax.block_until_ready(fn())
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(t) for name, t in times.items()}


def overhead_lines(overhead, calls):
    simulate, compiled, bound, executable = (
        overhead[name] * 1e3 for name in ("simulate", "compiled", "bound", "executable")
    )
    return [
        f"Fixed cost of a call (15 accepted steps, t_final = 1e-4 s; medians of {calls} calls each, round robin):",
        "",
        "| call | median time | minus the compiled run |",
        "|---|---:|---:|",
        f"| `peeljax.simulate(model, V=1.1, tau=0.1, t_final=1e-4, ts=ts)` | {simulate:.3f} ms | {simulate - compiled:+.3f} ms |",
        f"| its compiled run, `jax.jit` with device-resident arguments | {compiled:.3f} ms | 0 |",
        (
            f"| bound `sim = peeljax.Simulator(model, t_final=1e-4, ts=ts)`, `sim(1.1, 0.1)` | {bound:.3f} ms "
            f"| {bound - compiled:+.3f} ms |"
        ),
        (
            f"| (reference) simulate's program, ahead-of-time executable, packed arguments on the device | "
            f"{executable:.3f} ms | {executable - compiled:+.3f} ms |"
        ),
        "",
        (
            f"`simulate` spends {simulate - compiled:.3f} ms on input checks, module building, host-to-device "
            f"copies and dispatch; the bound simulator {bound - compiled:+.3f} ms (target: at most +0.05 ms), "
            f"{bound - executable:+.3f} ms beyond the bare executable it runs (the `jax.jit` call of the "
            "compiled run flattens the equinox modules on every call)."
        ),
        "",
    ]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="two tolerances, three repeats")
    parser.add_argument(
        "--overhead-only", action="store_true", help=f"only the fixed cost of a call (writes {OVERHEAD_RESULTS.name})"
    )
    args = parser.parse_args(argv)
    calls = 1000
    if args.overhead_only:
        overhead = call_overhead(calls)
        text = "\n".join(
            [
                "# The fixed cost of a call: simulate, its compiled run, a bound Simulator",
                "",
                f"On {cpu_model()}, {jax.devices()[0].platform}.",
                "",
                *overhead_lines(overhead, calls),
            ]
        )
        print(text)
        write_result(OVERHEAD_RESULTS, text)
        return
    rtols = (1e-4, 1e-6) if args.quick else (1e-3, 1e-4, 1e-5, 1e-6, 1e-7)
    repeats = 3 if args.quick else 9
    rows = compare(0.01, rtols, repeats) + compare(0.1, rtols, repeats)
    overhead = call_overhead(calls)
    lines = [
        "# Error control: peeljax's driver against the α-method inside diffrax",
        "",
        f"On {cpu_model()}, "
        f"{jax.devices()[0].platform}. V = 1.1 m/s, t ∈ [0, 3 s], 301 output times, error = max |Δv| "
        "against diffrax Kvaerno5 at rtol 1e-11; atol = 1e-3·rtol; medians of "
        f"{repeats} round-robin repeats; ratio = time / `peeljax.simulate`'s.",
        "",
        "| τ | rtol | method | error in v | accepted | rejected | median time | ratio |",
        "|---:|---:|---|---:|---:|---:|---:|---:|",
    ]
    for tau, rtol, name, error, accepted, rejected, median, ratio in rows:
        lines.append(
            f"| {tau:g} | {rtol:g} | {name} | {error:.2e} | {accepted} | {rejected} | {median * 1e3:.2f} ms | {ratio:.2f} |"
        )
    lines += ["", *overhead_lines(overhead, calls)]
    text = "\n".join(lines)
    print(text)
    write_result(RESULTS, text)


if __name__ == "__main__":
    main()
