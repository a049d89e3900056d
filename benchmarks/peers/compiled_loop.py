"""The α-method of ``peeljax.integrators.alpha`` as a compiled scalar loop (numba), paper geometry.

This is the *practical limit* that ``benchmarks/studies/step_cost.py`` compares peeljax against: the
same algorithm, step for step, written as plain scalar code that LLVM compiles into one loop.

Same algorithm as ``AlphaMethod`` (defaults ρ = 0, rtol = 1e-10, atol = 1e-12, 25 Newton
iterations, 4 subdivision levels):

* ψ(y) = (f, −F̃·f / J_t) with the exact Schur complement
  J_t = −φ_v + τ·F̃·(𝐈 − τ·f_x)⁻¹·f_v (paper geometry: F = (k/l)·u, lever sinα);
* Newton on z = (α, ω, u, log v) for y − known − b·h·ψ(y) = 0 with the exact 4×4 Jacobian
  (hand-derived derivatives, checked against ``jax.jacfwd`` by :func:`check_jacobian`);
  convergence when max_i |δz_i|/w_i ≤ 1, w = (atol + rtol·|z_{0..2}|, rtol) at the new iterate;
  start guess z_n; Gaussian elimination with the same pairwise partial pivoting as
  peeljax's small dense solve;
* a_{n+1} = (ψ_{n+1} − ψ_n)/(γh) + (1 − 1/γ)·a_n, a_0 = ψ'(y_0)·ψ(y_0);
* a failed Newton solve is retried on 2, 4, …, 16 substeps (counted), and the statuses
  (NEWTON_FAILED / NONFINITE / IMPASSE) are those of ``peeljax.StopReason``.

Derivatives (x = (α, ω, u), s = ω − v/R, K = k/l):

    f   = (s, −R·K·u·sinα/I, R·sinα·s + V − v)
    f_x = [[0, 1, 0], [−R·K·u·cosα/I, 0, −R·K·sinα/I], [R·cosα·s, R·sinα, 0]]
    f_v = (−1/R, 0, −sinα − 1)
    F̃   = (K·u·cosα, 0, K·(1 + sinα))
    ∂J_t/∂y_k = −φ_vv·δ_k3 + τ·(∂F̃/∂y_k)·w + τ·λ·(∂f_v/∂y_k + τ·(∂f_x/∂y_k)·w),
        w = (𝐈 − τf_x)⁻¹f_v,  λ = (𝐈 − τf_x)⁻ᵀF̃
    ∂ψ_4/∂y_k = −∂(F̃·f)/∂y_k / J_t + (F̃·f)·∂J_t/∂y_k / J_t²

The same loop with error control (``integrate_adaptive``), which only the retired studies ran, is
at commit ``80fb824`` (``benchmarks/studies/README.md``).

Run ``python benchmarks/peers/compiled_loop.py`` to check the Jacobian against autodiff and the
loop against ``peeljax.simulate``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# StopReason codes (peeljax.solution.StopReason)
NEWTON_FAILED, IMPASSE, NONFINITE = 1, 2, 3

# Layout of the parameter vector: R, I, K = k/l, V, tau, c1, p1, c2, p2, c3, c4, C6, p9


def parameters(V=1.1, tau=0.01, R=0.1, I=1e-2, k=1000.0, l=1.0, adhesion=None):
    """The parameter vector of the compiled loop (paper geometry, the paper's φ family)."""
    c = {"c1": 400.0, "p1": 0.35, "c2": 110.0, "p2": 0.15, "c3": 130.0, "c4": 11.0, "c5": 2.0, "p5": 1.5,
         "c6": 415.0, "c7": 45.0, "p7": 0.4, "c8": 0.35, "p8": 2.15, "p9": 0.5}  # fmt: skip
    if adhesion is not None:
        c.update(adhesion)
    C6 = c["c6"] - c["c7"] * V ** c["p7"] - c["c8"] * V ** c["p8"]  # the V-dependent factor of v^p9
    return np.array(
        [R, I, k / l, V, tau, c["c1"], c["p1"], c["c2"], c["p2"], c["c3"], c["c4"], C6, c["p9"]], dtype=np.float64
    )


def initial_state(p):
    """The paper's consistent start: v0 = 1e-10·V, ω0 = v0/R, α0 = (π/4)·1e-8, u0 from (sac)."""
    R, K, V = p[0], p[2], p[3]
    c1, p1, c2, p2, c3, c4, C6, p9 = p[5], p[6], p[7], p[8], p[9], p[10], p[11], p[12]
    c5, p5 = 2.0, 1.5
    v0 = 1e-10 * V
    alpha0 = 0.25 * math.pi * 1e-8
    phi = c1 * v0**p1 + c2 * v0**p2 + c3 * math.exp(v0 / c4) - c5 * V**p5 - C6 * v0**p9
    u0 = phi / (1.0 + math.sin(alpha0)) / K
    return np.array([alpha0, v0 / R, u0, v0])


# --------------------------------------------------------------------------- ψ and ψ'
@njit(cache=True, error_model="numpy", inline="always")
def _solve3(m00, m01, m02, m10, m11, m12, m20, m21, m22, b0, b1, b2):
    """3×3 solve by Cramer's rule (the matrix 𝐈 − τf_x is close to 𝐈 here)."""
    c00 = m11 * m22 - m12 * m21
    c01 = m12 * m20 - m10 * m22
    c02 = m10 * m21 - m11 * m20
    det = m00 * c00 + m01 * c01 + m02 * c02
    x0 = (b0 * c00 + b1 * (m02 * m21 - m01 * m22) + b2 * (m01 * m12 - m02 * m11)) / det
    x1 = (b0 * c01 + b1 * (m00 * m22 - m02 * m20) + b2 * (m02 * m10 - m00 * m12)) / det
    x2 = (b0 * c02 + b1 * (m01 * m20 - m00 * m21) + b2 * (m00 * m11 - m01 * m10)) / det
    return x0, x1, x2


@njit(cache=True, error_model="numpy")
def evaluate(y, p, psi, jac, want_jac):
    """ψ(y) into ``psi`` and, if ``want_jac``, ψ'(y) into ``jac`` (4×4); returns (J_t, F̃·f)."""
    R, I, K, V, tau = p[0], p[1], p[2], p[3], p[4]
    c1, p1, c2, p2, c3, c4, C6, p9 = p[5], p[6], p[7], p[8], p[9], p[10], p[11], p[12]
    al, om, u, v = y[0], y[1], y[2], y[3]
    sa = math.sin(al)
    ca = math.cos(al)
    s = om - v / R
    # f, f_x, f_v, F̃
    f0 = s
    f1 = -R * sa * K * u / I
    f2 = R * sa * s + V - v
    fx10 = -R * ca * K * u / I
    fx12 = -R * sa * K / I
    fx20 = R * ca * s
    fx21 = R * sa
    fv0 = -1.0 / R
    fv2 = -sa - 1.0
    Ft0 = K * u * ca
    Ft2 = K * (1.0 + sa)
    # φ_v (and φ_vv); v > 0 always (Newton runs on log v)
    vp1 = v ** (p1 - 1.0)
    vp2 = v ** (p2 - 1.0)
    vp9 = v ** (p9 - 1.0)
    ex = math.exp(v / c4)
    phiv = c1 * p1 * vp1 + c2 * p2 * vp2 + c3 / c4 * ex - C6 * p9 * vp9
    # M = 𝐈 − τ f_x ; w = M⁻¹ f_v ; J = −φ_v + τ F̃·w
    m00, m01, m02 = 1.0, -tau, 0.0
    m10, m11, m12 = -tau * fx10, 1.0, -tau * fx12
    m20, m21, m22 = -tau * fx20, -tau * fx21, 1.0
    w0, w1, w2 = _solve3(m00, m01, m02, m10, m11, m12, m20, m21, m22, fv0, 0.0, fv2)
    J = -phiv + tau * (Ft0 * w0 + Ft2 * w2)
    drive = Ft0 * f0 + Ft2 * f2
    psi[0], psi[1], psi[2], psi[3] = f0, f1, f2, -drive / J
    if want_jac:
        phivv = (
            c1 * p1 * (p1 - 1.0) * vp1 / v
            + c2 * p2 * (p2 - 1.0) * vp2 / v
            + c3 / (c4 * c4) * ex
            - C6 * p9 * (p9 - 1.0) * vp9 / v
        )
        # λ = M⁻ᵀ F̃
        _l0, l1, l2 = _solve3(m00, m10, m20, m01, m11, m21, m02, m12, m22, Ft0, 0.0, Ft2)
        # rows 0..2: [f_x | f_v]
        jac[0, 0], jac[0, 1], jac[0, 2], jac[0, 3] = 0.0, 1.0, 0.0, fv0
        jac[1, 0], jac[1, 1], jac[1, 2], jac[1, 3] = fx10, 0.0, fx12, 0.0
        jac[2, 0], jac[2, 1], jac[2, 2], jac[2, 3] = fx20, fx21, 0.0, fv2
        # ∂(F̃·f)/∂y_k = (∂F̃/∂y_k)·f + F̃·(∂f/∂y_k)
        dd_a = (-K * u * sa) * f0 + (K * ca) * f2 + Ft0 * 0.0 + Ft2 * fx20
        dd_o = Ft0 * 1.0 + Ft2 * fx21
        dd_u = (K * ca) * f0 + Ft0 * 0.0 + Ft2 * 0.0
        dd_v = Ft0 * fv0 + Ft2 * fv2
        # ∂J/∂y_k = −φ_vv δ_k3 + τ (∂F̃/∂y_k)·w + τ λ·(∂f_v/∂y_k + τ (∂f_x/∂y_k) w)
        # ∂f_x/∂α: [1,0] = R K u sinα/I, [1,2] = −R K cosα/I, [2,0] = −R sinα s, [2,1] = R cosα; ∂f_v/∂α = (0,0,−cosα)
        dJ_a = tau * ((-K * u * sa) * w0 + (K * ca) * w2) + tau * (
            l1 * (tau * (R * K * u * sa / I * w0 - R * K * ca / I * w2))
            + l2 * (-ca + tau * (-R * sa * s * w0 + R * ca * w1))
        )
        # ∂f_x/∂ω: [2,0] = R cosα
        dJ_o = tau * l2 * (tau * R * ca * w0)
        # ∂F̃/∂u = (K cosα, 0, 0); ∂f_x/∂u: [1,0] = −R K cosα/I
        dJ_u = tau * (K * ca) * w0 + tau * l1 * (tau * (-R * K * ca / I) * w0)
        # ∂f_x/∂v: [2,0] = −cosα
        dJ_v = -phivv + tau * l2 * (tau * (-ca) * w0)
        iJ = 1.0 / J
        q = drive * iJ * iJ
        jac[3, 0], jac[3, 1] = -dd_a * iJ + q * dJ_a, -dd_o * iJ + q * dJ_o
        jac[3, 2], jac[3, 3] = -dd_u * iJ + q * dJ_u, -dd_v * iJ + q * dJ_v
    return J, drive


@njit(cache=True, error_model="numpy")
def _solve4(A, b, x, work):
    """A·x = b by Gaussian elimination with the pairwise partial pivoting of ``solve_small``."""
    n = 4
    for i in range(n):
        for j in range(n):
            work[i, j] = A[i, j]
        work[i, n] = b[i]
    for k in range(n):
        for i in range(k + 1, n):
            if abs(work[i, k]) > abs(work[k, k]):
                for j in range(n + 1):
                    t = work[k, j]
                    work[k, j] = work[i, j]
                    work[i, j] = t
        for i in range(k + 1, n):
            factor = work[i, k] / work[k, k]
            for j in range(k + 1, n + 1):
                work[i, j] = work[i, j] - factor * work[k, j]
    for i in range(n - 1, -1, -1):
        acc = work[i, n]
        for j in range(i + 1, n):
            acc = acc - work[i, j] * x[j]
        x[i] = acc / work[i, i]


# --------------------------------------------------------------------------- one step
@njit(cache=True, error_model="numpy")
def evaluate_carried(c, logd, p, psi, jac, yy, want_jac):
    """ψ in the carried coordinates c: y itself, or (α, ω, u, log v) when ``logd``.

    With ``logd`` the ODE is z' = (f, ψ_v/v) (``peeljax.LogTransformedODE``) and its Jacobian
    follows from ψ'(y) by the chain rule. Returns (J_t, F̃·f); ``yy`` receives y.
    """
    yy[0], yy[1], yy[2] = c[0], c[1], c[2]
    yy[3] = math.exp(c[3]) if logd else c[3]
    J, drive = evaluate(yy, p, psi, jac, want_jac)
    if logd:
        v = yy[3]
        pv = psi[3]
        psi[3] = pv / v
        if want_jac:
            for i in range(3):
                jac[i, 3] = jac[i, 3] * v
            for j in range(3):
                jac[3, j] = jac[3, j] / v
            jac[3, 3] = jac[3, 3] - pv / v
    return J, drive


@njit(cache=True, error_model="numpy")
def _substep(
    y, psi, a, J, drive, h, p, coef, tol, max_it, logd, max_log_change, accept_unresolved, out_y, out_psi, out_a, ws
):
    """One α-step of size h from (y, ψ, a) in the carried coordinates; writes the candidate.

    Returns (status, iterations, J, drive). Without ``logd`` the Newton unknown is (α, ω, u, log v)
    and the scheme acts on y; with ``logd`` both act on z = (α, ω, u, log v).
    """
    gamma, b = coef[0], coef[1]
    rtol, atol = tol[0], tol[1]
    known, z, yz, ps, jac, mat, r, delta, work = ws
    hb = b * h
    for i in range(4):
        known[i] = y[i] + (1.0 - b) * h * psi[i] + (0.5 - b) * h * h * a[i]
    z0_log = y[3] if logd else math.log(y[3])
    z[0], z[1], z[2], z[3] = y[0], y[1], y[2], z0_log
    it = 0
    norm = 2.0
    while norm > 1.0 and it < max_it and math.isfinite(norm):
        if logd:
            evaluate_carried(z, True, p, ps, jac, yz, True)
            for i in range(4):
                r[i] = z[i] - known[i] - hb * ps[i]
                for j in range(4):
                    mat[i, j] = (1.0 if i == j else 0.0) - hb * jac[i, j]
        else:
            yz[0], yz[1], yz[2] = z[0], z[1], z[2]
            ev = math.exp(z[3])
            yz[3] = ev
            evaluate(yz, p, ps, jac, True)
            for i in range(4):
                r[i] = yz[i] - known[i] - hb * ps[i]
                for j in range(4):
                    d = ev if j == 3 else 1.0  # dy_j/dz_j
                    mat[i, j] = ((1.0 if i == j else 0.0) - hb * jac[i, j]) * d
        _solve4(mat, r, delta, work)
        finite = True
        norm = 0.0
        for i in range(4):
            z[i] = z[i] - delta[i]
            if not math.isfinite(z[i]):
                finite = False
        for i in range(3):
            wi = atol + rtol * abs(z[i])
            norm = max(norm, abs(delta[i]) / wi)
        norm = max(norm, abs(delta[3]) / rtol)
        if not finite:
            norm = math.inf
        it += 1
    converged = norm <= 1.0
    out_y[0], out_y[1], out_y[2] = z[0], z[1], z[2]
    out_y[3] = z[3] if logd else math.exp(z[3])
    J_new, drive_new = evaluate_carried(out_y, logd, p, out_psi, jac, yz, False)
    finite = True
    for i in range(4):
        out_a[i] = (out_psi[i] - psi[i]) / (gamma * h) + (1.0 - 1.0 / gamma) * a[i]
        if not (math.isfinite(out_y[i]) and math.isfinite(out_psi[i]) and math.isfinite(out_a[i])):
            finite = False
    unresolved = (abs(z[3] - z0_log) > max_log_change) and not accept_unresolved
    if (not converged) or unresolved:
        status = NEWTON_FAILED
    elif not finite:
        status = NONFINITE
    elif (J * J_new < 0.0) and (drive * drive_new > 0.0):
        status = IMPASSE
    else:
        status = 0
    return status, it, J_new, drive_new


@njit(cache=True, error_model="numpy")
def integrate(y0, p, h, n_steps, rho=0.0, rtol=1e-10, atol=1e-12, max_it=25, max_subdivisions=4,
              log_discretization=False, max_log_change=math.inf):  # fmt: skip
    """The α-method on n_steps uniform steps of size h from y0.

    ``log_discretization`` and ``max_log_change`` as in ``peeljax.AlphaMethod`` (False and inf
    give the scheme on y of the paper with Newton on log v and no log-change subdivision).
    Returns (ys (n+1, 4), newton_iterations per step (n,), subdivision level per step (n,),
    status, number of steps whose first Newton solve failed or was unresolved).
    """
    logd = log_discretization
    gamma = 2.0 / (rho + 1.0) - 0.5
    beta = 1.0 / (rho + 1.0) ** 2
    coef = np.array([gamma, beta / gamma])
    tol = np.array([rtol, atol])
    # known, z, yz, ps, jac, mat, r, delta, work
    ws = (np.empty(4), np.empty(4), np.empty(4), np.empty(4), np.empty((4, 4)), np.empty((4, 4)), np.empty(4),
          np.empty(4), np.empty((4, 5)))  # fmt: skip
    ys = np.full((n_steps + 1, 4), np.nan)
    iters = np.zeros(n_steps, np.int64)
    levels = np.zeros(n_steps, np.int64)
    status = 0
    if not y0[3] > 0:
        status = NONFINITE
    y = y0.copy()  # the carried coordinates
    if logd:
        y[3] = math.log(y0[3]) if y0[3] > 0 else 0.0
    psi = np.empty(4)
    a = np.empty(4)
    jac = np.empty((4, 4))
    yy = np.empty(4)
    J, drive = evaluate_carried(y, logd, p, psi, jac, yy, True)
    for i in range(4):
        s = 0.0
        for j in range(4):
            s += jac[i, j] * psi[j]
        a[i] = s
        if not (math.isfinite(psi[i]) and math.isfinite(s)):
            status = NONFINITE
        if not math.isfinite(s):
            a[i] = 0.0
    ys[0] = y0
    # candidates and the subdivision's own carry
    ny, npsi, na = np.empty(4), np.empty(4), np.empty(4)
    cy, cpsi, ca = np.empty(4), np.empty(4), np.empty(4)
    failures = 0
    for n in range(n_steps):
        if status != 0:
            break
        st, it, nJ, nd = _substep(
            y, psi, a, J, drive, h, p, coef, tol, max_it, logd, max_log_change, max_subdivisions == 0, ny, npsi, na, ws
        )
        total = it
        level = 0
        if st == NEWTON_FAILED:
            failures += 1
        while st == NEWTON_FAILED and level < max_subdivisions:
            level += 1
            n_sub = 2**level
            hs = h / n_sub
            cy[:] = y
            cpsi[:] = psi
            ca[:] = a
            cJ, cd = J, drive
            st = 0
            k = 0
            while k < n_sub and st == 0:
                st, it, nJ2, nd2 = _substep(
                    cy, cpsi, ca, cJ, cd, hs, p, coef, tol, max_it, logd, max_log_change, level >= max_subdivisions,
                    ny, npsi, na, ws,
                )  # fmt: skip
                total += it
                if st == 0:
                    cy[:] = ny
                    cpsi[:] = npsi
                    ca[:] = na
                    cJ, cd = nJ2, nd2
                k += 1
            if st == 0:
                ny[:] = cy
                npsi[:] = cpsi
                na[:] = ca
                nJ, nd = cJ, cd
        iters[n] = total
        levels[n] = level
        status = st
        if st == 0:
            y[:] = ny
            psi[:] = npsi
            a[:] = na
            J, drive = nJ, nd
            ys[n + 1] = y
            if logd:
                ys[n + 1, 3] = math.exp(y[3])
    return ys, iters, levels, status, failures


def options_of(solver):
    """The keyword arguments of :func:`integrate` that reproduce a ``peeljax.AlphaMethod``."""
    return {
        "rho": float(solver.rho),
        "rtol": float(solver.newton_rtol),
        "atol": float(solver.newton_atol),
        "max_it": int(solver.max_newton_iterations),
        "max_subdivisions": int(solver.max_subdivisions),
        "log_discretization": bool(getattr(solver, "log_discretization", False))
        and 3 in getattr(solver, "log_components", (3,)),
        "max_log_change": float(getattr(solver, "max_log_change", math.inf)),
    }


# --------------------------------------------------------------------------- checks
def check_jacobian(n_points=20, seed=0):
    """Max relative difference between :func:`evaluate`'s ψ, ψ' and peeljax's (autodiff)."""
    import jax
    import jax.numpy as jnp

    import peeljax

    rng = np.random.default_rng(seed)
    p = parameters()
    ode = peeljax.HomogenizedODE(peeljax.PeelingModel(), 1.1, 0.01)
    psi_j = jax.jit(lambda y: ode(y))
    jac_j = jax.jit(jax.jacfwd(lambda y: ode(y)))
    worst = 0.0
    psi = np.empty(4)
    jac = np.empty((4, 4))
    for _ in range(n_points):
        y = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-1, 15), rng.uniform(0.1, 0.4), 10 ** rng.uniform(-10, 0.5)])
        evaluate(y, p, psi, jac, True)
        ref_psi = np.asarray(psi_j(jnp.asarray(y)))
        ref_jac = np.asarray(jac_j(jnp.asarray(y)))
        worst = max(
            worst,
            np.max(np.abs(psi - ref_psi) / (np.abs(ref_psi) + 1e-300)),
            np.max(np.abs(jac - ref_jac) / (np.max(np.abs(ref_jac), axis=1, keepdims=True) + 1e-300)),
        )
    return worst


def compare_with_peeljax(V=1.1, tau=0.01, h=1 / 820, t_final=3.0, solver=None):
    """Run ``peeljax.simulate`` and the compiled loop with the same settings and compare them.

    Returns max |Δv|/|v| over the grid, the Newton iteration totals and per-step differences,
    statuses and subdivided-step counts of both.
    """
    import jax

    import peeljax

    n = round(t_final / h)
    solver = peeljax.AlphaMethod() if solver is None else solver
    sol = peeljax.simulate(V=V, tau=tau, dt=h, t_final=t_final, solver=solver)
    jax.block_until_ready(sol.ys)
    p = parameters(V, tau)
    ys, iters, levels, status, failures = integrate(initial_state(p), p, t_final / n, n, **options_of(solver))
    v_ref = np.asarray(sol.ys)[:, 3]
    rel = np.max(np.abs(ys[:, 3] - v_ref) / np.abs(v_ref))
    it_ref = np.asarray(sol.diagnostics.newton_iterations)[1:]
    return {
        "max_rel_dv": float(rel),
        "max_abs_dy": float(np.max(np.abs(ys - np.asarray(sol.ys)))),
        "newton_peeljax": int(it_ref.sum()),
        "newton_numba": int(iters.sum()),
        "max_step_iteration_difference": int(np.max(np.abs(it_ref - iters))),
        "steps_with_different_iterations": int(np.sum(it_ref != iters)),
        "status": (int(sol.status), int(status)),
        "subdivided": (int(sol.stats["subdivided_steps"]), int(np.sum(levels > 0))),
        "failures": int(failures),
    }


def main(argv=None):
    """The checks: ψ' against autodiff, the loop against ``peeljax.simulate``."""
    import argparse

    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args(argv)
    print("max rel. difference of ψ, ψ' vs jax autodiff:", check_jacobian())
    import peeljax

    print("AlphaMethod() defaults:", options_of(peeljax.AlphaMethod()))
    for h in (1 / 82, 1 / 820, 1 / 8200):
        print(f"h = 1/{round(1 / h)}:", compare_with_peeljax(h=h))
    # the scheme on y as printed in the paper, Newton on log v, no log-change subdivision (peeljax takes no inf)
    paper = peeljax.AlphaMethod(log_discretization=False, max_log_change=1e300)
    print("log_discretization=False, no max_log_change, h = 1/820:", compare_with_peeljax(solver=paper))


if __name__ == "__main__":
    # Run as the module the peers import (``peers.compiled_loop``): numba's on-disk cache rebuilds a
    # function's environment by its module's name, which a ``__main__`` copy would not match.
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from peers.compiled_loop import main as _main

    _main()
