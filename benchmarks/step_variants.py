"""A copy of peeljax's α-method step (paper geometry) with switchable changes, for timing only.

``benchmarks/step_experiments.py`` times these variants against each other and against the
compiled loop; nothing in ``peeljax/`` uses this file. The baseline (``Variant()``) is the
algorithm of ``peeljax.integrators.alpha`` (ψ from ``HomogenizedODE.evaluate``, Newton matrix
by ``jax.jacfwd`` of the step residual, start guess z_n, a final ``evaluate`` at the accepted
state, the subdivision safeguard, one ``lax.scan`` with a ``lax.cond`` skip), and is checked
to reproduce ``peeljax.simulate`` to rounding.

Switches (``Variant``):

* ``psi="analytic"``: ψ and ψ' written out as scalar arithmetic (the derivatives of
  ``benchmarks/compiled_loop.py``) instead of nested ``jax.jacfwd`` (``jacobians`` inside
  ``evaluate``, then ``jacfwd`` of the residual over it);
* ``psi="semi"``: ψ written out (f_x, f_v, F̃, φ_v by hand, no inner ``jacfwd``), ψ' still by
  one ``jax.jacfwd`` of the residual;
* ``predictor=True``: Newton starts from the explicit predictor z_n + hψ_n + h²/2·a_n;
* ``reuse=True``: no evaluation after Newton: ψ_{n+1} = (z_{n+1} − known)/(b·h), which is
  ψ(z_k) − ψ'(z_k)·δ_k, the last Newton evaluation corrected to first order (error O(δ²)),
  and J_t, F̃·f for the impasse test from the last Newton evaluation;
* ``unroll=k``: ``lax.scan(..., unroll=k)``;
* ``no_cond=True``: the scan body without the ``lax.cond`` skip (the step runs and its result
  is masked after a stop).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp

NEWTON_FAILED, IMPASSE, NONFINITE = 1, 2, 3


@dataclasses.dataclass(frozen=True)
class Variant:
    psi: str = "autodiff"  # or "analytic", "semi"
    predictor: bool = False
    reuse: bool = False
    unroll: int = 1
    no_cond: bool = False

    def label(self) -> str:
        parts = [self.psi]
        if self.predictor:
            parts.append("predictor")
        if self.reuse:
            parts.append("reuse")
        if self.unroll != 1:
            parts.append(f"unroll={self.unroll}")
        if self.no_cond:
            parts.append("no-cond")
        return "+".join(parts)


def solve_small(A, b):
    """Copy of ``peeljax._linalg.solve_small``: unrolled Gaussian elimination, pairwise pivoting."""
    n = A.shape[0]
    rows = [[A[i, j] for j in range(n)] + [b[i]] for i in range(n)]
    for k in range(n):
        for i in range(k + 1, n):
            swap = jnp.abs(rows[i][k]) > jnp.abs(rows[k][k])
            rows[k], rows[i] = (
                [jnp.where(swap, ri, rk) for rk, ri in zip(rows[k], rows[i])],
                [jnp.where(swap, rk, ri) for rk, ri in zip(rows[k], rows[i])],
            )
        for i in range(k + 1, n):
            factor = rows[i][k] / rows[k][k]
            rows[i] = [rows[i][j] - factor * rows[k][j] if j > k else rows[i][j] for j in range(n + 1)]
    x = [None] * n
    for i in reversed(range(n)):
        acc = rows[i][n]
        for j in range(i + 1, n):
            acc = acc - rows[i][j] * x[j]
        x[i] = acc / rows[i][i]
    return jnp.stack(x)


# --------------------------------------------------------------------------- ψ providers
def _autodiff_eval(ode, y):
    ev = ode.evaluate(y)
    return ev.psi, ev.J, ev.drive


def _solve3(m, b):
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = m
    b0, b1, b2 = b
    c00 = m11 * m22 - m12 * m21
    c01 = m12 * m20 - m10 * m22
    c02 = m10 * m21 - m11 * m20
    det = m00 * c00 + m01 * c01 + m02 * c02
    x0 = (b0 * c00 + b1 * (m02 * m21 - m01 * m22) + b2 * (m01 * m12 - m02 * m11)) / det
    x1 = (b0 * c01 + b1 * (m00 * m22 - m02 * m20) + b2 * (m02 * m10 - m00 * m12)) / det
    x2 = (b0 * c02 + b1 * (m01 * m20 - m00 * m21) + b2 * (m00 * m11 - m01 * m10)) / det
    return x0, x1, x2


def _analytic_eval(ode, y, want_jac):
    """ψ(y), J_t, F̃·f and (optionally) ψ'(y) for the paper geometry, as scalar arithmetic."""
    m, ad = ode.model, ode.model.adhesion
    R, I, K, V, tau = m.R, m.I, m.k / m.l, ode.V, ode.tau
    C6 = ad.c6 - ad.c7 * V**ad.p7 - ad.c8 * V**ad.p8
    al, om, u, v = y[0], y[1], y[2], y[3]
    sa, ca = jnp.sin(al), jnp.cos(al)
    s = om - v / R
    f0, f1, f2 = s, -R * sa * K * u / I, R * sa * s + V - v
    fx10, fx12, fx20, fx21 = -R * ca * K * u / I, -R * sa * K / I, R * ca * s, R * sa
    fv0, fv2 = -1.0 / R, -sa - 1.0
    Ft0, Ft2 = K * u * ca, K * (1.0 + sa)
    vp1, vp2, vp9 = v ** (ad.p1 - 1.0), v ** (ad.p2 - 1.0), v ** (ad.p9 - 1.0)
    ex = jnp.exp(v / ad.c4)
    phiv = ad.c1 * ad.p1 * vp1 + ad.c2 * ad.p2 * vp2 + ad.c3 / ad.c4 * ex - C6 * ad.p9 * vp9
    M = ((1.0, -tau, 0.0), (-tau * fx10, 1.0, -tau * fx12), (-tau * fx20, -tau * fx21, 1.0))
    w0, w1, w2 = _solve3(M, (fv0, 0.0, fv2))
    J = -phiv + tau * (Ft0 * w0 + Ft2 * w2)
    drive = Ft0 * f0 + Ft2 * f2
    psi = jnp.stack([f0, f1, f2, -drive / J])
    if not want_jac:
        return psi, J, drive, None
    phivv = (
        ad.c1 * ad.p1 * (ad.p1 - 1.0) * vp1 / v
        + ad.c2 * ad.p2 * (ad.p2 - 1.0) * vp2 / v
        + ad.c3 / (ad.c4 * ad.c4) * ex
        - C6 * ad.p9 * (ad.p9 - 1.0) * vp9 / v
    )
    MT = tuple(zip(*M))
    _l0, l1, l2 = _solve3(MT, (Ft0, 0.0, Ft2))
    dd_a = (-K * u * sa) * f0 + (K * ca) * f2 + Ft2 * fx20
    dd_o = Ft0 + Ft2 * fx21
    dd_u = (K * ca) * f0
    dd_v = Ft0 * fv0 + Ft2 * fv2
    dJ_a = tau * ((-K * u * sa) * w0 + (K * ca) * w2) + tau * (
        l1 * (tau * (R * K * u * sa / I * w0 - R * K * ca / I * w2))
        + l2 * (-ca + tau * (-R * sa * s * w0 + R * ca * w1))
    )
    dJ_o = tau * l2 * (tau * R * ca * w0)
    dJ_u = tau * (K * ca) * w0 + tau * l1 * (tau * (-R * K * ca / I) * w0)
    dJ_v = -phivv + tau * l2 * (tau * (-ca) * w0)
    iJ = 1.0 / J
    q = drive * iJ * iJ
    zero = jnp.zeros_like(v)
    one = jnp.ones_like(v)
    jac = jnp.stack(
        [
            jnp.stack([zero, one, zero, fv0 * one]),
            jnp.stack([fx10, zero, fx12, zero]),
            jnp.stack([fx20, fx21, zero, fv2]),
            jnp.stack([-dd_a * iJ + q * dJ_a, -dd_o * iJ + q * dJ_o, -dd_u * iJ + q * dJ_u, -dd_v * iJ + q * dJ_v]),
        ]
    )
    return psi, J, drive, jac


# --------------------------------------------------------------------------- the integrator
class Config(eqx.Module):
    """The AlphaMethod settings (``compiled_loop.options_of``)."""

    rho: float
    rtol: float
    atol: float
    max_it: int = eqx.field(static=True)
    max_subdivisions: int = eqx.field(static=True)
    log_discretization: bool = eqx.field(static=True)
    max_log_change: float


def _state(c, logd):
    """y from the carried coordinates."""
    return c.at[3].set(jnp.exp(c[3])) if logd else c


def make_integrate(variant: Variant, n_steps: int, max_it: int, max_subdivisions: int, logd: bool):
    """fn(ode, cfg_arrays, y0, t_final) -> (ys, iterations, levels, status), jit-able."""

    def evaluate_c(ode, c, want_jac):
        """ψ (and ψ') in the carried coordinates, with J_t and F̃·f."""
        y = _state(c, logd)
        if variant.psi == "analytic":
            psi, J, drive, jac = _analytic_eval(ode, y, want_jac)
        elif variant.psi == "semi":
            psi, J, drive, jac = _analytic_eval(ode, y, False)
        else:
            psi, J, drive = _autodiff_eval(ode, y)
            jac = None
        if logd:
            v, pv = y[3], psi[3]
            psi = psi.at[3].set(pv / v)
            if jac is not None:
                jac = jac.at[:3, 3].multiply(v).at[3, :3].divide(v).at[3, 3].add(-pv / v)
        return psi, J, drive, jac

    def newton(ode, rtol, atol, known, hb, z_start):
        eye = jnp.eye(4)
        mask = jnp.arange(4) == 3

        def to_state(z):  # the Newton unknown -> carried coordinates
            return z if logd else z.at[3].set(jnp.exp(z[3]))

        def residual(z):
            c = to_state(z)
            psi, J, drive, _ = evaluate_c(ode, c, False)
            r = c - known - hb * psi
            return r, (r, J, drive)

        def body(carry):
            z, it, _, _, _ = carry
            if variant.psi == "analytic":
                c = to_state(z)
                psi, J, drive, jac = evaluate_c(ode, c, True)
                r = c - known - hb * psi
                matrix = eye - hb * jac
                if not logd:
                    matrix = matrix.at[:, 3].multiply(c[3])
            else:
                matrix, (r, J, drive) = jax.jacfwd(residual, has_aux=True)(z)
            delta = solve_small(matrix, r)
            z_new = z - delta
            norm = jnp.max(jnp.abs(delta) / jnp.where(mask, rtol, atol + rtol * jnp.abs(z_new)))
            norm = jnp.where(jnp.all(jnp.isfinite(z_new)), norm, jnp.inf)
            return z_new, it + 1, norm, J, drive

        def cond(carry):
            _, it, norm, _, _ = carry
            return (norm > 1.0) & (it < max_it) & jnp.isfinite(norm)

        init = (z_start, jnp.asarray(0, jnp.int32), jnp.asarray(2.0), jnp.asarray(1.0), jnp.asarray(1.0))
        z, it, norm, J, drive = jax.lax.while_loop(cond, body, init)
        return z, it, norm <= 1.0, J, drive

    def substep(ode, cfg, carry, h, accept_unresolved):
        y, psi, a, J, drive, _ = carry
        gamma = 2.0 / (cfg.rho + 1.0) - 0.5
        b = 1.0 / (cfg.rho + 1.0) ** 2 / gamma
        known = y + (1.0 - b) * h * psi + (0.5 - b) * h**2 * a
        start = y + h * psi + 0.5 * h**2 * a if variant.predictor else y
        z0 = start if logd else start.at[3].set(jnp.log(start[3]))
        z_prev_log = y[3] if logd else jnp.log(y[3])
        z, it, converged, J_last, drive_last = newton(ode, cfg.rtol, cfg.atol, known, b * h, z0)
        y_new = z if logd else z.at[3].set(jnp.exp(z[3]))
        if variant.reuse:
            psi_new = (y_new - known) / (b * h)
            J_new, drive_new = J_last, drive_last
        else:
            psi_new, J_new, drive_new, _ = evaluate_c(ode, y_new, False)
        a_new = (psi_new - psi) / (gamma * h) + (1.0 - 1.0 / gamma) * a
        finite = jnp.all(jnp.isfinite(y_new)) & jnp.all(jnp.isfinite(psi_new)) & jnp.all(jnp.isfinite(a_new))
        unresolved = (jnp.abs(z[3] - z_prev_log) > cfg.max_log_change) & ~accept_unresolved
        status = jnp.where(
            ~converged | unresolved,
            NEWTON_FAILED,
            jnp.where(~finite, NONFINITE, jnp.where((J * J_new < 0) & (drive * drive_new > 0), IMPASSE, 0)),
        ).astype(jnp.int32)
        return (y_new, psi_new, a_new, J_new, drive_new, status), it

    def subdivided(ode, cfg, carry, h, level):
        n_sub = 2**level
        h_sub = h / n_sub

        def body(state):
            i, current, its = state
            new, it = substep(ode, cfg, current, h_sub, level >= max_subdivisions)
            ok = new[5] == 0
            current = tuple(jnp.where(ok, a, b) for a, b in zip(new[:5], current[:5])) + (new[5],)
            return i + 1, current, its + it

        def cond(state):
            return (state[0] < n_sub) & (state[1][5] == 0)

        _, new, its = jax.lax.while_loop(cond, body, (jnp.asarray(0, jnp.int32), carry, jnp.asarray(0, jnp.int32)))
        return new, its

    def step(ode, cfg, carry, h):
        new, its = substep(ode, cfg, carry, h, max_subdivisions == 0)
        if max_subdivisions == 0:
            return new, its, jnp.asarray(0, jnp.int32)

        def retry_cond(state):
            return (state[1][5] == NEWTON_FAILED) & (state[0] < max_subdivisions)

        def retry_body(state):
            level, _, its = state
            new, it = subdivided(ode, cfg, carry, h, level + 1)
            return level + 1, new, its + it

        level, new, its = jax.lax.while_loop(retry_cond, retry_body, (jnp.asarray(0, jnp.int32), new, its))
        return new, its, level

    def integrate(ode, cfg, y0, t_final):
        h = t_final / n_steps
        c0 = y0.at[3].set(jnp.log(y0[3])) if logd else y0
        psi0, J0, drive0, _ = evaluate_c(ode, c0, False)
        a0 = jax.jvp(lambda c: evaluate_c(ode, c, False)[0], (c0,), (psi0,))[1]
        ok0 = jnp.all(jnp.isfinite(psi0)) & jnp.all(jnp.isfinite(a0)) & (y0[3] > 0)
        carry0 = (
            c0,
            psi0,
            jnp.where(jnp.isfinite(a0), a0, 0.0),
            J0,
            drive0,
            jnp.where(ok0, 0, NONFINITE).astype(jnp.int32),
        )
        zero = jnp.asarray(0, jnp.int32)

        def advance(carry):
            new, its, level = step(ode, cfg, carry, h)
            ok = new[5] == 0
            kept = tuple(jnp.where(ok, a, b) for a, b in zip(new[:5], carry[:5])) + (new[5],)
            return kept, its, level, ok

        def skip(carry):
            return carry, zero, zero, jnp.asarray(False)

        def body(carry, _):
            if variant.no_cond:
                running = carry[5] == 0
                new, its, level, ok = advance(carry)
                new = tuple(jnp.where(running, a, b) for a, b in zip(new, carry))
                its, level, ok = jnp.where(running, its, 0), jnp.where(running, level, 0), ok & running
            else:
                new, its, level, ok = jax.lax.cond(carry[5] == 0, advance, skip, carry)
            return new, (new[0], its, level, ok)

        final, (cs, its, levels, oks) = jax.lax.scan(body, carry0, None, length=n_steps, unroll=variant.unroll)
        ys = jnp.concatenate([c0[None], cs])
        if logd:
            ys = ys.at[:, 3].set(jnp.exp(ys[:, 3]))
        valid = jnp.concatenate([ok0[None], oks])
        ys = jnp.where(valid[:, None], ys, jnp.nan)
        return ys, its, levels, final[5]

    return integrate


def build(variant: Variant, n_steps: int, options: dict, V=1.1, tau=0.01):
    """(compiled-on-first-call fn, args): fn(*args) runs one trajectory."""
    import peeljax

    ode = peeljax.HomogenizedODE(peeljax.PeelingModel(), V, tau)
    cfg = Config(
        rho=jnp.asarray(options["rho"]),
        rtol=jnp.asarray(options["rtol"]),
        atol=jnp.asarray(options["atol"]),
        max_it=options["max_it"],
        max_subdivisions=options["max_subdivisions"],
        log_discretization=options["log_discretization"],
        max_log_change=jnp.asarray(options["max_log_change"]),
    )
    fn = make_integrate(variant, n_steps, options["max_it"], options["max_subdivisions"], options["log_discretization"])
    jitted = jax.jit(fn)
    y0 = ode.model.initial_state(ode.V)
    return jitted, (ode, cfg, y0, jnp.asarray(3.0))
