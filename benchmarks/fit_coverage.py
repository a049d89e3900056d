"""Coverage of the table fit's 95 % intervals: over many noise draws of one hidden-truth
stick-slip table, the fraction of draws whose 95 % confidence set of each coefficient covers
the truth (target 92–98 % over ≥ 200 draws for two coefficients, ≥ 100 for three).

Problems (``PROBLEMS``): ``two`` (c1, c6 × 1.05 at 4 V), ``three`` (c1, c3, c6 at 8 V in 0.8–3 m/s)
and ``wide`` (c1, c3, c6 at 0.5 … 4 m/s; at 0.5 m/s the tape stops after every slip). Each draw
perturbs the exact table by 1 % noise (``synthetic_table``'s recipe) and fits it from the paper's φ
with ``fit_stick_slip``'s defaults, reusing the compiled programs. One JSON line per draw goes to
``--out`` (appended: ``--resume`` goes on from the draws there): coverage of the reported and of the
linearized interval, χ²/dof, convergence, bifurcations crossed, profiles computed, time.

    python benchmarks/fit_coverage.py [--problem two|three|wide] [--draws 200] [--seed 0]
                                      [--intervals auto|linear|profile] [--out FILE] [--resume]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

import peeljax as pj
from peeljax.fit import StickSlipTable, fit_stick_slip
from peeljax.measurements.statistics import STATISTICS
from peeljax.fit.table import attractor_statistics

PROBLEMS = {
    "two": ({"c1": 1.05, "c6": 1.05}, (1.0, 1.5, 2.2, 3.0)),
    "three": ({"c1": 1.12, "c3": 1.06, "c6": 1.10}, (0.8, 1.0, 1.2, 1.5, 1.8, 2.2, 2.6, 3.0)),
    "wide": ({"c1": 1.07, "c3": 0.93, "c6": 1.07}, (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)),
}


def truth_of(problem: str) -> tuple[pj.AdhesionLaw, tuple[str, ...], tuple[float, ...]]:
    factors, V = PROBLEMS[problem]
    c = pj.AdhesionLaw().coefficients()
    return pj.AdhesionLaw(**{**c, **{n: c[n] * m for n, m in factors.items()}}), tuple(factors), V


def exact_statistics(truth: pj.AdhesionLaw, V, names) -> tuple[dict[str, np.ndarray], list[str]]:
    """The statistics the fit predicts at the truth (module docstring), and each row's kind."""
    point, rows, _ = attractor_statistics(truth, V, names=names)
    values = np.where(point.available, point.values, np.nan)
    return {s: values[:, j] for j, s in enumerate(STATISTICS)}, rows.kinds


def draw(stats: dict, V, rng, noise: float = 0.01) -> StickSlipTable:
    """One noisy table: each entry × (1 + noise·N(0, 1)), σ = noise·|exact|."""
    columns = {}
    for name in STATISTICS:
        exact = np.asarray(stats[name])
        columns[name] = exact * (1 + noise * rng.normal(size=exact.shape))
        columns[f"{name}_std"] = noise * np.abs(exact)
    return StickSlipTable.from_dict(V=np.asarray(V), **columns)


def summarize(records: list[dict], names, level: float) -> str:
    n = len(records)
    lines = ["| coefficient | coverage (reported) | coverage (linearized) | ± binomial SE | draws |", "|---|---:|---:|---:|---:|"]
    for name in names:
        p = np.mean([r["covers"][name] for r in records])
        q = np.mean([r["covers_linear"][name] for r in records])
        lines.append(f"| {name} | {p:.1%} | {q:.1%} | {math.sqrt(max(p * (1 - p), 1e-12) / n):.1%} | {n} |")
    chi2 = np.mean([r["chi2_dof"] for r in records])
    lines.append(
        f"\nmean chi2/dof {chi2:.3f}; converged {sum(r['converged'] for r in records)} of {n}; profiles computed in "
        f"{sum(bool(r['profiles']) for r in records)}; bifurcations crossed per fit {np.mean([r['crossings'] for r in records]):.1f}; "
        f"fit median {np.median([r['wall'] for r in records]):.1f} s (first {records[0]['wall']:.0f} s with compilation)"
    )
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problem", choices=tuple(PROBLEMS), default="two")
    parser.add_argument("--draws", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--level", type=float, default=0.95)
    parser.add_argument("--intervals", choices=("auto", "linear", "profile"), default="auto")
    parser.add_argument("--out", default=None, help="JSON lines, one per draw (default: none)")
    parser.add_argument("--resume", action="store_true", help="go on after the draws already in --out")
    args = parser.parse_args(argv)
    truth, names, V = truth_of(args.problem)
    true = {n: float(getattr(truth, n)) for n in names}
    began = time.perf_counter()
    stats, kinds = exact_statistics(truth, V, names)
    print(f"truth {true} at V = {V}: rows {kinds} ({time.perf_counter() - began:.0f} s)", flush=True)
    records = []
    if args.out and args.resume and Path(args.out).exists():
        records = [json.loads(line) for line in Path(args.out).read_text().splitlines() if line.strip()]
    rng = np.random.default_rng(args.seed)
    for k in range(args.draws):
        table = draw(stats, V, rng)  # drawn for every k, so that a resumed run draws the same tables
        if k < len(records):
            continue
        began = time.perf_counter()
        result = fit_stick_slip(table, free=names, intervals=args.intervals, level=args.level)
        linear = result.uncertainty.intervals(args.level)
        record = {
            "draw": k, "covers": result.covers(true, args.level),
            "covers_linear": {n: bool(linear[n][0] <= true[n] <= linear[n][1]) for n in names},
            "values": dict(zip(names, map(float, result.uncertainty.values))),
            "se": dict(zip(names, map(float, result.uncertainty.standard_errors))),
            "intervals": result.intervals(args.level), "chi2": result.chi2, "chi2_dof": result.chi2_dof,
            "converged": result.converged, "stop": result.stop_reason.split(":")[0],
            "crossings": len(result.crossings), "profiles": sorted(result.profiles),
            "rows": [(r["kind"], r.get("slips")) for r in result.rows], "wall": time.perf_counter() - began,
        }  # fmt: skip
        records.append(record)
        if args.out:
            with open(args.out, "a") as f:
                f.write(json.dumps(record) + "\n")
        cover = ", ".join(f"{n} {record['covers'][n]}/{record['covers_linear'][n]}" for n in names)
        print(f"draw {k}: {cover} (reported/linear); chi2/dof {result.chi2_dof:.2f}; {record['stop']}; "
              f"{record['crossings']} crossings; profiles {record['profiles']}; {record['wall']:.0f} s", flush=True)  # fmt: skip
        if len(records) % 10 == 0:
            print(summarize(records, names, args.level), flush=True)
    print(summarize(records, names, args.level))


if __name__ == "__main__":
    main()
