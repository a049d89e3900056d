"""Fit acceptance: the trajectory fit (issue 4 §2) and, with ``--table``, the stick-slip table fit
(issue 28's target).

Trajectory fit (default): all 14 coefficients or a chosen subset, from the paper's φ perturbed by
±(10–20) %, to v, F and α with 1 % noise at V = 1.1, 2, 4 m/s, τ = 0.01 s, t ∈ [0, T]. Passes if φ is
within 2 % of the paper's over the visited v range and the loss falls ≥ 100× (``tests/test_fit.py``
asserts it); the noise floor (the loss of the true φ) is printed beside it.

``--table``: ``fit_stick_slip`` on a stick-slip table at 8 V in 0.8 … 3 m/s made from φ with c1 × 1.12,
c3 × 1.06, c6 × 1.10. Passes if every coefficient is within 2 % of the truth and 3 standard errors, in
≤ 60 s compilation included (``tests/test_fit_table.py`` checks it on a smaller problem). ``--wide``:
the same across 0.5–4 m/s (``WIDE_TRUTH``, ``WIDE_STOPS``: the tape stops after every slip at 0.5 m/s).

    python benchmarks/fit_acceptance.py [--free c1 c3 ...] [--t-final 1.0] [--tau 0.01] [--steps 500]
    python benchmarks/fit_acceptance.py --table [--V 0.8 1.0 ...] [--seed 1]
    python benchmarks/fit_acceptance.py --wide grazing|stops [--seed 1]

Prints a table; writes nothing.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import peeljax as pj
from machine import timed

VELOCITIES = (1.1, 2.0, 4.0)


def noisy_observations(model, tau, t_final, rng, noise=0.01, dt=1 / 82, error_control=False):
    """v, F and α of the paper's runs at each V with multiplicative Gaussian noise, and the exact v.

    ``error_control``: the runs use error control at rtol 1e-9 with output every ``dt``
    (else the uniform mesh of step ``dt``)."""
    observations, visited = [], []
    for V in VELOCITIES:
        if error_control:
            grid = np.linspace(0.0, t_final, round(t_final / dt) + 1)
            sol = pj.simulate(model, V=V, tau=tau, t_final=t_final, ts=grid, rtol=1e-9, atol=1e-12)
        else:
            sol = pj.simulate(model, V=V, tau=tau, dt=dt, t_final=t_final)
        ok = np.asarray(sol.valid)
        ys = np.asarray(sol.ys)[ok]
        exact = {"v": ys[:, 3], "F": np.asarray(model.tension(ys[:, 2], ys[:, 0])), "alpha": ys[:, 0]}
        noisy = {q: x * (1 + noise * rng.standard_normal(x.size)) for q, x in exact.items()}
        observations.append(pj.Observation(V=V, t=np.asarray(sol.ts)[ok], **noisy))
        visited.append(exact["v"])
    return observations, visited


def phi_error_at(law, true, visited):
    """max |φ_law/φ_true − 1| at the (v, V) the runs visit at the observation times."""
    return max(
        float(np.max(np.abs(np.asarray(law(v, V)) / np.asarray(true(v, V)) - 1))) for v, V in zip(visited, VELOCITIES)
    )


def perturbed_start(rng, names):
    """The paper's coefficients, those in ``names`` moved by ±(10–20) %."""
    return pj.AdhesionLaw(
        **{n: pj.PAPER_COEFFICIENTS[n] * (1 + rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 0.2)) for n in names}
    )


def run(
    *, t_final=1.0, tau=0.01, steps=500, free=None, optimizer="lbfgs", seed=0, progress=True, rtol=1e-6, dt=None
) -> dict:
    """The acceptance fit; returns the fit result and the measures the criteria are about.

    Default: data and model with error control (model at ``rtol``, atol = 1e-3·rtol; data at
    rtol 1e-9, output every 1/82 s). ``dt``: data and model on the uniform mesh of that step."""
    rng = np.random.default_rng(seed)
    model = pj.PeelingModel()
    observations, visited = noisy_observations(model, tau, t_final, rng, error_control=dt is None)
    names = tuple(free or pj.COEFFICIENT_NAMES)
    true = pj.AdhesionLaw()
    start = perturbed_start(rng, names)
    settings = {"tau": tau, "t_final": t_final, "free": names, "optimizer": optimizer}
    settings |= {"rtol": rtol, "atol": 1e-3 * rtol} if dt is None else {"dt": dt}
    # The true φ's loss on the same noisy data: the noise floor (same shapes, same compiled program).
    floor = pj.fit_adhesion(observations, start=true, steps=0, progress=False, **settings).final_loss
    result = pj.fit_adhesion(
        observations, start=start, steps=steps, patience=30, tolerance=1e-6, progress=progress, **settings
    )
    return {
        "result": result,
        "start": start,
        "noise_floor": floor,
        "phi_error_start": pj.phi_relative_error(start, true, VELOCITIES, result.v_range),
        "phi_error": pj.phi_relative_error(result.adhesion, true, VELOCITIES, result.v_range),
        "phi_error_start_at_samples": phi_error_at(start, true, visited),
        "phi_error_at_samples": phi_error_at(result.adhesion, true, visited),
    }


TABLE_TRUTH = {"c1": 1.12, "c3": 1.06, "c6": 1.10}  # multipliers of the paper's coefficients
TABLE_V = (0.8, 1.0, 1.2, 1.5, 1.8, 2.2, 2.6, 3.0)
TABLE_WINDOW = {"transient": 0.5, "window": 1.0}  # fit_stick_slip's defaults
# --wide: the whole stick-slip range, long orbits near grazings at 3.5-4 m/s (their derivatives
# singular) and, with WIDE_STOPS, a tape that stops after each slip at 0.5 m/s (its 5-slip orbit,
# a multiplier −0.976, settles too slowly for the rows' runs: found by shooting k = 1 … 12)
WIDE_V = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)
WIDE_TRUTH = {"c1": 1.08, "c3": 0.93, "c6": 1.06}
WIDE_STOPS = {"c1": 1.07, "c3": 0.93, "c6": 1.07}  # φ_min 116.8 N < φ(0⁺) = 125.4 N at 0.5 m/s
WIDE_LIMIT = 60.0  # [s], compilation included


def hidden_truth(multipliers=None) -> pj.AdhesionLaw:
    """The paper's φ with the coefficients of ``multipliers`` (default ``TABLE_TRUTH``) scaled."""
    c = pj.AdhesionLaw().coefficients()
    return pj.AdhesionLaw(**{**c, **{n: c[n] * m for n, m in (multipliers or TABLE_TRUTH).items()}})


def run_table(*, V=TABLE_V, multipliers=None, seed=1, noise=0.01, **options) -> dict:
    """The table acceptance fit (module docstring): the result, the truth and the wall time of
    the fit (compilation included)."""
    from peeljax.fit import fit_stick_slip
    from peeljax.fit.synthetic import synthetic_table
    from peeljax.fit.table import table_tolerances

    truth = hidden_truth(multipliers)
    rtol, atol = table_tolerances(0.0, options.get("rtol"), options.get("atol"))
    method = options.get("method", "orbit")  # the table made as the fit predicts it
    table = synthetic_table(truth, np.asarray(V, float), noise=noise, seed=seed, rtol=rtol, atol=atol, method=method,
                            **TABLE_WINDOW)  # fmt: skip
    names = tuple(multipliers or TABLE_TRUTH)
    began, cpu = time.perf_counter(), time.process_time()
    result = fit_stick_slip(table, free=names, **TABLE_WINDOW, **options)
    return {"result": result, "truth": truth, "table": table, "wall_s": time.perf_counter() - began,
            "cpu_s": time.process_time() - cpu}  # fmt: skip


def print_table(out: dict) -> bool:
    """The table fit's coefficients against the truth; True when the criteria hold."""
    result, truth = out["result"], out["truth"]
    u = result.uncertainty
    print(result.summary())
    print("\n| coefficient | truth | start | fitted | ± SE | error | error / SE |\n|---|---:|---:|---:|---:|---:|---:|")
    limit = out.get("limit") or (15 if result.settings.get("method") == "orbit" else 60)  # [s], compilation included
    ok = out["wall_s"] <= limit
    for n, value, se in zip(u.names, u.values, u.standard_errors):
        true = float(getattr(truth, n))
        error = value / true - 1
        ok &= abs(error) <= 0.02 and abs(value - true) <= 3 * se
        print(f"| {n} | {true:.5g} | {float(getattr(result.start, n)):.5g} | {value:.5g} | {se:.3g} | "
              f"{error:+.2%} | {(value - true) / se:+.2f} |")  # fmt: skip
    print(f"\nV = {list(result.settings['V'])}; {result.steps} LM iterations after a coarse batch of "
          f"{result.settings['n_coarse']}; {out['wall_s']:.1f} s from the call to the result (compilation included; "
          f"<= {limit} s required; {out['cpu_s']:.1f} s of CPU time on this process, and the load average was "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores); criteria (within 2 % and 3 SE, <= {limit} s): {'met' if ok else 'NOT met'}")  # fmt: skip
    return bool(ok)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--free", nargs="+", default=None, help="coefficients to fit (default all 14)")
    parser.add_argument("--t-final", type=float, default=1.0)
    parser.add_argument("--tau", type=float, default=0.01)
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--optimizer", default="lbfgs")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rtol", type=float, default=1e-6, help="error control's rtol (default 1e-6)")
    parser.add_argument("--dt", type=float, default=None, help="the uniform mesh of this step instead (data and model)")
    parser.add_argument("--table", action="store_true", help="the stick-slip table fit (issue 28's target) instead")
    parser.add_argument("--V", type=float, nargs="+", default=list(TABLE_V), help="--table: the pull velocities")
    parser.add_argument("--method", choices=("orbit", "window"), default="orbit", help="--table: fit_stick_slip's method")
    parser.add_argument("--wide", choices=("grazing", "stops"), default=None,
                        help="--table across 0.5-4 m/s: the truth WIDE_TRUTH (grazing orbits) or WIDE_STOPS (the tape stops)")  # fmt: skip
    args = parser.parse_args(argv)
    if args.wide:
        truth = WIDE_TRUTH if args.wide == "grazing" else WIDE_STOPS
        out = run_table(V=WIDE_V, multipliers=truth, seed=1 if args.seed == 0 else args.seed, method=args.method)
        print_table({**out, "limit": WIDE_LIMIT})
        return
    if args.table:
        print_table(run_table(V=args.V, seed=1 if args.seed == 0 else args.seed, method=args.method))
        return
    out, wall = timed(run, **{key: getattr(args, key) for key in ("t_final", "tau", "steps", "free", "optimizer", "seed",
                                                                 "rtol", "dt")})  # fmt: skip
    result, start, floor = out["result"], out["start"], out["noise_floor"]
    engine = f"uniform mesh dt = {args.dt:g}" if args.dt is not None else f"error control rtol = {args.rtol:g}"
    print(f"fitted {list(result.free)} ({engine}): {result.steps} iterations, {result.wall_time_s:.0f} s in the fit, "
          f"{wall:.0f} s from start to result (data generation and compilation included)")  # fmt: skip
    print(f"loss {result.initial_loss:.3e} -> {result.final_loss:.3e}: {result.loss_reduction:.0f}x (>= 100 required)")
    print(
        f"loss of the true phi on these data (noise floor) {floor:.3e}; L(start)/L(true) = {result.initial_loss / floor:.0f}"
    )
    print(f"visited v range {result.v_range}")
    print(
        f"max relative phi error over the visited range: start {out['phi_error_start']:.4f}, "
        f"fitted {out['phi_error']:.4f} (< 0.02 required)"
    )
    print(
        f"max relative phi error at the (v, V) the runs visit at the observation times: "
        f"start {out['phi_error_start_at_samples']:.4f}, fitted {out['phi_error_at_samples']:.4f}"
    )
    for n in result.free:
        print(
            f"  {n}: start {float(getattr(start, n)):.5g}, fitted {float(getattr(result.adhesion, n)):.5g}, "
            f"true {pj.PAPER_COEFFICIENTS[n]:.5g}"
        )


if __name__ == "__main__":
    main()
