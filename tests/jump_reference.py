"""Independent NumPy/SciPy reference for the peeling DAE carried through the folds of φ by jumps.

This is the ground truth the tests compare ``fold="jump"`` runs with; it imports nothing from
peeljax. It implements the τ = 0 "DAE algorithm with jumps" in the paper geometry
(F = (k/l)·u; R = 0.1 m, I = 1e-2 kg·m², k/l = 1000 N/m), x = (α, ω, u), pull velocity V:

    α̇ = ω − v/R,    ω̇ = −R·sinα·F/I,    u̇ = R·sinα·(ω − v/R) + V − v,
    G(x) = (1 + sinα)·F(u) = φ(v, V).

φ(·, V) rises to a maximum at v̂, falls to a minimum at v_min and rises again. Between jumps the
index-1 DAE x' = f(x, v(x)) is integrated with ``solve_ivp``, v(x) being the root of
φ(v, V) = G(x) on the current increasing branch of φ: the stick branch (0, v̂] or the slip branch
[v_min, ∞). Past a branch's end v is clamped to it (v = v̂ or v_min: continuous right-hand side;
v = 0 on the stick branch below φ(0⁺, V): the tape is fully stuck). Terminal events end a
segment at a fold, G(x) = φ(v̂, V) crossed upward on the stick branch (stick → slip) or
G(x) = φ(v_min, V) crossed downward on the slip branch (slip → stick); there x is kept and v
jumps to the root of φ(v, V) = G(x) on the other branch, and the integration restarts.
The last stretch before each fold is integrated again in a form that is regular at the fold,
which locates the jumps to ~1e-8 s where the event alone is off by up to ~5e-7 s (see
:func:`reference_jump_run`). Without a fold (V above ≈ 5.3 m/s) φ(·, V) increases on (0, ∞)
and there are no jumps.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

__all__ = [
    "K_OVER_L",
    "PAPER",
    "I",
    "R",
    "fold_velocities",
    "initial_state",
    "phi",
    "reference_jump_run",
    "repeat_time",
]

PAPER: dict[str, float] = {  # the paper's coefficients of φ
    "c1": 400.0, "p1": 0.35, "c2": 110.0, "p2": 0.15, "c3": 130.0, "c4": 11.0, "c5": 2.0, "p5": 1.5,
    "c6": 415.0, "c7": 45.0, "p7": 0.4, "c8": 0.35, "p8": 2.15, "p9": 0.5,
}  # fmt: skip
R = 0.1  # spool radius [m]
I = 1e-2  # spool moment of inertia [kg·m²]
K_OVER_L = 1000.0  # tape stiffness over length k/l [N/m]
FOLD_MARGIN = 0.05  # the approach to a fold is integrated again from |v − v_fold| = FOLD_MARGIN·v_fold
FOLD_STOP = 1e-4  # ... up to FOLD_STOP of that distance from v_fold, then extrapolated linearly


def phi(v, V, coefficients=PAPER):
    """φ(v, V) = c1·v^p1 + c2·v^p2 + c3·exp(v/c4) − c5·V^p5 − (c6 − c7·V^p7 − c8·V^p8)·v^p9.

    Every power of v is 0 at v ≤ 0 (its limit from the right).
    """
    c = coefficients
    v = np.asarray(v, dtype=float)
    V = np.asarray(V, dtype=float)
    vp = np.where(v > 0, v, 1.0)

    def power(p):
        return np.where(v > 0, vp**p, 0.0)

    return (
        c["c1"] * power(c["p1"])
        + c["c2"] * power(c["p2"])
        + c["c3"] * np.exp(v / c["c4"])
        - c["c5"] * V ** c["p5"]
        - (c["c6"] - c["c7"] * V ** c["p7"] - c["c8"] * V ** c["p8"]) * power(c["p9"])
    )


def _scalar_law(V):
    """(φ(·, V), ∂φ/∂v(·, V)) as fast scalar functions of v > 0 (paper coefficients)."""
    c = PAPER
    offset = c["c5"] * V ** c["p5"]
    c9 = c["c6"] - c["c7"] * V ** c["p7"] - c["c8"] * V ** c["p8"]
    c1, p1, c2, p2, c3, c4, p9 = c["c1"], c["p1"], c["c2"], c["p2"], c["c3"], c["c4"], c["p9"]

    def value(v):
        if v <= 0.0:
            return c3 - offset
        return c1 * v**p1 + c2 * v**p2 + c3 * math.exp(v / c4) - offset - c9 * v**p9

    def slope(v):
        return c1 * p1 * v ** (p1 - 1) + c2 * p2 * v ** (p2 - 1) + c3 / c4 * math.exp(v / c4) - c9 * p9 * v ** (p9 - 1)

    return value, slope


def fold_velocities(V):
    """(v̂, v_min): the velocities of φ(·, V)'s maximum and minimum; (nan, nan) without a fold.

    ∂φ/∂v → +∞ as v → 0⁺ and is positive for large v (the exp term); its sign changes are
    bracketed on a logarithmic grid over [1e-12, 1e3] m/s and refined with ``brentq``.
    """
    _, slope = _scalar_law(float(V))
    grid = np.logspace(-12, 3, 3001)
    signs = np.sign([slope(v) for v in grid])
    falls = np.flatnonzero((signs[:-1] > 0) & (signs[1:] < 0))
    if falls.size == 0:
        return math.nan, math.nan
    rises = np.flatnonzero((signs[:-1] < 0) & (signs[1:] > 0))
    rise = rises[rises > falls[0]][0]
    v_hat = brentq(slope, grid[falls[0]], grid[falls[0] + 1], xtol=1e-15, rtol=1e-15)
    v_min = brentq(slope, grid[rise], grid[rise + 1], xtol=1e-15, rtol=1e-15)
    return v_hat, v_min


def initial_state(V):
    """The paper's consistent initial data y0 = (α0, ω0, u0, v0): v0 = 1e-10·V, ω0 = v0/R,
    α0 = (π/4)·1e-8, u0 from (1 + sinα0)·(k/l)·u0 = φ(v0, V)."""
    v0 = 1e-10 * V
    alpha0 = 0.25 * math.pi * 1e-8
    u0 = float(phi(v0, V)) / ((1.0 + math.sin(alpha0)) * K_OVER_L)
    return np.array([alpha0, v0 / R, u0, v0])


def _shear_force(x):
    """G(x) = (1 + sinα)·(k/l)·u."""
    return (1.0 + math.sin(x[0])) * K_OVER_L * x[2]


class _Branch:
    """An increasing branch [lo, hi] of φ(·, V) and the root v(G) of φ(v, V) = G on it.

    The root is found by Newton's method in z = log v, warm-started at the previous root and
    kept inside a bracket that every residual evaluation shrinks (bisection in z when a Newton
    step leaves it).
    """

    def __init__(self, law, lo, hi):
        self.value, self.slope = law
        self.lo, self.hi = lo, hi
        self.phi_lo = self.value(lo)
        self.phi_hi = self.value(hi) if math.isfinite(hi) else math.inf
        self.guess = 0.0  # log v of the previous root; v = 1 m/s before the first

    def velocity(self, G):
        """The root on the branch, clamped to its ends (v = 0: fully stuck)."""
        if G <= self.phi_lo:
            return self.lo
        if G >= self.phi_hi:
            return self.hi
        # φ(1e-300) rounds to φ(0⁺) < G, so a zero lower end is bracketed by 1e-300.
        z_lo = math.log(self.lo if self.lo > 0 else 1e-300)
        if math.isfinite(self.hi):
            z_hi = math.log(self.hi)
        else:
            v = max(2.0 * self.lo, 1.0)
            while self.value(v) < G:
                v *= 2.0
            z_hi = math.log(v)
        z = min(max(self.guess, z_lo), z_hi)
        for _ in range(200):
            v = math.exp(z)
            residual = self.value(v) - G
            if residual < 0:
                z_lo = z
            elif residual > 0:
                z_hi = z
            else:
                break
            dz = v * self.slope(v)  # dφ/dz
            z_new = z - residual / dz if dz > 0 else math.nan
            if not z_lo < z_new < z_hi:
                z_new = 0.5 * (z_lo + z_hi)
            converged = abs(z_new - z) <= 1e-12
            z = z_new
            if converged:
                break
        else:
            raise RuntimeError(f"no root of phi(v) = {G!r} on [{self.lo!r}, {self.hi!r}] after 200 iterations")
        self.guess = z
        return math.exp(z)


def reference_jump_run(V, t_final=3.0, *, y0=None, rtol=1e-10, atol=1e-12, method="LSODA", ts=None):
    """Integrate from t = 0 to ``t_final`` with jumps at the folds of φ (see the module docstring).

    Crossing a fold in time is ill-conditioned: v(x) has a square-root singularity there
    (|v − v_fold| ∝ √|G − φ(v_fold)|), which spoils error control and dense output, and at the
    stick → slip folds G reaches φ(v̂) tangentially (Ġ → 0: v follows the quasi-static
    Ġ(x, v) ≈ 0 into the fold), so a state error δG moves the event by ~√δG; the event times
    alone are off by up to ~5e-7 s, depending on the method. So once a segment's fold event is
    found, its last stretch, from the last solver step with |v − v_fold| ≥ ``FOLD_MARGIN``·v_fold,
    is integrated again as the index-reduced system in (x, v, t) with the arclength σ of the
    (t, v) plane as the independent variable,

        d(x, v, t)/dσ = (f(x, v)·φ_v, Ġ(x, v), φ_v)/√(φ_v² + Ġ²),    φ_v = ∂φ/∂v(v, V),

    (Ġ = dG/dt along f(x, v)), regular where φ_v = 0 (the fold) or Ġ = 0 (G pausing below it),
    up to ``FOLD_STOP`` of the distance to v_fold (at the fold both vanish), and extrapolated
    linearly in v from there to v_fold: the jump time and state. ``RuntimeError`` if the fold
    is not reached.

    At the defaults (LSODA, rtol 1e-10) all jump times over [0, 3] s agree with Radau at rtol
    1e-11…1e-12 to 3e-9 s (V = 1.1), 8e-9 s (V = 2) and 1.4e-8 s (V = 4); at rtol 1e-8 LSODA is off
    by up to 8e-7 s.

    Args:
        V: pull velocity [m/s].
        t_final: end time [s].
        y0: initial (α, ω, u, v); x must satisfy the constraint, v only picks the branch
            (stick if v ≤ v̂, else slip). Default: :func:`initial_state`.
        rtol, atol, method: passed to ``solve_ivp`` for every integration.
        ts: optional increasing output times in [0, t_final]; a time equal to a jump time gets
            the state before the jump.

    Returns:
        dict with ``jump_t``, ``jump_up`` (True: stick → slip), ``jump_v_before`` (the fold
        velocity), ``jump_v_after``, ``jump_G`` (G(x) at the jump) as NumPy arrays, ``t_end``,
        and, with ``ts``, ``ys`` of shape (len(ts), 4) holding (α, ω, u, v).
    """
    V = float(V)
    law = _scalar_law(V)
    slope = law[1]
    v_hat, v_min = fold_velocities(V)
    y0 = initial_state(V) if y0 is None else np.asarray(y0, dtype=float)
    if math.isnan(v_hat):
        branches = {"stick": _Branch(law, 0.0, math.inf)}
        branch = "stick"
    else:
        branches = {"stick": _Branch(law, 0.0, v_hat), "slip": _Branch(law, v_min, math.inf)}
        branch = "stick" if y0[3] <= v_hat else "slip"
    want_ys = ts is not None
    options = {"method": method, "rtol": rtol, "atol": atol, "dense_output": want_ys}

    def f(x, v):
        slip = x[1] - v / R
        s = math.sin(x[0])
        return np.array([slip, -R * s * K_OVER_L * x[2] / I, R * s * slip + V - v])

    def g_dot(x, v):
        """Ġ = ∂G/∂α·α̇ + ∂G/∂u·u̇ along f(x, v)."""
        dx = f(x, v)
        return K_OVER_L * (math.cos(x[0]) * x[2] * dx[0] + (1.0 + math.sin(x[0])) * dx[2])

    def rhs(_, x, current):
        return f(x, current.velocity(_shear_force(x)))

    def fold_rhs(_, z, *_args):
        """d(x, v, t)/dσ, σ the arclength in the (t, v) plane."""
        x, v = z[:3], z[3]
        phi_v, g = slope(v), g_dot(x, v)
        norm = math.hypot(phi_v, g)
        return np.append(f(x, v) * (phi_v / norm), [g / norm, phi_v / norm])

    def stop_reached(_, z, v_stop, toward):
        return (z[3] - v_stop) * toward

    def stick_to_slip(_, x, current):
        return _shear_force(x) - current.phi_hi

    def slip_to_stick(_, x, current):
        return _shear_force(x) - current.phi_lo

    stick_to_slip.terminal, stick_to_slip.direction = True, 1.0
    slip_to_stick.terminal, slip_to_stick.direction = True, -1.0
    stop_reached.terminal, stop_reached.direction = True, 1.0

    ts = np.asarray([] if ts is None else ts, dtype=float)
    out_y = []  # (α, ω, u, v) at ts[:len(out_y)]
    # the outputs' own root finders: the warm starts of ``branches`` stay as without outputs
    probes = {name: _Branch(law, b.lo, b.hi) for name, b in branches.items()}

    def output(until, state_at):
        """Append state_at(t) for the output times up to ``until``."""
        while len(out_y) < ts.size and ts[len(out_y)] <= until:
            out_y.append(state_at(ts[len(out_y)]))

    jumps = []
    t, x = 0.0, y0[:3].copy()
    while t < t_final:
        current = branches[branch]
        if len(branches) == 1:
            events = None
        else:
            events = stick_to_slip if branch == "stick" else slip_to_stick
        sol = solve_ivp(rhs, (t, t_final), x, events=events, args=(current,), **options)
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed at t = {sol.t[-1]:.9g} s: {sol.message}")

        def on_branch(tk, sol=sol, probe=probes[branch]):
            xk = sol.sol(tk)
            return [*xk, probe.velocity(_shear_force(xk))]

        if sol.status != 1:
            output(t_final, on_branch)
            t = t_final
            break
        fold = current.hi if branch == "stick" else current.lo
        k = sol.t.size - 2  # sol.t[:-1]: the solver's steps; the last one crosses the fold
        while k > 0 and abs(current.velocity(_shear_force(sol.y[:, k])) - fold) < FOLD_MARGIN * fold:
            k -= 1
        t_b, x_b = sol.t[k], sol.y[:, k]
        v_b = current.velocity(_shear_force(x_b))
        v_stop = fold - FOLD_STOP * (fold - v_b)
        sigma_max = 10.0 * (sol.t[-1] - t_b + abs(fold - v_b))  # σ: Δt plus the variation of v, or less
        approach = solve_ivp(
            fold_rhs, (0.0, sigma_max), np.append(x_b, [v_b, t_b]), events=stop_reached,
            args=(v_stop, math.copysign(1.0, fold - v_b)), **options,
        )  # fmt: skip
        if approach.status != 1:
            raise RuntimeError(
                f"the fold v = {fold:.6g} m/s was not reached after t = {t_b:.9g} s ({approach.message})"
            )
        z_stop = approach.y_events[0][0]
        dz = fold_rhs(0.0, z_stop)
        z_jump = z_stop + (fold - z_stop[3]) / dz[3] * dz
        t_jump = z_jump[4]

        def near_fold(tk, approach=approach, z_stop=z_stop, z_jump=z_jump):
            if tk <= z_stop[4]:
                sigma = brentq(
                    lambda s: approach.sol(s)[4] - tk, 0.0, approach.t[-1], xtol=1e-15, rtol=4 * np.finfo(float).eps
                )
                return approach.sol(sigma)[:4]
            return z_stop[:4] + (tk - z_stop[4]) / (z_jump[4] - z_stop[4]) * (z_jump[:4] - z_stop[:4])

        output(t_b, on_branch)
        output(min(t_jump, t_final), near_fold)
        if t_jump > t_final:  # the refined jump time lies past the end
            t = t_final
            break
        t, x = t_jump, z_jump[:3]
        G = _shear_force(x)
        other = "slip" if branch == "stick" else "stick"
        jumps.append((t, branch == "stick", fold, branches[other].velocity(G), G))
        branch = other

    table = np.array(jumps, dtype=float).reshape(-1, 5)
    result = {
        "jump_t": table[:, 0],
        "jump_up": table[:, 1].astype(bool),
        "jump_v_before": table[:, 2],
        "jump_v_after": table[:, 3],
        "jump_G": table[:, 4],
        "t_end": t,
    }
    if want_ys:
        result["ys"] = np.array(out_y, dtype=float).reshape(-1, 4)
    return result


def repeat_time(jump_t, jump_up, transient, *, tol=1e-4):
    """(T, m): the repeat time of the stick → slip events after ``transient`` seconds, and their
    number m per repeat.

    With s_k the stick → slip times after the transient, m is the least count for which
    s_{k+m} − s_k is the same for every k, up to a spread below ``tol`` seconds, and T is their
    mean over whole repeats, (s_{j·m} − s_0)/j for the largest such j. The pattern settles
    slowly (the spread is still ~1e-5 s after 2 s at V = 1.1…4), so ``tol`` must cover what is
    left of the transient; counts that are not a repeat have spreads of a stick–slip interval
    (≳ 1e-2 s). Raises ``ValueError`` when no count up to half the events fits.
    """
    s = np.asarray(jump_t)[np.asarray(jump_up, dtype=bool)]
    s = s[s > transient]
    for m in range(1, s.size // 2 + 1):
        spans = s[m:] - s[:-m]
        if spans.max() - spans.min() < tol:
            j = (s.size - 1) // m
            return (s[j * m] - s[0]) / j, m
    raise ValueError(f"no repeat among the {s.size} stick → slip events after t = {transient} s (tol = {tol} s)")
