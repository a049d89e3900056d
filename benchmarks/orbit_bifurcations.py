"""The bifurcations of the 8-slip orbit at V = 1.1 m/s (the paper's φ), in V and in c1.

Continues the orbit both ways in V over [0.9, 1.2] m/s and in c1 over ±2 % of the paper's
value, and prints every bifurcation located (kind, where, slips per period), the branch's
stable range, and the time each continuation took after compilation (with the load).

Usage: ``python benchmarks/orbit_bifurcations.py [--out results/orbit_bifurcations.md]``
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

import peeljax as pj


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "orbit_bifurcations.md"))
    args = parser.parse_args(argv)
    orbit = pj.periodic_orbit(V=1.1)
    c1 = float(orbit.model.adhesion.c1)
    rows = []
    for parameter, bounds in [("V", (0.9, 1.2)), ("c1", (0.98 * c1, 1.02 * c1))]:
        pj.continue_orbit(orbit, parameter=parameter, bounds=bounds, max_points=3)  # compiles
        start = time.perf_counter()
        branch = pj.continue_orbit(orbit, parameter=parameter, bounds=bounds)
        wall = time.perf_counter() - start
        stable = branch.values[branch.stable]
        rows.append((parameter, branch, wall, (stable.min(), stable.max()) if stable.size else (np.nan, np.nan)))
    load = os.getloadavg()[0]
    lines = [f"Made by `python benchmarks/orbit_bifurcations.py`. Load average (1 min) {load:.1f} on {os.cpu_count()} cores.", ""]
    for parameter, branch, wall, (lo, hi) in rows:
        scale = c1 if parameter == "c1" else 1.0
        unit = f" (× the paper's {c1:g})" if parameter == "c1" else " m/s"
        lines += [
            f"## In {parameter}: {len(branch)} orbits, {wall:.1f} s after compilation; stable for {parameter} in "
            f"[{lo / scale:.6g}, {hi / scale:.6g}]{unit}",
            "",
            f"| {parameter}{' / paper' if parameter == 'c1' else ' [m/s]'} | bifurcation | slips per period |",
            "|---:|---|---:|",
        ]
        lines += [f"| {b.parameter / scale:.6g} | {b.kind.value} | {b.slips} |" for b in sorted(branch.bifurcations, key=lambda b: b.parameter)]
        lines += [""]
    text = "\n".join(lines)
    print(text)
    Path(args.out).write_text(text, encoding="utf-8")


if __name__ == "__main__":
    main()
