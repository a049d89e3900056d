"""The peer of the table fit (issue 28, item 5): ``scipy.optimize.least_squares`` with
finite-difference Jacobians on the same residuals and runs — what a user does without peeljax.

Both minimise the same χ²(θ) = ‖r(θ)‖² of one hidden-truth stick-slip table
(``fit_acceptance.run_table``'s recipe on fewer V: φ with c1 × 1.12, c3 × 1.06, c6 × 1.10,
V = 1.0, 1.5, 2.2, 3.0 m/s, [0.5, 1.5] s, 1 % noise) from the paper's φ, θ = log(c/c_paper):

* peeljax: :func:`peeljax.fit.fit_stick_slip` (its Levenberg–Marquardt with forward-mode
  Jacobians through the jumps; ``n_coarse=1``: from the paper's φ, no coarse batch);
* scipy: ``least_squares(method="trf", jac="2-point")`` (also ``"lm"``) on r(θ) evaluated by
  the same compiled runs (:class:`peeljax.fit.table.TableFit`, ``jax.jit``-compiled once,
  outside the timing), stopped at ``xtol = ftol = gtol = 1e-10``.

Timed after compilation (the compiled programs are reused, the first call is left out),
``--repeats`` times; prints the medians, the ratio, each method's χ², model evaluations and its
distance to peeljax's optimum in standard errors ("the same optimum": within 0.1 SE).

    python benchmarks/fit_peer_scipy.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import time

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import scipy.optimize

import peeljax as pj
from peeljax.fit import fit_stick_slip
from peeljax.fit.plots import synthetic_table
from peeljax.fit.table import _table_arrays, build_table_fit, table_tolerances

MULTIPLIERS = {"c1": 1.12, "c3": 1.06, "c6": 1.10}
V = (1.0, 1.5, 2.2, 3.0)
WINDOW = {"transient": 0.5, "window": 1.0}  # fit_stick_slip's defaults


@eqx.filter_jit
def _residuals(fit, theta):
    return fit.residuals(theta)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    c = pj.AdhesionLaw().coefficients()
    truth = pj.AdhesionLaw(**{**c, **{n: c[n] * m for n, m in MULTIPLIERS.items()}})
    names = tuple(MULTIPLIERS)
    rtol, atol = table_tolerances(0.0)
    table = synthetic_table(truth, np.asarray(V), noise=0.01, seed=1, rtol=rtol, atol=atol, **WINDOW)
    options = {"free": names, "n_coarse": 1, "n_starts": 1, "max_iterations": 50, **WINDOW}

    began = time.perf_counter()
    result = fit_stick_slip(table, **options)
    compile_peeljax = time.perf_counter() - began
    data, sigma, measured, _ = _table_arrays(table, table.statistics)
    fit = build_table_fit(
        pj.AdhesionLaw(), pj.PeelingModel(), table.V, data, sigma, measured, names=names, tau=0.0, n_samples=401,
        rtol=rtol, atol=atol, max_jumps=4096, max_steps=400_000, **WINDOW,
    )  # fmt: skip
    evaluations = [0]

    def residuals(z):
        evaluations[0] += 1
        return np.asarray(_residuals(fit, {n: jnp.asarray(z[k]) for k, n in enumerate(names)}))

    began = time.perf_counter()
    residuals(np.zeros(len(names)))
    compile_scipy = time.perf_counter() - began

    timings = {"peeljax (LM, forward-mode Jacobian)": [], "scipy least_squares trf, 2-point": [],
               "scipy least_squares lm, 2-point": []}  # fmt: skip
    ends = {}
    for _ in range(args.repeats):
        began = time.perf_counter()
        result = fit_stick_slip(table, **options)
        timings["peeljax (LM, forward-mode Jacobian)"].append(time.perf_counter() - began)
        ends["peeljax (LM, forward-mode Jacobian)"] = (
            np.log([result.uncertainty.values[k] / c[n] for k, n in enumerate(names)]), result.chi2, result.steps
        )
        for method in ("trf", "lm"):
            key = f"scipy least_squares {method}, 2-point"
            evaluations[0] = 0
            began = time.perf_counter()
            sol = scipy.optimize.least_squares(
                residuals, np.zeros(len(names)), jac="2-point", method=method, xtol=1e-10, ftol=1e-10, gtol=1e-10
            )
            timings[key].append(time.perf_counter() - began)
            ends[key] = (sol.x, float(sol.fun @ sol.fun), evaluations[0])
    se_log = np.sqrt(np.diag(result.uncertainty.covariance_log))
    best = ends["peeljax (LM, forward-mode Jacobian)"][0]
    reference = np.median(timings["peeljax (LM, forward-mode Jacobian)"])
    print(f"table: V = {list(V)}, {len(result.residuals)} residuals, free {list(names)}; compilation: peeljax fit "
          f"{compile_peeljax:.1f} s (first call), scipy's residual program {compile_scipy:.1f} s; {args.repeats} repeats\n")  # fmt: skip
    print("| method | median [s] | / peeljax | chi2 | model evaluations | distance to peeljax's optimum [SE] |")
    print("|---|---:|---:|---:|---:|---:|")
    for key, times in timings.items():
        z, chi2, n_eval = ends[key]
        distance = float(np.max(np.abs(z - best) / se_log))
        print(f"| {key} | {np.median(times):.2f} | {np.median(times) / reference:.1f}x | {chi2:.4g} | {n_eval} | "
              f"{distance:.3g} |")  # fmt: skip
    print("\n(peeljax's model evaluations: Levenberg–Marquardt iterations, each runs the rows with one tangent per "
          "coefficient; scipy's: residual calls, each runs the rows once.)")


if __name__ == "__main__":
    main()
