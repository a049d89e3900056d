"""τ > 0: the switching stepper (``solver="auto"``) against the α-method, Tsit5 and CasADi, at equal error.

P1 (one trajectory, τ = 0.01 and 0.1) and a 64-lane P3 slice (``compare_problems.py``), each
candidate and CasADi cvodes (log v) at the loosest rtol of ``LADDER`` that meets ``TARGET``, timed
in round-robin rounds (wall and CPU medians); then the step attempts of two long runs. P1 is
timed two ways: one call of each a round (the issue's protocol; a ~1 ms call, so many rounds),
and ``P1_CALLS`` calls of each in a row a round (what a loop of calls sees: in eight runs on
2026-12-06 CasADi's call was then 1.1–1.8× faster than with one call a round, peeljax's
0.95–1.3×).

    python benchmarks/switching.py                 # ~10 min on 2 shared cores
    python benchmarks/switching.py --only P1 long  # P1 and the long runs (~3 min)
    python benchmarks/switching.py --only P3 --lane-batch 32   # P3's lanes under vmap, 32 at once

Writes ``benchmarks/results/switching.md``. Speed is reported, never asserted.
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # benchmarks/: machine, compare_problems, peers
from compare_problems import (  # noqa: E402
    GRID, P3_SAVE_DT, P3_VELOCITIES, REF_ATOL, REF_RTOL, T_FINAL, V, p3_grid, p3_subsample, reference,
    relative_errors
)  # fmt: skip
from machine import cpu_model, round_robin, versions, write_result  # noqa: E402
from machine import load_average as load  # noqa: E402

TARGET = 1e-3
N_TAU, PER_V = 16, 8  # the 64-lane slice, 32 checked lanes
P1_CALLS = 40  # P1's calls in a row in a round of the second timing
LADDER = tuple(float(f"{m}e{e}") for e in range(-2, -8, -1) for m in (5, 2, 1))

# name → (what the table says, simulate/sweep options; atol the default)
CANDIDATES = {
    "auto": ("switching Tsit5 ↔ α-method (solver='auto')", {"solver": "auto"}),
    "alpha": ("α-method ρ = 0 (solver='alpha', the default before)", {"solver": "alpha"}),
    "tsit5": ("Tsit5 (solver='tsit5')", {"solver": "tsit5"}),
    "auto_rho": ("switching, its α-method at ρ = 0.5", {"solver": "auto ρ = 0.5"}),
}


@functools.lru_cache(maxsize=None)
def _solver(name):
    """A candidate's solver: a name, or the switching stepper whose α-method has ρ = 0.5 (built
    once, outside the timed calls: a construction takes ~0.1 ms)."""
    if name != "auto ρ = 0.5":
        return name
    from peeljax.integrators import AlphaMethod, AlphaStepper, SwitchingStepper

    return SwitchingStepper(implicit=AlphaStepper(AlphaMethod(rho=0.5)))


TAUS_P1 = (0.01, 0.1)
LONG_RUNS = ((1.1, 0.01, 1e9), (4.0, 0.1, 1e5))


def options(key, rtol):
    kwargs = CANDIDATES[key][1]
    return dict(kwargs, rtol=rtol, solver=_solver(kwargs["solver"]))


def calibrate(run, error_of, attempts_of=None):
    """(rtol, error, result) at the loosest rung meeting TARGET, and every rung tried (rtol,
    error, attempts: None without ``attempts_of``)."""
    tried = []
    for rtol in LADDER:
        result = run(rtol)
        error = error_of(result)
        tried.append((rtol, error, None if attempts_of is None else attempts_of(result[1])))
        if error <= TARGET:
            return (rtol, error, result), tried
    return None, tried


def measure(problem, keys, run, error, attempts, casadi_run, casadi_call, timings):
    """Each candidate and CasADi calibrated on the ladder, then timed round-robin at the rtol
    found, once for each of ``timings`` ({label: (rounds, calls in a row a round)}): (chosen
    rows, ladders, {label: {key: (wall, CPU) a call in each round}}, load averages).
    ``run(key, rtol)`` → (v, result)."""
    chosen, ladders = {}, {}
    for key in keys:
        started = time.perf_counter()
        found, ladders[key] = calibrate(lambda r, key=key: run(key, r), error, attempts)
        if found is None:
            print(f"  [{problem} {key}: no rung met the target]", file=sys.stderr)
            continue
        rtol, err, (_, result) = found
        chosen[key] = {"rtol": rtol, "error": err, "attempts": ladders[key][-1][2], "first_s": time.perf_counter() - started}
        print(f"  [{problem} {key}: rtol {rtol:g}, error {err:.2g}, {chosen[key]['attempts']:.0f} attempts]", file=sys.stderr)
    found, ladders["casadi"] = calibrate(casadi_run, error)
    rtol_c, err_c, _ = found
    chosen["casadi"] = {"rtol": rtol_c, "error": err_c, "attempts": None}
    once = {key: (lambda key=key: run(key, chosen[key]["rtol"])) for key in chosen if key != "casadi"}
    once["casadi"] = lambda: casadi_call(rtol_c)
    loads, times = [load()], {}
    for label, (rounds, calls) in timings.items():
        rows = {key: (lambda f=f: [f() for _ in range(calls)]) for key, f in once.items()}
        cpu = {}
        each_round = (lambda _: loads.append(load())) if rounds <= 50 else None  # (else: at the end only)
        wall = round_robin(rows, rounds, each_round, rotate=True, cpu=cpu)
        times[label] = {key: (np.asarray(wall[key]) / calls, np.asarray(cpu[key]) / calls) for key in rows}
        loads.append(load())
    return chosen, ladders, times, loads


def p1(keys, repeats, tau):
    """P1 timed with one call of each a round (``repeats × P1_CALLS`` rounds) and with
    ``P1_CALLS`` calls of each in a row (``repeats`` rounds)."""
    import jax

    import peeljax as pj
    from peers.casadi_peer import CasadiPeer

    v_ref = reference(tau)

    def simulate(key, rtol):
        sol = pj.simulate(V=V, tau=tau, t_final=T_FINAL, ts=GRID, **options(key, rtol))
        return np.asarray(jax.block_until_ready(sol.ys))[:, 3], sol

    def error(result):
        v = result[0]
        return float(np.max(np.abs(v - v_ref))) if np.all(np.isfinite(v)) else np.inf

    casadi = CasadiPeer(tau, LADDER, log_v=True)
    casadi.prepare()

    def casadi_run(r):
        casadi.setup(r)
        return (casadi.run(r),)

    def attempts(sol):
        return int(sol.stats["accepted_steps"]) + int(sol.stats["rejected_steps"])

    timings = {
        f"one call a round ({repeats * P1_CALLS} rounds)": (repeats * P1_CALLS, 1),
        f"{P1_CALLS} calls in a row ({repeats} rounds)": (repeats, P1_CALLS),
    }
    return measure("P1", keys, simulate, error, attempts, casadi_run, casadi.run, timings)


def p3(keys, repeats, lane_batch=None):
    import jax

    import peeljax as pj
    from peers.casadi_peer import CasadiBatch
    from peers.diffrax_peer import diffrax_vmap

    Vs, taus = p3_grid(N_TAU)
    sub = p3_subsample(N_TAU, PER_V)
    v_ref, status = diffrax_vmap()(Vs[sub], taus[sub], REF_RTOL, REF_ATOL)
    assert np.all(status == 0), "the P3 reference stopped"
    devices = len(jax.devices())

    def sweep(key, rtol):
        result = pj.sweep(None, Vs, taus, None, T_FINAL, save_dt=P3_SAVE_DT, grid="pairs", progress=False, chunk=Vs.size,
                          lane_batch=lane_batch, **options(key, rtol))  # fmt: skip
        return np.asarray(result.ys)[:, :, 3], result

    def error(result):
        return float(np.max(relative_errors(result[0][sub], v_ref)))

    casadi = CasadiBatch()

    def casadi_all(rtol):
        return np.stack([casadi(float(Vp), float(tau), rtol) for Vp, tau in zip(Vs, taus)])

    def casadi_run(rtol):
        casadi.setup(rtol)
        return (casadi_all(rtol),)

    def attempts(result):
        return float(np.mean(np.asarray(result.accepted_steps) + np.asarray(result.rejected_steps)))

    return (*measure("P3", keys, sweep, error, attempts, casadi_run, casadi_all, {"": (repeats, 1)}), devices)


def long_runs(keys):
    """Step attempts (accepted + rejected) of each long run and candidate, and how it ended."""
    import peeljax as pj

    lines = ["### Long runs: step attempts (rtol 1e-6, the defaults)", "", "| V, τ, t_final | " + " | ".join(
        CANDIDATES[k][0] for k in keys) + " | auto ÷ α-method |", "|---|" + "---:|" * (len(keys) + 1)]  # fmt: skip
    for V_long, tau, t_final in LONG_RUNS:
        attempts = {}
        for key in keys:
            sol = pj.simulate(V=V_long, tau=tau, t_final=t_final, ts=np.linspace(0.0, t_final, 11), **options(key, 1e-6))
            attempts[key] = (int(sol.stats["accepted_steps"]) + int(sol.stats["rejected_steps"]), sol.status_name)
        cells = [f"{n} ({status})" if status != "completed" else f"{n}" for n, status in attempts.values()]
        ratio = f"{attempts['auto'][0] / attempts['alpha'][0]:.2f}" if {"auto", "alpha"} <= set(keys) else "–"
        lines.append(f"| {V_long}, {tau}, {t_final:g} s | " + " | ".join(cells) + f" | {ratio} |")
    return lines + [""]


def _rung(rtol, error, attempts):
    """A ladder's rung as the table lists it: rtol: error (attempts, where counted)."""
    return f"{rtol:g}: {error:.2g}" + ("" if attempts is None else f" ({attempts:.0f})")


def table(title, attempts_label, chosen, ladders, timings, loads, per_core_devices=None):
    """The rows of ``measure``'s results (per timing: the wall time a call, its ratio to CasADi's
    (the medians') and the quartiles of the rounds' own ratios; the CPU ratio of the first timing),
    then the load averages and the ladders tried."""
    cores = "" if per_core_devices is None else f" × {per_core_devices} devices"
    head = [f"| candidate | rtol | error | {attempts_label} |", "|---|---:|---:|---:|"]
    for label in timings:
        named = f", {label}" if label else ""
        head[0] += f" wall ms{named} | wall{cores} ÷ CasADi's | the rounds' quartiles |"
        head[1] += "---:|---:|---:|"
    head[0] += " CPU ÷ CasADi's |"
    head[1] += "---:|"
    lines = [f"### {title}", "", *head]
    for key, row in chosen.items():
        label = "CasADi cvodes (log v), atol = 1e-2·rtol" + (", looped on one core" if per_core_devices else "")
        name = label if key == "casadi" else CANDIDATES[key][0]
        k = 1 if key == "casadi" or per_core_devices is None else per_core_devices
        att = "–" if row["attempts"] is None else f"{row['attempts']:.0f}"
        cells = f"| {name} | {row['rtol']:g} | {row['error']:.2g} | {att} |"
        for times in timings.values():
            wall, base = times[key][0], times["casadi"][0]
            low, high = np.percentile(k * wall / base, [25, 75])  # the rounds' own ratios
            cells += f" {1e3 * np.median(wall):.2f} | {k * np.median(wall) / np.median(base):.2f} | {low:.2f}–{high:.2f} |"
        first = next(iter(timings.values()))
        lines.append(cells + f" {np.median(first[key][1]) / np.median(first['casadi'][1]):.2f} |")
    ladder_text = "; ".join(f"{k}: " + ", ".join(_rung(*t) for t in v) for k, v in ladders.items())
    return lines + ["", "Load averages during the timing: " + ", ".join(f"{x:.1f}" for x in loads), "",
                    "Ladders (rtol: error (attempts)): " + ladder_text, ""]  # fmt: skip


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", choices=("P1", "P3", "long"), default=("P1", "P3", "long"))
    parser.add_argument("--candidates", nargs="+", choices=tuple(CANDIDATES), default=tuple(CANDIDATES))
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--lane-batch", type=int, default=None, help="P3's lanes under vmap, this many at once (a "
                        "lane's lax.cond becomes a select: both steppers' steps); writes results/switching_lane_batch.md")
    args = parser.parse_args(argv)
    import peeljax  # noqa: F401 (first: its XLA flags apply only if it comes before JAX's backend starts)

    import jax

    started = time.perf_counter()
    start_load = load()
    lines = [
        "# τ > 0: the switching stepper at equal error, against CasADi",
        "",
        f"- machine: {cpu_model()}, {os.cpu_count()} cores shared with other jobs, {len(jax.devices())} JAX devices; "
        f"load average {start_load:.1f} at the start",
        f"- {versions('jax', 'peeljax')}",
        f"- error targets {TARGET:g}; ladder {', '.join(f'{r:g}' for r in LADDER)} (loosest rung meeting the target); "
        f"medians of {args.repeats} round-robin rounds after a first call (P1: also {args.repeats * P1_CALLS} rounds "
        "of one call each); a row's quartiles: of its ratios to CasADi in each round",
        "",
    ]
    for tau in TAUS_P1 if "P1" in args.only else ():
        title = f"P1: V = {V}, τ = {tau} s, max |v − v_ref| ≤ {TARGET:g}"
        lines += table(title, "attempts", *p1(args.candidates, args.repeats, tau))
    if "P3" in args.only:
        batch = "" if args.lane_batch is None else f", lane_batch = {args.lane_batch} (under vmap)"
        title = f"P3 slice: {N_TAU * len(P3_VELOCITIES)} lanes, relative error ≤ {TARGET:g} on {PER_V * len(P3_VELOCITIES)}{batch}"
        lines += table(title, "attempts per lane", *p3(args.candidates, args.repeats, args.lane_batch))
    if "long" in args.only:
        lines += long_runs(args.candidates)
    lines.append(f"Total {time.perf_counter() - started:.0f} s; load average {load():.1f} at the end.")
    text = "\n".join(lines) + "\n"
    print(text)
    every = set(args.candidates) == set(CANDIDATES)
    if set(args.only) == {"P1", "P3", "long"} and every and args.lane_batch is None:
        print(write_result(HERE / "results" / "switching.md", text))
    elif set(args.only) == {"P3"} and every and args.lane_batch is not None:
        print(write_result(HERE / "results" / "switching_lane_batch.md", text))


if __name__ == "__main__":
    main()
