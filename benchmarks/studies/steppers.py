"""Which stepper the one error-controlled loop should run by default: every stepper at equal accuracy.

    python benchmarks/studies/steppers.py            # ~6 min on 2 cores; writes results/steppers.md
    python benchmarks/studies/steppers.py --quick    # P6 to 1e-5 s and P1 at τ = 0.01 only

* P6 (τ = 0, the DAE with jumps): V = 1.1, [0, 3] s, 210 jumps; error = the largest |Δt| over
  every jump against ``tests/jump_reference.py`` (scipy LSODA events with the arclength
  refinement, rtol 1e-12); per stepper, the loosest rtol of a half-decade ladder whose error
  is ≤ the target (1e-5 s, 1e-6 s), and its median time (``simulate`` with output at [0, 3]).
  Rows: the α-method and Tsit5 on the DAE in time (v solved from the constraint at every
  evaluation, :class:`peeljax.ConstrainedDAE`), and the Runge–Kutta steppers on the DAE in
  pseudo-time (:class:`peeljax.DesingularizedDAE`, the default formulation of a named
  Runge–Kutta solver), Tsit5 at several time scales ε.
* P1 (τ > 0, the homogenized ODE): V = 1.1, τ = 0.01 and 0.1, [0, 3] s, error = the largest
  relative error in v on 301 output times against Dopri8 at rtol 1e-11; the loosest rtol of
  a decade ladder with error ≤ 1e-3, and its median time.

Every run: atol = 1e-3·rtol, compilation apart (a first call), medians of ``--repeats`` calls.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1] / "tests"))  # jump_reference
sys.path.insert(0, str(HERE.parent))  # benchmarks/: machine
from machine import write_result  # noqa: E402

STEPPERS = ("alpha", "tsit5", "dopri5", "dopri8", "kvaerno5")
TIME_SCALES = (1e-3, 3e-3, 3e-2, 1e-1)  # ε of the pseudo-time, beside the default (DEFAULT_TIME_SCALE)


def p6_steppers():
    """(label, solver) of every P6 row: the formulations of the DAE and the steppers."""
    import diffrax

    from peeljax.desingularized import DEFAULT_TIME_SCALE
    from peeljax.integrators import RungeKutta

    rows = [("alpha (in time)", "alpha"), ("tsit5 in time", RungeKutta(diffrax.Tsit5(), ()))]
    # a named explicit Runge–Kutta solver runs the DAE in pseudo-time, an implicit one (Kvaerno) in time
    rows += [
        (f"{name} (in time: implicit)" if name.startswith("kvaerno") else f"{name} (pseudo-time, ε = {DEFAULT_TIME_SCALE:g} s)", name)
        for name in STEPPERS[1:]
    ]
    rows += [
        (f"tsit5 (pseudo-time, ε = {eps:g} s)", RungeKutta(diffrax.Tsit5(), (3,), time_scale=eps)) for eps in TIME_SCALES
    ]
    return rows
P6_LADDER = tuple(m * 10.0**-e for e in range(4, 11) for m in (1.0, 0.3))[:-1]
P1_LADDER = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7)


def timed(call, repeats):
    out = call()  # compile (and the result, when repeats is 0)
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        out = call()
        times.append(time.perf_counter() - started)
    return out, float(np.median(times)) if times else float("nan")


def p6(repeats, targets):
    import jump_reference

    import peeljax as pj

    reference = jump_reference.reference_jump_run(1.1, 3.0, rtol=1e-12, atol=1e-14, method="LSODA")["jump_t"]
    rows = []
    for name, solver in p6_steppers():
        remaining = sorted(targets, reverse=True)
        for rtol in P6_LADDER:
            if not remaining:
                break

            def call(rtol=rtol, solver=solver):
                sol = pj.simulate(
                    V=1.1, tau=0, t_final=3.0, rtol=rtol, atol=1e-3 * rtol, ts=np.array([0.0, 3.0]), solver=solver
                )
                sol.ys.block_until_ready()
                return sol

            sol, seconds = timed(call, 1)
            jumps = sol.jumps.as_numpy()["jump_t"]
            error = float(np.max(np.abs(jumps - reference))) if jumps.size == reference.size else np.inf
            while remaining and error <= remaining[0]:
                _, seconds = timed(call, repeats)
                rows.append({
                    "stepper": name, "target": remaining.pop(0), "rtol": rtol, "error": error, "seconds": seconds,
                    "accepted": int(sol.stats["accepted_steps"]), "rejected": int(sol.stats["rejected_steps"]),
                })  # fmt: skip
            if seconds > 20:
                break
        for target in remaining:
            rows.append({"stepper": name, "target": target, "rtol": None})
        print(f"  P6 {name} done", file=sys.stderr, flush=True)
    return rows


def p1(repeats, taus):
    import peeljax as pj

    ts = np.linspace(0.0, 3.0, 301)
    rows = []
    for tau in taus:
        ref = pj.simulate(V=1.1, tau=tau, t_final=3.0, rtol=1e-11, atol=1e-14, ts=ts, solver="dopri8")
        v_ref = np.asarray(ref.v)
        for name in STEPPERS:
            row = {"stepper": name, "tau": tau, "rtol": None}
            for rtol in P1_LADDER:

                def call(rtol=rtol, name=name):
                    sol = pj.simulate(V=1.1, tau=tau, t_final=3.0, rtol=rtol, atol=1e-3 * rtol, ts=ts, solver=name)
                    sol.ys.block_until_ready()
                    return sol

                sol, _ = timed(call, 0)
                if sol.status_name != "completed":
                    continue
                error = float(np.max(np.abs(np.asarray(sol.v) - v_ref) / np.abs(v_ref)))
                if error <= 1e-3:
                    _, seconds = timed(call, repeats)
                    row = {
                        "stepper": name, "tau": tau, "rtol": rtol, "error": error, "seconds": seconds,
                        "accepted": int(sol.stats["accepted_steps"]), "rejected": int(sol.stats["rejected_steps"]),
                    }  # fmt: skip
                    break
            rows.append(row)
        print(f"  P1 tau={tau} done", file=sys.stderr, flush=True)
    return rows


def report(p6_rows, p1_rows, seconds):
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        "# Choosing the stepper: every stepper of the one loop at equal accuracy",
        "",
        f"{seconds:.0f} s, {os.cpu_count()} cores, load {load:.1f} at the end. "
        "atol = 1e-3·rtol; compile apart; medians.",
        "",
        "## P6: the DAE (τ = 0) with jumps, V = 1.1, [0, 3] s, every one of the 210 jump times",
        "",
        "| stepper | target (s) | rtol | error (s) | median (s) | / fastest | accepted + rejected steps |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for target in sorted({r["target"] for r in p6_rows}, reverse=True):
        rows = [r for r in p6_rows if r["target"] == target]
        fastest = min((r["seconds"] for r in rows if r["rtol"] is not None), default=np.nan)
        for r in rows:
            if r["rtol"] is None:
                lines.append(f"| {r['stepper']} | {target:g} | not reached on the ladder | | | | |")
            else:
                lines.append(
                    f"| {r['stepper']} | {target:g} | {r['rtol']:.0e} | {r['error']:.2g} | {r['seconds']:.3g} | "
                    f"{r['seconds'] / fastest:.1f}× | {r['accepted']} + {r['rejected']} |"
                )
    lines += [
        "",
        "## P1: the homogenized ODE (τ > 0), V = 1.1, [0, 3] s, relative error in v ≤ 1e-3 on 301 times",
        "",
        "| stepper | τ (s) | rtol | error | median (ms) | / fastest | accepted + rejected steps |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for tau in sorted({r["tau"] for r in p1_rows}):
        rows = [r for r in p1_rows if r["tau"] == tau]
        fastest = min((r["seconds"] for r in rows if r["rtol"] is not None), default=np.nan)
        for r in rows:
            if r["rtol"] is None:
                lines.append(f"| {r['stepper']} | {tau:g} | not reached on the ladder | | | | |")
            else:
                lines.append(
                    f"| {r['stepper']} | {tau:g} | {r['rtol']:.0e} | {r['error']:.2g} | {1e3 * r['seconds']:.3g} | "
                    f"{r['seconds'] / fastest:.1f}× | {r['accepted']} + {r['rejected']} |"
                )
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="P6 to 1e-5 s, P1 at tau = 0.01 only")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default=str(HERE / "results" / "steppers.md"))
    args = parser.parse_args(argv)
    started = time.perf_counter()
    p6_rows = p6(args.repeats, (1e-5,) if args.quick else (1e-5, 1e-6))
    p1_rows = p1(args.repeats, (0.01,) if args.quick else (0.01, 0.1))
    text = report(p6_rows, p1_rows, time.perf_counter() - started)
    write_result(args.out, text)
    print(text)


if __name__ == "__main__":
    main()
