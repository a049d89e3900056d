"""The attractor map over V against the brute-force stick-slip map at the same V resolution.

Both run at τ = 0 over ``--n-V`` values of V in [0.3, 5.4] m/s on this machine's cores:

* ``peeljax.attractor_map(V)``: rest, steady and ``--random-starts`` random starts per V, the
  neighbours' seeds, the periodic orbits refined, the undecided runs again and their Lyapunov
  exponents, the boundaries bisected to 1e-4 m/s (its defaults);
* ``peeljax.stick_slip_map(V)``: one 3 s run per V from rest and one from steady peeling (its
  defaults), no labels beyond its repeat search.

Each is first run once on a 16-V grid (its compilation: the same programs), then timed once on
the full grid (a map takes minutes: one timing each, both in this process, the load stated).
What the attractor map finds is tabulated: the attractors by label, and every attractor the
brute-force map's repeat search finds (periodic with k slips at a V) checked to be on it.

    python benchmarks/attractor_map.py                  # 200 V (several minutes on 2 cores)
    python benchmarks/attractor_map.py --n-V 40         # a check

Writes ``results/attractor_map.md`` (``results/attractor_map_quick.md`` with ``--n-V`` < 200).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import Counter
from pathlib import Path

import numpy as np

import peeljax as pj
from peeljax.attractor_map import PERIODIC, UNSTABLE

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import timed  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n-V", dest="n_V", type=int, default=200)
    parser.add_argument("--random-starts", dest="random_starts", type=int, default=None)
    parser.add_argument("--save", default=None, help="also write the map there (.npz, peeljax.load reads it)")
    args = parser.parse_args(argv)
    kwargs = {} if args.random_starts is None else {"random_starts": args.random_starts}
    V = np.linspace(0.3, 5.4, args.n_V)
    small = np.linspace(0.3, 5.4, 16)

    _, warm = timed(lambda: (pj.attractor_map(V=small, progress=False, **kwargs), pj.stick_slip_map(V=small, progress=False)))

    load = os.getloadavg()[0]
    amap, t_map = timed(pj.attractor_map, V=V, **kwargs)
    if args.save:
        amap.save(args.save)
    smap, t_brute = timed(pj.stick_slip_map, V=V, progress=False)

    labels = Counter(amap.labels)
    missing, transient, multiple = compare(amap, smap)
    b = amap.boundaries
    command = "python benchmarks/attractor_map.py" + ("" if args.n_V == 200 else f" --n-V {args.n_V}")
    lines = [
        f"Made by `{command}`.",
        "",
        f"# The attractor map against the brute-force map ({args.n_V} V in [0.3, 5.4] m/s, τ = 0)",
        "",
        f"{os.cpu_count()} cores, load {load:.1f} at the start; compilation and a 16-V warm-up: {warm:.0f} s.",
        "",
        "| map | wall time [s] | ratio |",
        "|---|---:|---:|",
        f"| `attractor_map` (rounds of lanes: {', '.join(map(str, amap.rounds))}) | {t_map:.1f} | {t_map / t_brute:.2f} |",
        f"| `stick_slip_map` (2 starts × {args.n_V} V, 3 s) | {t_brute:.1f} | 1 |",
        "",
        "Attractors: " + ", ".join(f"{n} {label}" for label, n in sorted(labels.items())),
        "",
        f"Periodic repeats of the brute-force map that are runs near an unstable orbit of the same k "
        f"(not attractors; on the attractor map with that label): {transient}",
        "",
        f"Periodic repeats of the brute-force map that are an orbit of the attractor map counted over several "
        f"of its periods (k and T both a multiple of the orbit's): {multiple}",
        "",
        f"Periodic attractors of the brute-force map not on the attractor map: {len(missing)}",
        *(f"- {line}" for line in missing[:20]),
        "",
        f"Boundaries located: {b['branch'].size}",
        "",
        "| branch | V inside | V outside | change |",
        "|---:|---:|---:|---|",
        *(f"| {b['branch'][i]} | {b['V_inside'][i]:.5f} | {b['V_outside'][i]:.5f} | {b['change'][i]} |" for i in range(b["branch"].size)),
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    name = "attractor_map.md" if args.n_V >= 200 else "attractor_map_quick.md"
    (RESULTS / name).write_text(text)
    return 0


def compare(amap, smap) -> tuple[list[str], int, int]:
    """The brute-force map's periodic repeats (k, T) against the attractor map at the same V:
    (those not on it, those it labels near an unstable orbit, those that are one of its orbits
    repeated over several periods: k = m·k', T = m·T' to 1e-3)."""
    missing, transient, multiple = [], 0, 0
    for s, start in enumerate(smap.starts):
        for j in np.flatnonzero(smap.events[s] > 0):
            k, T = int(smap.events[s][j]), float(smap.period[s][j])
            here = amap.V_index == j
            if np.any(here & (amap.kind == PERIODIC) & (amap.slips == k)):
                continue
            if np.any(here & (amap.kind == UNSTABLE) & (amap.slips == k)):
                transient += 1  # the brute force's repeat is a run still near an unstable orbit
                continue
            orbits = np.flatnonzero(here & (amap.kind == PERIODIC) & (amap.slips > 0))
            if any(k % amap.slips[i] == 0 and abs(T - k // amap.slips[i] * amap.period[i]) <= 1e-3 * T for i in orbits):
                multiple += 1
            else:
                missing.append(f"V = {amap.grid_V[j]:.4f}: periodic k = {k} (from {start})")
    return missing, transient, multiple


if __name__ == "__main__":
    sys.exit(main())
