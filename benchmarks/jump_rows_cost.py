"""The cost of keeping both sides of every jump in a run's rows (``ErrorControl(save_jumps=...)``).

V = 1.1 m/s, τ = 0 (the DAE with jumps, 66 in 1 s), ``simulate``'s integrator, the same compiled
run with ``save_jumps`` True and False, round-robin in one process (medians of ``--repeats``
calls after compiling), on the accepted steps and with dense output at 1001 times. Then
τ = 0.01 (P1 of compare.py: 3 s, 301 output times, no fold reached), ``simulate`` with the
default ``fold="jump"`` (room for ``max_jumps`` jumps in its rows) against ``fold="stop"``
(none), the α-method and Tsit5, each run compiled once (``jax.jit(...).lower().compile()``,
the whole Solution returned) and the same runs through ``simulate`` itself.

    python benchmarks/jump_rows_cost.py [--repeats 5] [--max-jumps 10000]

Measured: ``benchmarks/results/jump_rows_cost.md`` (before and after the change below). Writing
the state before and the one after a jump with two updates of each output array per step made
XLA copy the arrays at every step (1105 ms against 84 ms); the output times' inner loop and the
jump's pair writing the same rows did the same (P1 with Tsit5 6.56 ms against 0.82 without jump
rows): the pairs are now rows of their own, merged in time order after the loop (1.90 ms).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time

import jax
import numpy as np

from peeljax._arrays import float_array
from peeljax.integrators.select import integrator_for, resolve_max_steps
from peeljax.simulate import _prepare, _run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--max-jumps", dest="max_jumps", type=int, default=10_000)
    args = parser.parse_args()
    print(f"load before: {os.getloadavg()}")
    ode, y0 = _prepare(None, 1.1, 0.0, None, None, allow_dae=True)
    t_final = float_array(1.0)
    for label, ts in (("accepted steps", None), ("dense output, 1001 times", np.linspace(0.0, 1.0, 1001))):
        base = integrator_for(None, t_final=1.0, fold="jump", max_jumps=args.max_jumps, dae=True,
                              max_steps=resolve_max_steps(None, keeps_steps=ts is None))  # fmt: skip
        variants = {flag: dataclasses.replace(base, save_jumps=flag) for flag in (True, False)}
        for integrator in variants.values():  # compile
            jax.block_until_ready(_run(integrator, ode, y0, t_final, ts))
        times = {flag: [] for flag in variants}
        for _ in range(args.repeats):
            for flag, integrator in variants.items():
                start = time.perf_counter()
                jax.block_until_ready(_run(integrator, ode, y0, t_final, ts))
                times[flag].append(time.perf_counter() - start)
        with_rows, without = (statistics.median(times[flag]) for flag in (True, False))
        print(f"{label}: with the jump rows {with_rows * 1e3:.1f} ms, without {without * 1e3:.1f} ms, "
              f"ratio {with_rows / without:.3f}")  # fmt: skip
    tau_rows(args.repeats, args.max_jumps)
    print(f"load after: {os.getloadavg()}")


def tau_rows(repeats: int, max_jumps: int) -> None:
    """τ = 0.01 (P1): fold="jump" with room for ``max_jumps`` jumps against fold="stop"."""
    import peeljax as pj

    grid = np.linspace(0.0, 3.0, 301)
    cases = {
        (solver, fold): dict(fold=fold, **({} if fold == "stop" else {"max_jumps": max_jumps}), **({"solver": solver} if solver else {}))
        for solver in (None, "tsit5")
        for fold in ("jump", "stop")
    }  # fmt: skip
    compiled = {key: jax.jit(lambda kw=kw: pj.simulate(V=1.1, tau=0.01, t_final=3.0, ts=grid, **kw)).lower().compile()
                for key, kw in cases.items()}  # fmt: skip
    calls = {("compiled", key): compiled[key] for key in cases}
    calls.update({("simulate", key): (lambda kw=kw: pj.simulate(V=1.1, tau=0.01, t_final=3.0, ts=grid, **kw).ys)
                  for key, kw in cases.items()})  # fmt: skip
    times = {key: [] for key in calls}
    for call in calls.values():
        jax.block_until_ready(call())
    for _ in range(repeats):
        for key, call in calls.items():
            start = time.perf_counter()
            jax.block_until_ready(call())
            times[key].append(time.perf_counter() - start)
    print(f"\nτ = 0.01, V = 1.1, 3 s, 301 output times (P1), medians of {repeats} (ms):")
    print('| stepper | how | fold="jump" (max_jumps %d) | fold="stop" | ratio |' % max_jumps)
    print("|---|---|---:|---:|---:|")
    for solver in (None, "tsit5"):
        for how in ("compiled", "simulate"):
            jump, stop = (statistics.median(times[(how, (solver, fold))]) for fold in ("jump", "stop"))
            print(f"| {solver or 'α-method'} | {how} | {jump * 1e3:.2f} | {stop * 1e3:.2f} | {jump / stop:.2f} |")


if __name__ == "__main__":
    main()
