"""The orbit diagram over V against the brute-force stick-slip map, in one process.

Runs ``peeljax.orbit_diagram`` over [0.3, 5.4] m/s (seeds at 52 V, both starts, 6 s runs) and
``peeljax.stick_slip_map`` at 200 V × 3 s (both starts), and prints:

* the wall time of each (the machine's load beside them);
* how many of the map's periodic lanes lie on a traced branch: a branch point with the lane's
  k (or a divisor of it) whose time between slips and slip duration agree with the lane's
  window means to 1 % at the lane's V (interpolated along the branch);
* the bifurcations located, by kind, and the ends of the stick-slip range.

Usage: ``python benchmarks/orbit_diagram.py [--diagram FILE.npz] [--out results/orbit_diagram.md]``
(``--diagram``: a diagram saved before, e.g. by ``peeljax orbit --V 0.3:5.4 --out FILE.npz``,
instead of computing it: its own wall time is reported).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

import peeljax as pj


def _on_branch(diagram, V: float, k: int, interval: float, duration: float, rtol: float = 0.01) -> bool:
    for branch in diagram.branches:
        for kb in {int(x) for x in branch.slips}:
            if k % kb:
                continue
            mine = branch.slips == kb
            Vb = branch.V[mine]
            if Vb.size < 2 or not Vb.min() <= V <= Vb.max():
                continue
            for i in np.flatnonzero(mine)[:-1]:
                if not mine[i + 1] or not min(branch.V[i], branch.V[i + 1]) <= V <= max(branch.V[i], branch.V[i + 1]):
                    continue
                w = (V - branch.V[i]) / (branch.V[i + 1] - branch.V[i]) if branch.V[i + 1] != branch.V[i] else 0.0
                T = (1 - w) * branch.statistics["period"][i] + w * branch.statistics["period"][i + 1]
                D = (1 - w) * branch.statistics["slip_duration"][i] + w * branch.statistics["slip_duration"][i + 1]
                if abs(T / interval - 1) < rtol and abs(D / duration - 1) < rtol:
                    return True
    return False


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--diagram", default=None)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "orbit_diagram.md"))
    parser.add_argument("--map-V", type=int, default=200)
    args = parser.parse_args(argv)
    load = os.getloadavg()[0]
    if args.diagram:
        diagram = pj.load(args.diagram)
        diagram_time = diagram.wall_time
    else:
        start = time.perf_counter()
        diagram = pj.orbit_diagram(V=(0.3, 5.4), seeds=52, t_final=6.0)
        diagram_time = time.perf_counter() - start
    start = time.perf_counter()
    V = np.linspace(0.3, 5.4, args.map_V)
    m = pj.stick_slip_map(V=V, t_final=3.0, progress=False)
    map_time = time.perf_counter() - start
    load = max(load, os.getloadavg()[0])

    lanes, on = 0, 0
    missing = []
    for s in range(len(m.starts)):
        for i, v in enumerate(V):
            k = int(m.events[s, i]) if np.isfinite(m.events[s, i]) else 0
            if k <= 0:
                continue
            lanes += 1
            interval, duration = float(m.slip_interval[s, i]), float(m.slip_duration[s, i])
            found = _on_branch(diagram, float(v), k, interval, duration)
            on += found
            if not found:
                missing.append(f"{m.starts[s]} V = {v:.4g}: k = {k}, T/k = {1e3 * interval:.4g} ms")
    kinds: dict[str, int] = {}
    for _, b in diagram.bifurcations:
        kinds[b.kind.value] = kinds.get(b.kind.value, 0) + 1
    lines = [
        f"Made by `python benchmarks/orbit_diagram.py{' --diagram ' + args.diagram if args.diagram else ''}`.",
        "",
        f"Load average (1 min) up to {load:.1f} on {os.cpu_count()} cores.",
        "",
        "| what | wall time [s] |",
        "|---|---:|",
        f"| orbit diagram over [0.3, 5.4] m/s ({len(diagram.branches)} branches, "
        f"{sum(len(b) for b in diagram.branches)} orbits, seeds {diagram.seed_time:.0f} s of it) | {diagram_time:.1f} |",
        f"| brute-force map, {args.map_V} V × 3 s, both starts | {map_time:.1f} |",
        "",
        f"Periodic map lanes on a traced branch (k or a divisor, T/k and slip duration within 1 %): {on} of {lanes}.",
        "",
        "Bifurcations located: " + (", ".join(f"{n} {k}" for k, n in sorted(kinds.items())) or "none") + ".",
    ]
    if missing:
        lines += ["", "Map lanes on no traced branch:", ""] + [f"- {x}" for x in missing[:60]]
    text = "\n".join(lines) + "\n"
    print(text)
    Path(args.out).write_text(text, encoding="utf-8")


if __name__ == "__main__":
    main()
