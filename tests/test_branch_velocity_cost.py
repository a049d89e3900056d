"""The cheaper branch root finder (issue 27 item 2) solves what the old one solved.

``peeljax.branches.branch_velocity`` stops its Newton iteration in log v earlier than before
(a zero residual or a round-off-sized update is final, a quadratically predicted error below
round-off skips the confirming iteration, clamped states skip the search). The old algorithm
is copied here: the roots must agree to round-off at states on both branches, near both folds,
on the stuck tape and past the folds, and the implicit-function-theorem derivatives must match
central finite differences (and the old derivatives).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from peeljax.branches import SLIP, STICK, _bounds, _root_on, _stop_gradient, branch_velocity, phi_folds
from peeljax.model import PeelingModel

V = 1.1
EPS = np.finfo(float).eps


def _old_root_on(model, V, target, lo, hi, guess):
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
        return (carry[3] < 80) & (carry[4] > 1e-14)

    w0 = jnp.clip(jnp.log(jnp.clip(guess, lo, hi)), log_lo, log_hi)
    return jax.lax.while_loop(more, body, (w0, log_lo, log_hi, jnp.asarray(0), jnp.asarray(jnp.inf)))[0]


def _old_branch_velocity(model, x, V, branch, folds, guess=1.0):
    lo, hi = _bounds(folds, branch)
    target = model.shear_force(x)
    sg = _stop_gradient
    w = _old_root_on(sg(model), sg(V), sg(target), sg(lo), sg(hi), sg(guess))
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


@pytest.fixture(scope="module")
def setup():
    model = PeelingModel()
    return model, phi_folds(model, V)


def _x_for(model, G):
    """x = (0, 0, u) with G(x) = G (paper geometry: G = (k/l)·u at α = 0)."""
    return jnp.array([0.0, 0.0, float(G) * float(model.l) / float(model.k)])


def _cases(model, folds):
    """(G, branch, guess) at many states: both branches, near the folds, stuck, past the folds."""
    phi = lambda v: float(model.phi(v, V))  # noqa: E731
    v_max, v_min, v_top = float(folds.v_max), float(folds.v_min), float(folds.v_top)
    phi_max, phi_min, phi_zero = float(folds.phi_max), float(folds.phi_min), float(folds.phi_zero)
    cases = []
    stick_v = np.concatenate([np.geomspace(1.1e-10, 0.9 * v_max, 14), v_max * (1 - np.geomspace(1e-2, 1e-7, 6))])
    slip_v = np.concatenate([v_min * (1 + np.geomspace(1e-7, 1e-2, 6)), np.geomspace(1.05 * v_min, 0.5 * v_top, 10)])
    for branch, vs in ((STICK, stick_v), (SLIP, slip_v)):
        for v in vs:
            G = phi(v)
            for guess in (v, v * (1 + 1e-6), v * 1.01, v * 0.5, v * 3.0, 1.0):
                cases.append((G, branch, guess))
    G_between = 0.5 * (phi_min + phi_max)
    cases += [
        (phi_zero - 1.0, STICK, 1e-3),  # stuck tape
        (phi_zero - 1e-9, STICK, 1e-10),
        (phi_max + 1e-9, STICK, 0.4),  # past the stick branch's fold: clamped at v̂
        (phi_max + 10.0, STICK, 1e-6),
        (phi_min - 1e-9, SLIP, 10.0),  # past the slip branch's fold: clamped at v̌
        (phi_min - 10.0, SLIP, 50.0),
        (G_between, STICK, 1e-3),
        (G_between, SLIP, 30.0),
    ]
    return cases


def _roundoff_in_log_v(model, v, G, slope):
    """Round-off floor of the root in log v: ε·(Σ|terms of φ|)/|∂φ/∂(log v)|."""
    c = model.adhesion.coefficients()
    terms = [
        c["c1"] * v ** c["p1"],
        c["c2"] * v ** c["p2"],
        c["c3"] * np.exp(v / c["c4"]),
        c["c5"] * V ** c["p5"],
        c["c6"] * v ** c["p9"],
        abs(G),
    ]
    return EPS * sum(abs(t) for t in terms) / max(abs(slope), 1e-300)


def test_new_root_equals_the_old_algorithms(setup):
    model, folds = setup
    cases = _cases(model, folds)
    X = jnp.stack([_x_for(model, G) for G, _, _ in cases])
    branches = jnp.array([b for _, b, _ in cases])
    guesses = jnp.array([g for _, _, g in cases])

    def both(x, b, g):
        return (
            branch_velocity(model, x, V, b, folds, guess=g),
            _old_branch_velocity(model, x, V, b, folds, guess=g),
        )

    new, old = (np.asarray(a) for a in jax.jit(jax.vmap(both))(X, branches, guesses))
    assert np.all(np.isfinite(new))
    np.testing.assert_array_equal(new == 0, old == 0)  # the stuck tape, alike
    lo_hi = {STICK: _bounds(folds, STICK), SLIP: _bounds(folds, SLIP)}
    slopes = np.asarray(  # ∂φ/∂(log v) at the old roots
        jax.jit(jax.vmap(jax.grad(lambda w: model.phi(jnp.exp(w), V))))(jnp.log(jnp.maximum(old, 1e-300)))
    )
    for (G, branch, guess), a, b, slope in zip(cases, new, old, slopes):
        if b == 0:
            continue
        lo, hi = (float(e) for e in lo_hi[branch])
        if b in (lo, hi):  # clamped: the same end, exactly
            assert a == b, (G, branch, guess, a, b)
            continue
        # 1e-12 relative, or the root's own round-off floor where the slope vanishes (folds)
        tolerance = max(1e-12, 4 * _roundoff_in_log_v(model, b, G, slope))
        assert abs(np.log(a) - np.log(b)) <= tolerance, (G, branch, guess, a, b, tolerance)
    # the cases do cover every situation
    kinds = {
        "stuck": np.sum(old == 0),
        "clamped": sum(o in (float(lo_hi[b][0]), float(lo_hi[b][1])) for (_, b, _), o in zip(cases, old)),
        "slip": int(np.sum((branches == SLIP) & (old > 0))),
    }
    assert all(n >= 2 for n in kinds.values()), kinds


def test_new_root_search_takes_fewer_iterations(setup):
    """From the exact root one evaluation; clamped states none (the old one bisected away
    from an exact root, and down to the branch's end on the stuck tape)."""
    model, folds = setup
    v = 0.02
    G = model.phi(v, V)
    lo, hi = _bounds(folds, STICK)
    w, n = _root_on(model, V, G, lo, hi, jnp.asarray(v), False, count=True)
    assert int(n) <= 2 and abs(float(w) - np.log(v)) < 1e-12
    _, n = _root_on(model, V, folds.phi_zero - 1.0, lo, hi, jnp.asarray(v), True, count=True)
    assert int(n) == 0


def test_gradients_match_finite_differences(setup):
    """jax.grad of v in x and V (folds held: v does not depend on them inside a branch) against
    central differences and against the old algorithm's derivatives, on both branches."""
    model, folds = setup
    cases = [(STICK, 1e-6), (STICK, 0.02), (STICK, 0.4), (SLIP, 10.0), (SLIP, 30.0)]
    alpha = 0.01

    def state(v):  # G(x) = φ(v, V) at α = 0.01
        u = float(model.phi(v, V)) * float(model.l) / float(model.k) / (1.0 + np.sin(alpha))
        return np.array([alpha, 0.3, u])

    X = jnp.asarray(np.stack([state(v) for _, v in cases]))
    B = jnp.array([b for b, _ in cases])
    guess = jnp.array([1.001 * v for _, v in cases])
    Vs = jnp.full(len(cases), V)

    def velocity(x, V_, b, g):
        return branch_velocity(model, x, V_, b, folds, guess=g)

    def old_velocity(x, V_, b, g):
        return _old_branch_velocity(model, x, V_, b, folds, guess=g)

    grads = jax.jit(jax.vmap(jax.grad(velocity, argnums=(0, 1))))
    old_grads = jax.jit(jax.vmap(jax.grad(old_velocity, argnums=(0, 1))))
    values = jax.jit(jax.vmap(velocity))
    gx, gV = (np.asarray(a) for a in grads(X, Vs, B, guess))
    gx_old, gV_old = (np.asarray(a) for a in old_grads(X, Vs, B, guess))
    np.testing.assert_allclose(values(X, Vs, B, guess), [v for _, v in cases], rtol=1e-9)
    np.testing.assert_allclose(gx, gx_old, rtol=1e-10, atol=0)
    np.testing.assert_allclose(gV, gV_old, rtol=1e-10, atol=0)
    # central differences: x_i ± h_i, V ± h, all in one batch
    steps = np.maximum(1e-6 * np.abs(np.asarray(X)), 1e-9)
    for i in range(4):
        if i < 3:
            e = np.zeros_like(steps)
            e[:, i] = steps[:, i]
            plus = values(X + e, Vs, B, guess)
            minus = values(X - e, Vs, B, guess)
            fd, exact, h = (np.asarray(plus) - np.asarray(minus)) / (2 * steps[:, i]), gx[:, i], steps[:, i]
        else:
            h = 1e-6
            plus, minus = values(X, Vs + h, B, guess), values(X, Vs - h, B, guess)
            fd, exact = (np.asarray(plus) - np.asarray(minus)) / (2 * h), gV
        v = np.array([v for _, v in cases])
        # FD's own round-off is ~ε·v/h
        assert np.all(np.abs(exact - fd) <= 2e-5 * np.abs(fd) + 1e-13 * v / h), (i, exact, fd)
