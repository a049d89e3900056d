"""Fit acceptance, full version (issue 4 §2): all 14 coefficients, or a chosen subset.

Data: the paper's φ at V = 1.1, 2 and 4 m/s, τ (default 0.1 s: the runs complete), t ∈ [0, T],
dt = 1/82 s, v(t) and F(t) with 1 % multiplicative noise. Start: the coefficients perturbed
by ±(10–20) %. Criteria: φ(v, V) within 2 % of the paper's over the visited v range at the
three V, and a loss reduction ≥ 100×. ``tests/test_fit.py`` runs the short CI version.

    python benchmarks/fit_acceptance.py [--free c1 c3 ...] [--t-final 0.5] [--tau 0.1] [--steps 200]
"""

from __future__ import annotations

import argparse

import numpy as np

import peeljax as pj


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--free", nargs="+", default=None, help="coefficients to fit (default all 14)")
    parser.add_argument("--t-final", type=float, default=0.5)
    parser.add_argument("--tau", type=float, default=0.1)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--optimizer", default="lbfgs")
    parser.add_argument("--seed", type=int, default=4)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    model = pj.PeelingModel()
    observations = []
    for V in (1.1, 2.0, 4.0):
        sol = pj.simulate(model, V=V, tau=args.tau, dt=1 / 82, t_final=args.t_final)
        ok = np.asarray(sol.valid)
        F = np.asarray(model.tension(sol.ys[:, 2], sol.ys[:, 0]))[ok]
        v = np.asarray(sol.v)[ok]
        print(f"V = {V}: {sol.status_name}, t_stop = {float(sol.t_stop):.3g} s, v in [{v.min():.3g}, {v.max():.3g}]")
        observations.append(
            pj.Observation(
                V=V,
                t=np.asarray(sol.ts)[ok],
                v=v * (1 + 0.01 * rng.standard_normal(v.size)),
                F=F * (1 + 0.01 * rng.standard_normal(F.size)),
            )
        )
    names = args.free or pj.COEFFICIENT_NAMES
    true = pj.AdhesionLaw()
    start = pj.AdhesionLaw(
        **{n: pj.PAPER_COEFFICIENTS[n] * (1 + rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 0.2)) for n in names}
    )
    result = pj.fit_adhesion(
        observations,
        tau=args.tau,
        dt=1 / 82,
        free=names,
        start=start,
        optimizer=args.optimizer,
        steps=args.steps,
        patience=30,
        tolerance=1e-6,
    )
    Vs = (1.1, 2.0, 4.0)
    print(f"fitted {list(result.free)} in {result.steps} iterations, {result.wall_time_s:.0f} s")
    print(
        f"loss {result.initial_loss:.3e} -> {result.final_loss:.3e}: {result.loss_reduction:.0f}x (>= 100 required)"
    )
    print(f"visited v range {result.v_range}")
    print(
        f"max relative phi error over the visited range: start {pj.phi_relative_error(start, true, Vs, result.v_range):.4f}, "
        f"fitted {pj.phi_relative_error(result.adhesion, true, Vs, result.v_range):.4f} (< 0.02 required)"
    )
    for n in names:
        print(f"  {n}: start {float(getattr(start, n)):.5g}, fitted {float(getattr(result.adhesion, n)):.5g}, true {pj.PAPER_COEFFICIENTS[n]:.5g}")


if __name__ == "__main__":
    main()
