"""The α-method's error estimate on the non-stiff test set of Hull, Enright, Fellen and Sedgwick (1972).

Every problem A1–E5 (``tests/detest_problems.py``) on t ∈ [0, 20], solved as diffrax's own
``test_detest.py`` solves it: ``diffrax.diffeqsolve(..., dt0=None,
stepsize_controller=PIDController(rtol=1e-6, atol=1e-6), max_steps=16**4)``, the end point
compared with a tight reference (diffrax Dopri8 at rtol = atol = 1e-13). diffrax's bound for
second-order solvers is |y(20) − y_ref| ≤ 1e-3 + 1e-3·|y_ref| in every component; the table gives
max over components of |Δy|/(1e-3 + 1e-3·|y_ref|) ("bound ratio": ≤ 1 is within it) and the step
attempts (accepted + rejected).

Solvers: ``peeljax.AlphaSolver`` at ρ = 0 and 0.5 with ``error_estimate="embedded"`` (the default:
y_{n+1} − (y_n + h·f_n), error order 2) and ``"local"`` (C·h²·(a_{n+1} − a_n), error order 3,
the estimate of peeljax's own loop); diffrax's Heun (second order, first-order embedded estimate)
and Bosh3 (third order, second-order estimate) beside them.

Where the local estimate stands: along each ``"local"`` run, every accepted step is replayed
from the run's own (y_n, f_n, a_n) and its true local error is taken against Dopri8 (rtol 1e-13)
from y_n over the same step; columns: the median and max over the accepted steps of
true/estimate (both in the controller's weighted RMS norm), and the max of the true local error
in that norm (≤ 1 would be "every step within the tolerance").

    python benchmarks/studies/detest.py               # every problem: ~10 min on 2 shared cores
    python benchmarks/studies/detest.py a5 b4 d5      # some problems

Writes ``benchmarks/studies/results/detest.md`` (all problems only). Nothing is timed.
"""

from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # benchmarks/: machine
sys.path.insert(0, str(HERE.parents[1] / "tests"))  # the problem set
from machine import write_result  # noqa: E402

RTOL = ATOL = 1e-6
BOUND = 1e-3  # diffrax's test_detest.py: rtol = atol = 1e-3 on the end point for order < 4
REF_TOL = 1e-13
RHOS = (0.0, 0.5)


def main(names):
    import diffrax
    import jax
    import jax.numpy as jnp
    import numpy as np

    import peeljax as pj
    from detest_problems import PROBLEMS, T_FINAL

    controller = diffrax.PIDController(rtol=RTOL, atol=ATOL)

    def solve(term, solver, y0, saveat=None):
        return diffrax.diffeqsolve(
            term, solver, 0.0, T_FINAL, None, y0, stepsize_controller=controller, max_steps=16**4, throw=False,
            **({} if saveat is None else {"saveat": saveat}),
        )  # fmt: skip

    def exact(term, t0, t1, y):
        sol = diffrax.diffeqsolve(
            term, diffrax.Dopri8(), t0, t1, (t1 - t0) / 4, y, max_steps=100_000,
            stepsize_controller=diffrax.PIDController(rtol=REF_TOL, atol=REF_TOL),
        )  # fmt: skip
        return sol.ys[-1]

    def local_honesty(term, solver, y0):
        """(median, max) of true/estimate over the accepted steps and the max true local error (weighted RMS)."""
        sol = solve(term, solver, y0, diffrax.SaveAt(steps=True))
        n = int(sol.stats["num_accepted_steps"])
        ts = jnp.concatenate([jnp.zeros(1), sol.ts[:n]])

        def body(carry, t01):
            y, state = carry
            y1, estimate, _, state, _ = solver.step(term, t01[0], t01[1], y, None, state, False)
            return (y1, state), (y, y1, estimate)

        state0 = solver.init(term, 0.0, ts[1], y0, None)
        _, (yn, y1, estimate) = jax.lax.scan(body, (y0, state0), jnp.stack([ts[:-1], ts[1:]], 1))
        true = y1 - jax.vmap(lambda a, b, y: exact(term, a, b, y))(ts[:-1], ts[1:], yn)
        scale = ATOL + RTOL * jnp.maximum(jnp.abs(yn), jnp.abs(y1))
        norm = lambda e: jnp.sqrt(jnp.mean((e / scale) ** 2, axis=1))  # noqa: E731
        ratio = np.asarray(norm(true) / norm(estimate))
        return float(np.median(ratio)), float(ratio.max()), float(jnp.max(norm(true)))

    solvers = {}
    for estimate in ("embedded", "local"):
        for rho in RHOS:  # ρ traced: one compilation serves both
            solvers[f"α ρ={rho:g} {estimate}"] = pj.AlphaSolver(rho=jnp.asarray(rho), error_estimate=estimate)
    solvers["Heun"] = diffrax.Heun()
    solvers["Bosh3"] = diffrax.Bosh3()

    rows, honesty = [], []
    started = time.perf_counter()
    for name in names:
        f, y0 = PROBLEMS[name]()
        term = diffrax.ODETerm(f)
        y_ref = np.asarray(exact(term, 0.0, T_FINAL, y0))
        row = {"problem": name.upper()}
        for label, solver in solvers.items():
            sol = solve(term, solver, y0)
            y = np.asarray(sol.ys[-1])
            ok = diffrax.is_successful(sol.result)
            error = np.abs(y - y_ref)
            row[label] = (float(np.max(error / (BOUND + BOUND * np.abs(y_ref)))), float(np.max(error)),
                          int(sol.stats["num_steps"]), bool(ok))  # fmt: skip
        rows.append(row)
        for rho in RHOS:
            honesty.append((name.upper(), rho, *local_honesty(term, solvers[f"α ρ={rho:g} local"], y0)))
        print(f"  [{name}: {time.perf_counter() - started:.0f} s]", file=sys.stderr, flush=True)
    return solvers, rows, honesty, time.perf_counter() - started


def report(solvers, rows, honesty, elapsed):
    import diffrax
    import jax
    import numpy as np

    lines = [
        "# The α-method's error estimate on the non-stiff test set (Hull, Enright, Fellen, Sedgwick 1972)",
        "",
        f"`python benchmarks/studies/detest.py` ({elapsed:.0f} s; {platform.machine()}, {os.cpu_count()} cores, "
        f"load {os.getloadavg()[0]:.1f} at the end; jax {jax.__version__}, diffrax {diffrax.__version__}).",
        "",
        f"Every problem on [0, 20] at rtol = atol = {RTOL:g}, dt0 = None, as diffrax's `test_detest.py`; end point "
        f"against diffrax Dopri8 at rtol = atol = {REF_TOL:g}. Cell: bound ratio max|Δy|/({BOUND:g} + {BOUND:g}·|y_ref|) "
        "(≤ 1: within diffrax's bound for second-order solvers) / step attempts; **bold**: outside the bound.",
        "",
        "| problem | " + " | ".join(solvers) + " |",
        "|---|" + "---:|" * len(solvers),
    ]
    worst = {label: 0.0 for label in solvers}
    for row in rows:
        cells = []
        for label in solvers:
            ratio, _, steps, ok = row[label]
            worst[label] = max(worst[label], ratio if ok else np.inf)
            text = f"{ratio:.3g} / {steps}" + ("" if ok else " (stopped)")
            cells.append(f"**{text}**" if ratio > 1 or not ok else text)
        lines.append(f"| {row['problem']} | " + " | ".join(cells) + " |")
    lines.append("| worst | " + " | ".join(f"{worst[label]:.3g}" for label in solvers) + " |")
    lines += [
        "",
        "## The local estimate C·h²·(a_{n+1} − a_n), step by step",
        "",
        'Along each `error_estimate="local"` run: every accepted step replayed from the run\'s own (y_n, f_n, a_n), '
        f"its true local error against Dopri8 (rtol {REF_TOL:g}) from y_n; both in the controller's weighted RMS norm.",
        "",
        "| problem | ρ | true/estimate, median | max | true local error (norm), max |",
        "|---|---:|---:|---:|---:|",
    ]
    lines += [f"| {p} | {rho:g} | {med:.3f} | {mx:.3g} | {true:.3g} |" for p, rho, med, mx, true in honesty]
    lines += [
        "",
        "Reading: the local estimate is honest step by step (true/estimate ≈ 1; its largest values are isolated "
        "steps where y‴ passes through zero, the first step — a_0 exact: 1.5 — and the true local error of every "
        "accepted step stays near the tolerance), yet the end points miss the bound by up to the factor in the "
        "table: controlling the local error per step, a second-order method's global error grows like "
        "tol^(2/3) times what the dynamics make of the accumulated local errors (the Kepler orbits D1–D5 turn "
        "them into a growing phase error). diffrax's second-order solvers meet the bound because their "
        "first-order embedded estimate overestimates their local error by a factor ∝ 1/h, which makes the "
        'global error proportional to the tolerance; `AlphaSolver`\'s default `"embedded"` estimate does the '
        "same.",
    ]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    from detest_problems import PROBLEMS  # noqa: E402

    names = [a.lower() for a in sys.argv[1:]] or list(PROBLEMS)
    unknown = [n for n in names if n not in PROBLEMS]
    if unknown:
        sys.exit(f"unknown problems {unknown}; choose from {list(PROBLEMS)}")
    text = report(*main(names))
    print(text)
    if len(names) == len(PROBLEMS):
        print(write_result(HERE / "results" / "detest.md", text))
