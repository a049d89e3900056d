"""Cost per right-hand-side evaluation of the τ = 0 DAE (``ConstrainedDAE``; ``DesingularizedDAE``), issue 27 item 2.

Every evaluation of ``ConstrainedDAE.evaluate`` (and ``.velocity``) solves the peeling velocity
v from G(x) = φ(v, V) on its stable branch (``peeljax.branches.branch_velocity``: safeguarded
Newton in log v, warm-started from y[3]). This script times, at 7 states of a V = 1.1, τ = 0
run (``peeljax.simulate(V=1.1, tau=0, t_final=0.5, rtol=1e-6, ts=np.linspace(0, 0.5, 51))``,
the paper's start ``PeelingModel().initial_state(1.1)``, a slip state and states just before
both folds):

* before: the previous root finder (stop when |w_new − w| ≤ 1e-14; ``value_and_grad``; a
  zero residual bisects away from the root), kept verbatim below as ``old_branch_velocity``;
* after: ``peeljax.branches.branch_velocity`` as it is now;
* numba: the same Newton (the new stopping rules) and the paper's φ, G, f written out in
  scalar Python compiled by numba (``@njit``), as a floor for a compiled scalar loop.

Two situations per state: **completed** (y's own solved v is the guess: what ``complete`` and
the first stage of a step see) and **stage** (x advanced by h·f(x, v), h = 1e-4 ≈ the run's mean
step, with the step-start v as the guess: what a Runge–Kutta stage sees). Each time is the
median over ``REPEATS`` runs of ``jax.jit`` of a ``fori_loop`` of ``N`` evaluations (the state's
α perturbed by acc·1e-300 so nothing is hoisted; compile excluded), in µs per evaluation. The
Newton iteration counts (φ evaluations) are printed too, and their mean/max over the stages
x + c·h·f (Tsit5's c) at the 51 output states.

    python benchmarks/studies/evaluation_cost.py           # ~2 min on 2 cores
    python benchmarks/studies/evaluation_cost.py --quick   # fewer evaluations and repeats

Output: a markdown table on stdout and ``benchmarks/studies/results/evaluation_cost[_quick].md``.
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # benchmarks/: machine
from machine import write_result  # noqa: E402
V = 1.1
H_STAGE = 1e-4
TSIT5_C = (0.161, 0.327, 0.9, 0.9800255409045097, 1.0)


# --------------------------------------------------------------------------- the old algorithm
def _old_functions():
    import jax
    import jax.numpy as jnp

    from peeljax.branches import STICK, _bounds, _stop_gradient

    iterations, tolerance = 80, 1e-14

    def old_root_on(model, V, target, lo, hi, guess, count=False):
        log_lo, log_hi = jnp.log(lo), jnp.log(hi)

        def residual(w):
            return model.phi(jnp.exp(w), V) - target

        def body(carry):
            w, a, b, i, _ = carry
            r, slope = jax.value_and_grad(residual)(w)
            a = jnp.where(r < 0, w, a)
            b = jnp.where(r < 0, b, w)
            newton = w - r / jnp.where(slope > 0, slope, 1.0)
            inside = (slope > 0) & (newton > a) & (newton < b)
            w_new = jnp.where(inside, newton, 0.5 * (a + b))
            return w_new, a, b, i + 1, jnp.abs(w_new - w)

        def more(carry):
            return (carry[3] < iterations) & (carry[4] > tolerance)

        w0 = jnp.clip(jnp.log(jnp.clip(guess, lo, hi)), log_lo, log_hi)
        w, _, _, i, _ = jax.lax.while_loop(more, body, (w0, log_lo, log_hi, jnp.asarray(0), jnp.asarray(jnp.inf)))
        return (w, i) if count else w

    def old_branch_velocity(model, x, V, branch, folds, guess=1.0):
        lo, hi = _bounds(folds, branch)
        target = model.shear_force(x)
        sg = _stop_gradient
        w = old_root_on(sg(model), sg(V), sg(target), sg(lo), sg(hi), sg(guess))
        v_star = jnp.exp(w)
        residual = model.phi(v_star, V) - target
        slope = jax.lax.stop_gradient(jax.grad(lambda v: model.phi(v, V))(v_star))
        past_end = sg(target >= model.phi(hi, V))
        below_start = sg(target <= model.phi(lo, V))
        interior = ~past_end & ~below_start & (slope > 0)
        correction = jnp.where(interior, (residual - sg(residual)) / jnp.where(interior, slope, 1.0), 0.0)
        v = jnp.where(past_end, hi, jnp.where(below_start, lo, v_star - correction))
        stuck = (branch == STICK) & (target < folds.phi_zero)
        return jnp.where(stuck, 0.0, v)

    return old_root_on, old_branch_velocity


def old_constrained_dae():
    """``ConstrainedDAE`` with the old ``velocity`` (for the comparison and the tests)."""
    from peeljax.constrained import ConstrainedDAE

    _, old_branch_velocity = _old_functions()

    class OldConstrainedDAE(ConstrainedDAE):
        def velocity(self, y):
            return old_branch_velocity(self.model, y[:3], self.V, self._branch(y), self.folds, guess=y[3])

    return OldConstrainedDAE


def iteration_counters(ode):
    """(old, new): y ↦ number of φ evaluations of the root search that ``velocity(y)`` runs."""
    import jax

    from peeljax.branches import _bounds, _root_on

    old_root_on, _ = _old_functions()
    model, Vj = ode.model, ode.V

    def old(y):
        lo, hi = _bounds(ode.folds, ode._branch(y))
        return old_root_on(model, Vj, model.shear_force(y[:3]), lo, hi, y[3], count=True)[1]

    def new(y):
        lo, hi = _bounds(ode.folds, ode._branch(y))
        target = model.shear_force(y[:3])
        clamped = (target >= model.phi(hi, Vj)) | (target <= model.phi(lo, Vj))
        return _root_on(model, Vj, target, lo, hi, y[3], clamped, count=True)[1]

    return jax.jit(jax.vmap(old)), jax.jit(jax.vmap(new))


# --------------------------------------------------------------------------- numba mirror
def numba_functions(coefficients, R, I, k, l, folds):
    """``velocity(y)`` and ``evaluate(y)`` (ψ, J, F̃·f) of the paper geometry and φ, in numba."""
    from numba import njit

    c = coefficients
    c1, p1, c2, p2, c3, c4 = c["c1"], c["p1"], c["c2"], c["p2"], c["c3"], c["c4"]
    c5, p5, c6, c7, p7, c8, p8, p9 = c["c5"], c["p5"], c["c6"], c["c7"], c["p7"], c["c8"], c["p8"], c["p9"]
    v_max, v_min, phi_zero = float(folds.v_max), float(folds.v_min), float(folds.phi_zero)
    v_low, v_top = float(folds.v_low), float(folds.v_top)
    exist = math.isfinite(v_max) and math.isfinite(v_min)
    split = math.sqrt(v_max * v_min) if exist else math.inf
    iterations, tolerance, predicted_error = 80, 1e-14, 1e-16

    @njit(cache=False, fastmath=False)
    def phi_and_dw(w, Vv):  # φ(eʷ, V) and ∂φ/∂w
        v = math.exp(w)
        a1 = c1 * math.exp(p1 * w)
        a2 = c2 * math.exp(p2 * w)
        a3 = c3 * math.exp(v / c4)
        m = c6 - c7 * Vv**p7 - c8 * Vv**p8
        a9 = m * math.exp(p9 * w)
        return a1 + a2 + a3 - c5 * Vv**p5 - a9, p1 * a1 + p2 * a2 + a3 * v / c4 - p9 * a9

    @njit(cache=False)
    def phi(v, Vv):
        if v <= 0.0:
            return c3 - c5 * Vv**p5 + 0.0
        return phi_and_dw(math.log(v), Vv)[0]

    @njit(cache=False)
    def root(Vv, target, lo, hi, guess):
        log_lo, log_hi = math.log(lo), math.log(hi)
        w = math.log(min(max(guess, lo), hi))
        a, b = log_lo, log_hi
        step_prev = 0.0
        for _ in range(iterations):
            r, slope = phi_and_dw(w, Vv)
            r -= target
            if r < 0:
                a = w
            else:
                b = w
            positive = slope > 0
            step = -r / slope if positive else -r
            newton = w + step
            converged = positive and abs(step) <= tolerance
            inside = positive and a < newton < b
            if converged:
                w_new = min(max(newton, a), b)
            elif inside:
                w_new = newton
            else:
                w_new = 0.5 * (a + b)
            size = abs(step)
            done = converged or (inside and size**3 <= predicted_error * step_prev**2) or abs(w_new - w) <= tolerance
            step_prev = size if inside else 0.0
            w = w_new
            if done:
                break
        return w

    @njit(cache=False)
    def velocity(y):
        G = (1.0 + math.sin(y[0])) * (k / l) * y[2]
        slip = exist and y[3] > split
        if slip:
            lo, hi = v_min, v_top
        else:
            lo, hi = v_low, (v_max if exist else v_top)
        if not slip and G < phi_zero:
            return 0.0
        if G >= phi(hi, V):
            return hi
        if G <= phi(lo, V):
            return lo
        return math.exp(root(V, G, lo, hi, y[3]))

    @njit(cache=False)
    def evaluate(y):
        v = velocity(y)
        alpha, omega, u = y[0], y[1], y[2]
        s, co = math.sin(alpha), math.cos(alpha)
        F = (k / l) * u
        slip = omega - v / R
        f0, f1, f2 = slip, -R * s * F / I, R * s * slip + V - v
        phi_v = phi_and_dw(math.log(v), V)[1] / v if v > 0 else 0.0
        drive = co * F * f0 + (1.0 + s) * (k / l) * f2
        return f0, f1, f2, -phi_v, drive

    @njit(cache=False)
    def run_velocity(y0, n):
        y = y0.copy()
        acc = 0.0
        for _ in range(n):
            y[0] = y0[0] + acc * 1e-300
            acc += velocity(y)
        return acc

    @njit(cache=False)
    def run_evaluate(y0, n):
        y = y0.copy()
        acc = 0.0
        for _ in range(n):
            y[0] = y0[0] + acc * 1e-300
            f0, f1, f2, J, drive = evaluate(y)
            acc += f0 + f1 + f2
        return acc

    return velocity, run_velocity, run_evaluate


# --------------------------------------------------------------------------- timing
def jax_timer(fn, n, repeats):
    import jax
    import jax.numpy as jnp

    @jax.jit
    def run(y):
        def body(_, acc):
            out = fn(y.at[0].add(acc * 1e-300))
            return acc + jnp.sum(out)

        return jax.lax.fori_loop(0, n, body, jnp.zeros(()))

    def time_at(y):
        y = jnp.asarray(y)
        run(y).block_until_ready()  # compile (once per fn) and warm
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            run(y).block_until_ready()
            times.append(time.perf_counter() - start)
        return float(np.median(times)) / n * 1e6

    return time_at


def numba_timer(run, n, repeats):
    def time_at(y):
        y = np.asarray(y, float)
        run(y, 10)
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            run(y, n)
            times.append(time.perf_counter() - start)
        return float(np.median(times)) / n * 1e6

    return time_at


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer evaluations and repeats")
    args = parser.parse_args(argv)
    n, repeats = (20_000, 3) if args.quick else (100_000, 7)

    import jax
    import jax.numpy as jnp

    import peeljax
    from peeljax.constrained import ConstrainedDAE
    from peeljax.model import PeelingModel

    model = PeelingModel()
    ode_new = ConstrainedDAE(model, V).with_folds()
    ode_old = old_constrained_dae()(model, V).with_folds()
    folds = ode_new.folds

    # ---- states
    sol = peeljax.simulate(V=V, tau=0, t_final=0.5, rtol=1e-6, ts=np.linspace(0, 0.5, 51))
    ys = np.asarray(sol.ys)
    jump_t = np.asarray(sol.jumps.t)[: int(sol.jumps.count)]
    t_up, t_down = float(jump_t[0]), float(jump_t[1])  # the first slip phase
    near = np.array([t_up - 1e-3, t_up - 1e-7, 0.5 * (t_up + t_down), t_down - 1e-7])
    sol2 = peeljax.simulate(V=V, tau=0, t_final=float(near[-1]), rtol=1e-6, ts=near)
    ys2 = np.asarray(sol2.ys)
    states = [
        ("paper's start", 0.0, np.asarray(model.initial_state(V))),
        ("stick, t = 0.1", 0.1, ys[10]),
        ("stick, t = 0.3", 0.3, ys[30]),
        ("stick, 1e-3 before the fold", near[0], ys2[0]),
        ("stick, 1e-7 before the fold", near[1], ys2[1]),
        ("slip, mid-phase", near[2], ys2[2]),
        ("slip, 1e-7 before the fold", near[3], ys2[3]),
    ]

    def stage(y, c=1.0):
        y = jnp.asarray(y)
        f = model.f(y[:3], y[3], V)
        return np.asarray(y.at[:3].add(c * H_STAGE * f))

    situations = {"completed": [y for *_, y in states], "stage": [stage(y) for *_, y in states]}

    # ---- iteration counts
    old_count, new_count = iteration_counters(ode_new)
    counts = {
        name: (np.asarray(old_count(jnp.asarray(np.stack(ys_)))), np.asarray(new_count(jnp.asarray(np.stack(ys_)))))
        for name, ys_ in situations.items()
    }
    run_stages = jnp.asarray(np.stack([stage(y, c) for y in ys for c in TSIT5_C]))
    run_old, run_new = np.asarray(old_count(run_stages)), np.asarray(new_count(run_stages))

    # ---- agreement of the roots (old vs new), in log v
    vel_old, vel_new = jax.jit(jax.vmap(ode_old.velocity)), jax.jit(jax.vmap(ode_new.velocity))
    every = jnp.asarray(np.concatenate([np.stack(v) for v in situations.values()] + [np.asarray(run_stages)]))
    a, b = np.asarray(vel_old(every)), np.asarray(vel_new(every))
    both = (a > 0) & (b > 0)
    worst = float(np.max(np.abs(np.log(a[both]) - np.log(b[both])))) if both.any() else 0.0
    zero_mismatch = int(np.sum((a > 0) != (b > 0)))

    # ---- numba
    import numba

    velocity_nb, run_velocity_nb, run_evaluate_nb = numba_functions(
        model.adhesion.coefficients(), float(model.R), float(model.I), float(model.k), float(model.l), folds
    )
    nb_check = np.array([velocity_nb(np.asarray(y, float)) for y in np.asarray(every)])
    nb_worst = float(np.max(np.abs(nb_check - b) / np.maximum(np.abs(b), 1e-300)))

    # ---- timings
    timers = {
        ("evaluate", "old"): jax_timer(lambda y: ode_old.evaluate(y).psi, n, repeats),
        ("evaluate", "new"): jax_timer(lambda y: ode_new.evaluate(y).psi, n, repeats),
        ("evaluate", "numba"): numba_timer(run_evaluate_nb, n, repeats),
        ("velocity", "old"): jax_timer(ode_old.velocity, n, repeats),
        ("velocity", "new"): jax_timer(ode_new.velocity, n, repeats),
        ("velocity", "numba"): numba_timer(run_velocity_nb, n, repeats),
    }
    # the DAE in pseudo-time (the default formulation at τ = 0): nothing is solved per evaluation
    ode_pseudo = ode_new.in_pseudo_time(peeljax.desingularized.DEFAULT_TIME_SCALE)
    pseudo_timer = jax_timer(lambda z: ode_pseudo.evaluate(z).psi, n, repeats)
    pseudo = [pseudo_timer(np.append(y, t)) for _, t, y in states]
    results = {}
    for situation, ys_ in situations.items():
        for index, y in enumerate(ys_):
            for key, timer in timers.items():
                results[situation, index, key] = timer(y)

    # ---- table
    lines = [
        "# Cost per evaluation of ConstrainedDAE (τ = 0, V = 1.1)",
        "",
        f"On {platform.processor() or platform.machine()}, {platform.system()}, "
        f"jax {jax.__version__}, numba {numba.__version__}, Python {platform.python_version()}; "
        f"median of {repeats} runs of {n} evaluations in a jitted `fori_loop`, compile excluded.",
        "",
        "µs per evaluation; *old* = the previous root finder (copied into the script), *new* = "
        "`peeljax.branches` now, *numba* = the same Newton, φ, G and f compiled by numba; "
        "old/new = speed-up. *it.* = φ evaluations of the root search (old → new). "
        "*completed*: y's own v is the guess; *stage*: x + h·f(x, v), h = 1e-4, guess = the step-start v.",
        "",
    ]
    for situation in situations:
        lines += [
            f"## {situation}",
            "",
            "| state | t | v | it. old → new | evaluate old | new | numba | old/new | new/numba "
            "| velocity old | new | numba | old/new | new/numba |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for index, (label, t, y) in enumerate(states):
            v = float(y[3])
            o, w_ = counts[situation][0][index], counts[situation][1][index]
            row = [label, f"{t:.6g}", f"{v:.4g}", f"{o} → {w_}"]
            for fn in ("evaluate", "velocity"):
                old, new, nb = (results[situation, index, (fn, k)] for k in ("old", "new", "numba"))
                row += [f"{old:.3f}", f"{new:.3f}", f"{nb:.3f}", f"{old / new:.1f}×", f"{new / nb:.1f}×"]
            lines.append("| " + " | ".join(row) + " |")
        lines.append("")
    lines += [
        f"Iterations over the stages x + c·h·f (Tsit5's c, h = 1e-4) at the 51 output states "
        f"({run_stages.shape[0]} solves): old mean {run_old.mean():.2f}, max {run_old.max()}; "
        f"new mean {run_new.mean():.2f}, max {run_new.max()}.",
        "",
        f"Roots, old vs new, at all {every.shape[0]} states above: max |Δ log v| = {worst:.2e}; "
        f"v = 0 (stuck) in one but not the other: {zero_mismatch}. numba vs new: max relative "
        f"difference in v {nb_worst:.2e}.",
        "",
        "## The DAE in pseudo-time (`DesingularizedDAE.evaluate`, the default formulation at τ = 0)",
        "",
        "u from the constraint in closed form, no root of φ: µs per evaluation at the same (completed) "
        "states, and its ratio to `ConstrainedDAE.evaluate` (*new*) there.",
        "",
        "| state | pseudo-time | new / pseudo-time |",
        "|---|---|---|",
        *(
            f"| {label} | {p:.3f} | {results['completed', i, ('evaluate', 'new')] / p:.1f}× |"
            for i, ((label, _, _), p) in enumerate(zip(states, pseudo))
        ),
        "",
    ]
    text = "\n".join(lines)
    print(text)
    out = HERE / "results" / ("evaluation_cost_quick.md" if args.quick else "evaluation_cost.md")
    write_result(out, text)
    print(f"written to {out.relative_to(HERE.parent)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
