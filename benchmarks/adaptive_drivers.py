"""The error-controlled α-method: peeljax's own driver against the α-method inside diffrax.

Problem: V = 1.1 m/s, τ = 0.01 and 0.1 s, t ∈ [0, 3 s], output on the 301-point grid, error =
max |Δv| there against diffrax Kvaerno5 at rtol 1e-11. For each rtol (atol = 1e-3·rtol):

* ``peeljax.simulate(..., rtol=…, ts=grid)``: input checks, dispatch and the compiled run;
* the same compiled run called directly (``jax.jit`` of ``integrate_alpha_adaptive``);
* ``diffrax.diffeqsolve`` with ``peeljax.AlphaSolver()`` and ``diffrax.PIDController`` on
  (α, ω, u, log v) (``peeljax.LogTransformedODE``), saving at the grid;

and the fixed cost of a call: ``simulate`` against its compiled run on a 15-step problem.
Medians of round-robin repeats; ratios are to ``peeljax.simulate`` in the same run.

    python benchmarks/adaptive_drivers.py [--quick]     # writes benchmarks/results/adaptive_drivers.md
"""

from __future__ import annotations

import argparse
import importlib
import statistics
import time
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from machine import cpu_model

import peeljax as pj
from peeljax.homogenized import HomogenizedODE
from peeljax.integrators import integrate_alpha_adaptive, integrator_for

RESULTS = Path(__file__).resolve().parent / "results" / "adaptive_drivers.md"
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


def call_overhead(repeats):
    """simulate() against its own compiled run, on a 15-step problem (t_final = 1e-4 s)."""
    simulate_module = importlib.import_module("peeljax.simulate")
    model = pj.PeelingModel()
    ts = np.linspace(0.0, 1e-4, 2)
    ode = HomogenizedODE(model, V, 0.1)
    integrator = integrator_for(t_final=1e-4)  # simulate's: error control at the default tolerances
    args = jax.device_put((integrator, ode, None, np.asarray(1e-4), ts))
    compiled = jax.jit(simulate_module._integrate)
    runs = {
        "simulate": lambda: pj.simulate(model, V=V, tau=0.1, t_final=1e-4, ts=ts).ys,
        "compiled": lambda: compiled(*args).ys,
    }
    for fn in runs.values():
        jax.block_until_ready(fn())
    times = {name: [] for name in runs}
    for _ in range(repeats):
        for name, fn in runs.items():
            start = time.perf_counter()
            for _ in range(50):
                jax.block_until_ready(fn())
            times[name].append((time.perf_counter() - start) / 50)
    return {name: statistics.median(t) for name, t in times.items()}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="two tolerances, three repeats")
    args = parser.parse_args()
    rtols = (1e-4, 1e-6) if args.quick else (1e-3, 1e-4, 1e-5, 1e-6, 1e-7)
    repeats = 3 if args.quick else 9
    rows = compare(0.01, rtols, repeats) + compare(0.1, rtols, repeats)
    overhead = call_overhead(repeats)
    lines = [
        "# Error control: peeljax's driver against the α-method inside diffrax",
        "",
        f"`python benchmarks/adaptive_drivers.py{' --quick' if args.quick else ''}` on {cpu_model()}, "
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
    lines += [
        "",
        "Fixed cost of a call (15 accepted steps, t_final = 1e-4 s): "
        f"`peeljax.simulate` {overhead['simulate'] * 1e3:.3f} ms, its compiled run with device-resident "
        f"arguments {overhead['compiled'] * 1e3:.3f} ms: {1e3 * (overhead['simulate'] - overhead['compiled']):.3f} ms "
        "of input checks, module building, host-to-device copies and dispatch.",
        "",
    ]
    text = "\n".join(lines)
    print(text)
    RESULTS.write_text(text)


if __name__ == "__main__":
    main()
