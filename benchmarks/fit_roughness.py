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
walk, and the largest jump of each statistic.

    python benchmarks/fit_roughness.py [--problem wide] [--coefficient c1] [--span 0.004] [--points 17]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from fit_coverage import PROBLEMS, truth_of
from machine import load_average, versions, write_result
from peeljax.fit.table import attractor_statistics
from peeljax.measurements.statistics import STATISTICS


def walk(problem: str, coefficient: str, span: float, points: int):
    """Each point's statistics (points, n, 5), which are produced, each row's kind and slips per
    period (−1: no periodic attractor), along log c ∈ [−span, span]."""
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
    return zs, values, available, kinds, slips, V, start


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
    zs, values, available, kinds, slips, V, start = walk(args.problem, args.coefficient, args.span, args.points)
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
    text = "\n".join(lines) + "\n"
    print(text)
    write_result(f"benchmarks/results/fit_roughness_{args.problem}_{args.coefficient}.md", text)


def _runs(values: list) -> list:
    """``values`` with repeats in a row collapsed: 5, 5, 6, 6, 5 → 5, 6, 5."""
    return [v for j, v in enumerate(values) if j == 0 or v != values[j - 1]]


if __name__ == "__main__":
    main()
