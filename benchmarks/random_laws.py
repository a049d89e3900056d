"""Random adhesion laws at τ = 0: does every run complete, and do ``simulate`` and ``sweep`` agree?

N laws φ are drawn with each of the 14 coefficients the paper's times a factor uniform in
[0.9, 1.1] (seed 0), and each is run at 10 V evenly spaced in [0.3, 5.4] m/s, τ = 0, 3 s,
with the defaults: once by ``peeljax.sweep`` (all N·10 lanes, ``grid="pairs"``, the coefficients
as swept parameters) and once by ``peeljax.simulate`` per lane. Many of these laws have φ's
minimum below φ(0⁺, V) at low V: every re-stick there lands at v = 0 and the tape stays fully
stuck until G rises back to φ(0⁺, V) (before this was handled, 9 of 120 such runs stopped early).

Reported: how many runs complete in each, how many laws make the tape stop somewhere, and the
agreement of the two (jump counts, the time of the last jump, the final state). A law whose φ_min
is negative at a V asks the tape to push (G < 0) on its slip branch: the peel angle then runs to
−π/2, where 1 + sin α = 0 and G = 0 for any stretch, and the run stops there ("step size
collapsed"). Those runs are outside the model and counted apart. ``simulate`` runs with ``max_jumps=100_000``: near the cusp where φ's
folds merge, some laws jump thousands of times a second (a record of 10 000 given by hand stops a
run there and says so; the default grows with the run).

    python benchmarks/random_laws.py             # 200 laws × 10 V (~2 min on 2 cores)
    python benchmarks/random_laws.py --laws 20   # a check

Writes ``results/random_laws.md`` (``results/random_laws_quick.md`` with fewer than 200 laws).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np

import peeljax as pj
from peeljax.adhesion import COEFFICIENT_NAMES, PAPER_COEFFICIENTS

from machine import cpu_model, timed, write_result

V_VALUES = np.linspace(0.3, 5.4, 10)
T_FINAL = 3.0
MAX_JUMPS = 100_000  # near the cusp of φ's folds (V ≳ 2.5) some laws jump ~6000 times a second


def draw_laws(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """n laws, each coefficient the paper's times U(0.9, 1.1)."""
    rng = np.random.default_rng(seed)
    return {name: PAPER_COEFFICIENTS[name] * rng.uniform(0.9, 1.1, n) for name in COEFFICIENT_NAMES}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--laws", type=int, default=200)
    args = parser.parse_args(argv)
    laws = draw_laws(args.laws)
    n_v = V_VALUES.size
    lane_V = np.tile(V_VALUES, args.laws)
    lane_params = {name: np.repeat(values, n_v) for name, values in laws.items()}

    stops = 0  # laws whose φ_min lies below φ(0⁺, V) at some V of the ten
    pushes = np.zeros(lane_V.size, bool)  # lanes whose φ_min < 0: the tape would push
    folds = jax.jit(jax.vmap(lambda law, V: pj.phi_folds(pj.PeelingModel(adhesion=law), V)))
    for i in range(args.laws):
        law = pj.AdhesionLaw(**{name: laws[name][i] for name in COEFFICIENT_NAMES})
        f = folds(jax.tree_util.tree_map(lambda a: np.broadcast_to(a, (n_v,)), law), V_VALUES)
        stops += bool(np.any(np.asarray(f.phi_min) < np.asarray(f.phi_zero)))
        pushes[i * n_v : (i + 1) * n_v] = np.asarray(f.phi_min) < 0

    swept, sweep_s = timed(pj.sweep, V=lane_V, tau=[0.0], t_final=T_FINAL, grid="pairs", params=lane_params,
                           progress=True, max_jumps=64)  # fmt: skip

    ts = np.array([0.0, T_FINAL])
    completed, jump_count, last_jump, final = [], [], [], []
    start = time.perf_counter()
    for lane, V in enumerate(lane_V):
        law = pj.AdhesionLaw(**{name: lane_params[name][lane] for name in COEFFICIENT_NAMES})
        run = pj.simulate(pj.PeelingModel(adhesion=law), V=V, tau=0, t_final=T_FINAL, ts=ts, max_jumps=MAX_JUMPS)
        run = run.without_padding()
        completed.append(run.status_name == "completed")
        record = run.jumps.as_numpy()
        jump_count.append(record["jump_t"].size)
        last_jump.append(record["jump_t"][-1] if record["jump_t"].size else np.nan)
        final.append(np.asarray(run.ys[-1]))
    simulate_s = time.perf_counter() - start

    completed, jump_count, last_jump, final = map(np.asarray, (completed, jump_count, last_jump, final))
    sweep_count = np.asarray(swept.jumps["jump_count"])
    sweep_last = np.array(
        [row[min(count, row.size) - 1] if count else np.nan for row, count in zip(swept.jumps["jump_t"], sweep_count)]
    )
    same_count = sweep_count == jump_count
    both = same_count & (jump_count > 0)
    dt_last = np.abs(sweep_last[both] - last_jump[both])
    dv_final = np.abs(np.asarray(swept.v_final) - final[:, 3]) / np.maximum(np.abs(final[:, 3]), 1e-3)

    ok = ~pushes
    over_cap = int(np.sum(jump_count > 10_000))
    failed = [
        f"law {lane // n_v}, V = {lane_V[lane]:.2f}: sweep {'completed' if swept.completed[lane] else 'stopped'}, "
        f"simulate {'completed' if completed[lane] else 'stopped'}{' (φ_min < 0)' if pushes[lane] else ''}"
        for lane in np.flatnonzero(~completed | ~np.asarray(swept.completed))
    ]
    rows = [
        ("laws × V", f"{args.laws} × {n_v} = {lane_V.size} runs, τ = 0, {T_FINAL:g} s, default tolerances"),
        ("laws whose tape stops (φ_min < φ(0⁺, V) at some V)", f"{stops} of {args.laws}"),
        ("runs whose φ_min < 0 (the tape would push: outside the model)", f"{int(np.sum(pushes))} of {lane_V.size}"),
        ("`sweep`: runs completed, where φ_min ≥ 0", f"{int(np.sum(np.asarray(swept.completed)[ok]))} of {int(np.sum(ok))} ({sweep_s:.0f} s for all, compilation included)"),
        ("`simulate`: runs completed, where φ_min ≥ 0", f"{int(np.sum(completed[ok]))} of {int(np.sum(ok))} ({simulate_s:.0f} s for all; `max_jumps={MAX_JUMPS}`)"),
        ("`simulate` runs with more than 10 000 jumps", f"{over_cap}"),
        ("jump counts equal", f"{int(np.sum(same_count))} of {lane_V.size}; where φ_min ≥ 0, {int(np.sum(same_count[ok]))} of {int(np.sum(ok))}"),
        ("time of the last jump, max / median difference", f"{np.max(dt_last, initial=0):.2e} / {np.median(dt_last) if dt_last.size else 0:.2e} s"),
        ("final v, relative difference > 1e-3", f"{int(np.sum(dv_final > 1e-3))} of {lane_V.size} (chaotic rows differ at round-off and grow)"),
    ]  # fmt: skip
    differ = [
        f"law {lane // n_v}, V = {lane_V[lane]:.2f}: {sweep_count[lane]} jumps in the sweep, {jump_count[lane]} in simulate"
        for lane in np.flatnonzero(~same_count & ok)
    ]
    table = "| | |\n|---|---|\n" + "\n".join(f"| {a} | {b} |" for a, b in rows)
    listing = "\n".join(f"- {line}" for line in failed) or "- none"
    differing = "\n".join(f"- {line}" for line in differ) or "- none"
    text = (
        f"# Random adhesion laws at τ = 0\n\n{cpu_model()}, {jax.device_count()} device(s).\n\n{table}\n\n"
        f"Runs that did not complete:\n\n{listing}\n\nRuns with φ_min ≥ 0 whose jump counts differ:\n\n{differing}\n"
    )
    name = "random_laws.md" if args.laws >= 200 else "random_laws_quick.md"
    print(text)
    write_result(Path(__file__).parent / "results" / name, text)


if __name__ == "__main__":
    main()
