"""The cost of a gradient through the jumps against the forward run (issue 20: at most 5×).

V = 1.1 m/s, τ = 0 (the DAE with jumps; ``--tau 1e-3``: the homogenized ODE with its fold jumps,
issue 42: at most 5× too), the paper's start, 3 s (≈ 210 jumps), error control.
The gradient is d/dc1 of (the sum of the jump times + the mean of F at the slips): reverse mode
as ``jax.grad`` gets it by default (``adjoint="reverse"``: one perturbed number, so by a
tangent of the plain loop, ``peeljax/integrators/adjoint.py``), reverse mode through the
checkpointed loop (``adjoint="checkpointed"``, what ``jax.grad`` takes for many parameters) and
forward mode (``jax.jvp``, one tangent). ``--tangents 1,4,8`` adds k tangents at once
(``jax.vmap`` of ``jax.jvp``): the cost of a gradient with respect to k numbers by tangents,
against which the limits in ``adjoint.TANGENT_LIMITS`` were set. Compile time is measured
separately (the first call); medians of ``--repeats`` calls after it, the calls round-robin.

    python benchmarks/jump_gradient_cost.py [--rtol 1e-6] [--repeats 15] [--tau 0] [--tangents 1,4,8]   # writes results/jump_gradient_cost[_tau=…].md

The run is ``simulate``'s default at τ (at τ = 0 Tsit5 on the DAE in pseudo-time; at τ > 0 the α-method).
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import statistics
import sys
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import peeljax as pj

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import load_average, round_robin, write_result  # noqa: E402


def objective(c1, *, rtol, adjoint, tau=0.0, t_final=3.0):
    law = eqx.tree_at(lambda a: a.c1, pj.AdhesionLaw(), c1)
    sol = pj.simulate(
        pj.PeelingModel(adhesion=law), V=1.1, tau=tau, t_final=t_final, rtol=rtol, atol=rtol * 1e-3,
        ts=np.array([0.0, t_final]), adjoint=adjoint, max_jumps=1024, max_steps=1_000_000,
    )  # fmt: skip
    jumps = sol.jumps
    slot = jnp.arange(jumps.max_jumps)
    valid = slot < jumps.count
    up = valid & jumps.up
    return jnp.sum(jnp.where(valid, jumps.t, 0.0)) + jnp.sum(jnp.where(up, jumps.F, 0.0)) / jnp.sum(up), jumps.count


def timed_round_robin(calls, repeats):
    """(first call, median of ``repeats`` later calls) per call, the later calls taken in turn."""
    calls = {name: lambda fn=fn: jax.block_until_ready(fn()) for name, fn in calls.items()}
    first = round_robin(calls, 1)
    times = round_robin(calls, repeats)
    return [(name, first[name][0], statistics.median(times[name])) for name in calls]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rtol", type=float, default=1e-6)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--tau", type=float, default=0.0)
    parser.add_argument("--tangents", default="", help="comma-separated k: also time k tangents at once")
    args = parser.parse_args(argv)
    c1 = jnp.asarray(400.0)

    def value(adjoint):
        return lambda c: objective(c, rtol=args.rtol, adjoint=adjoint, tau=args.tau)[0]

    def tangents(k):
        def derivatives(c):
            return jax.vmap(lambda t: jax.jvp(value("forward"), (c,), (t,))[1])(jnp.ones(k))

        return jax.jit(derivatives)

    forward = jax.jit(lambda c: objective(c, rtol=args.rtol, adjoint="forward", tau=args.tau))
    programs = {
        "forward run (plain loop)": forward,
        "forward run (checkpointed loop)": jax.jit(value("checkpointed")),
        "gradient, reverse mode (default)": jax.jit(jax.grad(value("reverse"))),
        "gradient, checkpointed loop": jax.jit(jax.grad(value("checkpointed"))),
        "derivative, forward mode (jvp)": jax.jit(lambda c: jax.jvp(value("forward"), (c,), (1.0,))),
        **{f"{k} tangents at once": tangents(int(k)) for k in filter(None, args.tangents.split(","))},
    }
    rows = timed_round_robin({name: functools.partial(program, c1) for name, program in programs.items()}, args.repeats)
    jumps = int(forward(c1)[1])
    base = rows[0][2]
    table = [
        f"V = 1.1, tau = {args.tau:g}, 3 s, {jumps} jumps, rtol {args.rtol:g}; medians of {args.repeats} after the first call",
        f"{'':34} {'first call [s]':>15} {'median [s]':>11} {'/ forward':>10}",
        *(f"{name:34} {first:>15.2f} {median:>11.4f} {median / base:>10.2f}" for name, first, median in rows),
    ]
    print("\n".join(table))
    load = load_average()
    text = "\n".join([
        "# Gradient cost through jumps (issues 27 and 42: target <= 5x the forward run; compile <= 5 s forward, <= 20 s gradient)",
        "",
        f"{os.cpu_count()} cores, {platform.machine()}, jax {jax.__version__}, load {load:.1f} "
        "at the end. 'first call' includes the compilation in this process.",
        "",
        "```",
        *table,
        "```",
        "",
    ])
    name = "jump_gradient_cost.md" if args.tau == 0 else f"jump_gradient_cost_tau={args.tau:g}.md"
    write_result(Path(__file__).resolve().parent / "results" / name, text)


if __name__ == "__main__":
    main()
