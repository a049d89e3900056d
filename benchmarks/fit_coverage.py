"""Coverage of the table fit's 95 % intervals (issue 28, item 4): over many noise draws of one
hidden-truth stick-slip table, the fraction of draws whose 95 % interval of each coefficient
covers the truth (target 92–98 % over ≥ 200 draws).

Problem (small, so that many draws fit in the time): φ with c1 × 1.05 and c6 × 1.05 (the pair
whose terms c1·v^0.35 and c6·v^0.5 compensate), a table at V = 1.0, 1.5, 2.2, 3.0 m/s with all
five statistics over [0.5, 1.5] s, made once at the fit's tolerances; each draw multiplies every
entry by 1 + 0.01·N(0, 1) and gives σ = 1 % of the exact value (``synthetic_table``'s recipe),
and is fitted from the paper's φ by :func:`peeljax.fit.fit_stick_slip` (``free=("c1", "c6")``,
the default ``scale_covariance="auto"``). Every draw reuses the one compiled program (same
shapes). Prints the coverage per coefficient with its binomial standard error, the mean χ²/dof,
how often the covariance was scaled, and how many fits converged.

    python benchmarks/fit_coverage.py [--draws 200] [--seed 0] [--level 0.95] [--taper 0.25]
"""

from __future__ import annotations

import argparse
import math
import time

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import peeljax as pj
from peeljax.fit import StickSlipTable, fit_stick_slip
from peeljax.fit.statistics import STATISTICS
from peeljax.fit.plots import model_statistics
from peeljax.fit.table import build_table_fit, table_tolerances

TRUTH = {"c1": 1.05, "c6": 1.05}
V = (1.0, 1.5, 2.2, 3.0)
WINDOW = {"transient": 0.5, "window": 1.0}  # fit_stick_slip's defaults
FIT = {"n_coarse": 2, "n_starts": 1, "max_iterations": 20}


def exact_statistics(truth: pj.AdhesionLaw, taper: float = 0.0) -> dict[str, np.ndarray]:
    """The model's statistics at ``V`` with φ = ``truth``, as the fit runs them (its tolerances, ``taper``)."""
    rtol, atol = table_tolerances(0.0)
    if taper == 0:
        return model_statistics(truth, V, rtol=rtol, atol=atol, **WINDOW)[0]
    shape = (len(V), len(STATISTICS))
    fit = build_table_fit(
        truth, pj.PeelingModel(), V, np.zeros(shape), np.ones(shape), np.ones(shape, bool), names=("c1",), tau=0.0,
        n_samples=401, rtol=rtol, atol=atol, max_jumps=4096, max_steps=400_000, taper=taper, **WINDOW,
    )  # fmt: skip
    values, available, _ = eqx.filter_jit(lambda f, th: f.statistics(th))(fit, {"c1": jnp.zeros(())})
    values = np.where(np.asarray(available), np.asarray(values), np.nan)
    return {s: values[:, j] for j, s in enumerate(STATISTICS)}


def draw(stats: dict, rng, noise: float = 0.01) -> StickSlipTable:
    """One noisy table: each entry × (1 + noise·N(0, 1)), σ = noise·|exact|."""
    columns = {}
    for name in STATISTICS:
        exact = np.asarray(stats[name])
        columns[name] = exact * (1 + noise * rng.normal(size=exact.shape))
        columns[f"{name}_std"] = noise * np.abs(exact)
    return StickSlipTable.from_dict(V=np.asarray(V), **columns)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--level", type=float, default=0.95)
    parser.add_argument("--taper", type=float, default=0.0, help="tapered window statistics (fit_stick_slip's taper)")
    args = parser.parse_args()
    c = pj.AdhesionLaw().coefficients()
    truth = pj.AdhesionLaw(**{**c, **{n: c[n] * m for n, m in TRUTH.items()}})
    names = tuple(TRUTH)
    stats = exact_statistics(truth, args.taper)
    rng = np.random.default_rng(args.seed)
    covered = np.zeros(len(names), int)
    chi2_dof, scaled, converged, walls = [], 0, 0, []
    for k in range(args.draws):
        began = time.perf_counter()
        result = fit_stick_slip(draw(stats, rng), free=names, taper=args.taper, **WINDOW, **FIT)
        walls.append(time.perf_counter() - began)
        intervals = result.uncertainty.intervals(args.level)
        covered += [intervals[n][0] <= float(getattr(truth, n)) <= intervals[n][1] for n in names]
        chi2_dof.append(result.chi2_dof)
        scaled += bool(result.uncertainty.scaled)
        converged += bool(result.converged)
        if (k + 1) % 10 == 0 or k + 1 == args.draws:
            n = k + 1
            cover = ", ".join(f"{name} {covered[j] / n:.1%}" for j, name in enumerate(names))
            print(f"{n} draws: coverage {cover}; mean chi2/dof {np.mean(chi2_dof):.3f}; scaled {scaled}; "
                  f"converged {converged}; fit median {np.median(walls[1:] or walls):.2f} s", flush=True)  # fmt: skip
    n = args.draws
    print(f"\n| coefficient | truth | coverage of the {args.level:.0%} intervals | ± binomial SE | draws |")
    print("|---|---:|---:|---:|---:|")
    for j, name in enumerate(names):
        p = covered[j] / n
        print(f"| {name} | {float(getattr(truth, name)):.5g} | {p:.1%} | {math.sqrt(p * (1 - p) / n):.1%} | {n} |")
    print(f"\nmean chi2/dof {np.mean(chi2_dof):.3f} (dof {result.dof}); covariance scaled in {scaled} of {n} draws; "
          f"{converged} of {n} fits converged; first fit (compilation) {walls[0]:.1f} s, then median "
          f"{np.median(walls[1:] or walls):.2f} s per draw")  # fmt: skip


if __name__ == "__main__":
    main()
