"""Where a table fit's χ² is rough, row by row: each row's statistics along one coefficient.

The table fit (``fit_stick_slip``, ``method="orbit"``) follows every row's attractor from one
trial θ to the next. Where a row's attractor changes (a grazing, a loss of stability) or a row
takes window statistics, its statistics can jump, and Levenberg–Marquardt stops on "the rough
floor of χ²". This script walks one coefficient c across [c·e^−span, c·e^span] from the
truth of a ``benchmarks/fit_coverage.py`` problem, each point followed from its neighbour (as
the fit steps), and measures each statistic s of each row in units of σ = 1 % of its value at
the truth (the coverage draws' noise). A smooth row changes by about the same amount from step
to step; the **jump** of a statistic between two neighbours is how far its change departs from
the median change of that statistic (in σ). Per row: its kinds and slips per period along the
walk, and the largest jump of each statistic. Where an orbit's slips per period change between
two neighbours, a second table says how: the grazing monitors of the orbit at the last point
before (``approach``: how close a slip's v came to φ's minimum without re-sticking, 0 at the
grazing; ``crossing``: the slowest crossing of the stick → slip section, 0 where a slip is about
to vanish) and the smallest force drop of a slip on either side (F at the slip minus F where the
tape sticks again, over two periods of the orbit run from its section). A slip born with a
small drop could be weighted away as an instrument misses it; one born at full size moves the
per-slip averages by a step whatever counts the slips. Last, each of the two orbits is followed
across the change from its own side: where both are stable, the row is bistable there and a fit
could choose between them.

    python benchmarks/fit_roughness.py [--problem wide] [--coefficient c1] [--span 0.004] [--points 17]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import equinox as eqx
import numpy as np

from fit_coverage import PROBLEMS, truth_of
from machine import load_average, versions, write_result
from peeljax import PeelingModel, simulate
from peeljax.fit.attractors import shoot_rows
from peeljax.fit.table import attractor_statistics
from peeljax.orbits.section import state_after_slip
from peeljax.measurements.statistics import STATISTICS


def walk(problem: str, coefficient: str, span: float, points: int):
    """Each point's statistics (points, n, 5), which are produced, each row's kind and slips per
    period (−1: no periodic attractor), along log c ∈ [−span, span]; the rows and the points."""
    truth, names, V = truth_of(problem)
    start, rows, _ = attractor_statistics(truth, V, names=names, follow_lost=True)
    k = names.index(coefficient)
    zs = np.linspace(-span, span, points)
    middle = points // 2
    found = {middle: start}
    for steps in (range(middle + 1, points), range(middle - 1, -1, -1)):  # outward from the truth
        base = start
        for i in steps:
            z = np.zeros(len(names))
            z[k] = zs[i]
            found[i] = base = rows.evaluate(z, base)
    points_ = [found[i] for i in range(points)]
    values = np.stack([p.values for p in points_])
    available = np.stack([p.available for p in points_])
    kinds = [[_kind(p, i, rows.kinds[i]) for p in points_] for i in range(len(V))]
    slips = [[p.attractors[i].slips if p.attractors[i] is not None else -1 for p in points_] for i in range(len(V))]
    return zs, values, available, kinds, slips, V, start, rows, points_


def slip_drops(rows, point, i: int) -> np.ndarray:
    """The force drops [N] of row i's orbit at ``point``: F at each stick → slip jump minus F at
    the slip → stick jump that ends it, over two periods run from the orbit's section."""
    attractor = point.attractors[i]
    model = eqx.tree_at(lambda m: m.adhesion, PeelingModel(), rows.law(point.z))
    V = float(rows.V[i])
    y0 = state_after_slip(model, V, attractor.section)
    sol = simulate(model, V=V, tau=0, t_final=2 * attractor.period, y0=y0, rtol=1e-9, atol=1e-12,
                   max_jumps=8 * attractor.slips + 8)  # fmt: skip
    jumps = sol.jumps.as_numpy()
    up, F = np.asarray(jumps["jump_up"], bool), np.asarray(jumps["jump_F"], float)
    # y0 is just after a slip: the first jump ends it, its F at the slip is the section's
    F_slip = np.concatenate([[float(model.tension(y0[2], y0[0]))], F[up]])
    F_stick = F[~up]
    n = min(F_slip.size, F_stick.size)
    return np.sort(F_slip[:n] - F_stick[:n])


def stable_to(rows, points, zs, i: int, j: int, step: int) -> float:
    """How far (in log c) row i's orbit at point j stays a stable orbit of the same slips per
    period, followed over the walk's points j + step, j + 2·step, … (to the walk's end)."""
    attractor, last = points[j].attractors[i], zs[j]
    for m in range(j + step, len(zs) if step > 0 else -1, step):
        row = shoot_rows(rows.program, np.asarray(points[m].z, float), rows.V[[i]], [attractor])
        if int(row["status"][0]) != 0 or not np.max(row["multipliers"][0]) < 1.0:
            break
        attractor = dataclasses.replace(attractor, section=row["section"][0], period=float(row["period"][0]))
        last = zs[m]
    return last


def slip_changes(zs, slips, V, rows, points) -> list[str]:
    """A table row for each change of an orbit's slips per period between two neighbours."""
    lines = []
    for i in range(len(V)):
        for j in range(len(zs) - 1):
            a, b = slips[i][j], slips[i][j + 1]
            if a == b or a < 0 or b < 0:
                continue
            last = j if abs(zs[j + 1]) > abs(zs[j]) else j + 1  # stepped from: the walk goes out from the truth
            orbit = points[last].orbits[i]
            drops = [slip_drops(rows, points[m], i) for m in (j, j + 1)]
            # the two orbits followed across the change, each as far as it stays stable
            both = (stable_to(rows, points, zs, i, j + 1, -1), stable_to(rows, points, zs, i, j, +1))
            coexist = f"{both[0]:+.4f} … {both[1]:+.4f}" if both[0] <= both[1] else "–"
            lines.append(f"| {V[i]:g} | {zs[j]:+.4f} → {zs[j + 1]:+.4f} | {a} → {b} | {float(orbit['approach']):.3g} | "
                         f"{float(orbit['crossing']):.4g} | {drops[0][0]:.2f} / {drops[1][0]:.2f} | "
                         f"{np.median(drops[0]):.1f} / {np.median(drops[1]):.1f} | {coexist} |")  # fmt: skip
    return lines


def _kind(point, i: int, kind: str) -> str:
    if kind == "orbit" and i in point.windowed:
        return "window (orbit lost)"
    if kind == "orbit" and point.attractors[i] is None:
        return "none"
    return kind + (" (singular)" if i in point.singular else "")


def jumps(values, available, scale):
    """Per row and statistic, the largest departure of a step's change from the median change
    (in σ = ``scale``), over the steps where both ends produce the statistic."""
    r = np.where(available, values / scale, np.nan)
    change = np.diff(r, axis=0)
    departure = np.abs(change - np.nanmedian(change, axis=0))
    seen = np.isfinite(departure).any(axis=0)
    return np.where(seen, np.nanmax(np.where(np.isfinite(departure), departure, -np.inf), axis=0), np.nan)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problem", choices=tuple(PROBLEMS), default="wide")
    parser.add_argument("--coefficient", default="c1")
    parser.add_argument("--span", type=float, default=0.004, help="log c from -span to span")
    parser.add_argument("--points", type=int, default=17, help="odd: the truth is the middle point")
    args = parser.parse_args(argv)
    if args.points < 3 or args.points % 2 == 0:
        parser.error(f"--points must be an odd number >= 3, got {args.points}")
    began = time.perf_counter()
    zs, values, available, kinds, slips, V, start, rows, points = walk(args.problem, args.coefficient, args.span,
                                                                       args.points)  # fmt: skip
    scale = 0.01 * np.abs(np.where(start.available, start.values, np.nan))
    largest = jumps(values, available, scale)
    step = zs[1] - zs[0]
    lines = [
        f"# Where the table fit's χ² is rough: problem `{args.problem}`, {args.coefficient} walked over "
        f"±{args.span:g} (log), {args.points} points\n",
        f"{versions('jax', 'equinox')}; {time.perf_counter() - began:.0f} s, load {load_average():.1f}.\n",
        f"Each point is followed from its neighbour, as Levenberg–Marquardt steps (a step of {step:.2g} in log "
        f"{args.coefficient}, {step * 100:.2g} % of it). σ = 1 % of each statistic at the truth. A jump: the largest "
        "departure of one step's change from that statistic's median change, in σ (0 on a straight line; a "
        "smooth curve's departure over the walk is its curvature's).\n",
        "| V [m/s] | kinds along the walk | slips per period along the walk | " + " | ".join(STATISTICS) + " |",
        "|---|---|---|" + "---:|" * len(STATISTICS),
    ]
    for i, v in enumerate(V):
        kind = ", ".join(dict.fromkeys(kinds[i]))
        slips_i = " → ".join(str(s) for s in _runs(slips[i]))
        cells = " | ".join("–" if not np.isfinite(x) else f"{x:.2f}" for x in largest[i])
        lines.append(f"| {v:g} | {kind} | {slips_i} | {cells} |")
    lines.append("\nSlips per period −1: no periodic attractor at that point (the row takes its window statistics).")
    changes = slip_changes(zs, slips, V, rows, points)
    if changes:
        lines += [
            "\n## Where an orbit's slips per period change\n",
            "The grazing monitors of the orbit at the last point before the change, as the walk goes out from the "
            "truth (`approach` [N]: 0 where a slip's v reaches φ's minimum without re-sticking; `crossing` [N/s]: "
            "0 where a slip is about to vanish), and the slips' force drops on either side of the change "
            "(F at the slip minus F where the tape sticks again). Both stable: the points of the walk where "
            "each of the two orbits, followed across the change from its side, is still a stable orbit "
            "(–: nowhere).\n",
            f"| V [m/s] | log {args.coefficient} | slips per period | approach [N] | crossing [N/s] | "
            f"smallest drop [N] | median drop [N] | both stable, log {args.coefficient} |",
            "|---|---|---|---:|---:|---:|---:|---|",
            *changes,
        ]
    text = "\n".join(lines) + "\n"
    print(text)
    write_result(f"benchmarks/results/fit_roughness_{args.problem}_{args.coefficient}.md", text)


def _runs(values: list) -> list:
    """``values`` with repeats in a row collapsed: 5, 5, 6, 6, 5 → 5, 6, 5."""
    return [v for j, v in enumerate(values) if j == 0 or v != values[j - 1]]


if __name__ == "__main__":
    main()
