"""Exact gradients through the α-method (issue 4 §1).

One compiled gradient serves the finite-difference, stop-early and parameter checks (τ is a
traced leaf, so τ = 0.1 and τ = 1e-3 share it); one compiled linearisation serves the
forward-mode and no-unrolling checks.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.extend.core
import jax.numpy as jnp
import numpy as np
import pytest

import peeljax as pj
from peeljax.integrators.uniform_mesh import integrate_alpha

T_FINAL, N_STEPS = 0.5, 41  # h = 1/82, the paper's step
NAMES = ("c1", "p1", "c3", "c6", "p9", "V", "tau", "R", "I", "k", "l", "y0")


def params0(tau=0.1):
    model = pj.PeelingModel()
    law = model.adhesion
    return {
        "c1": law.c1,
        "p1": law.p1,
        "c3": law.c3,
        "c6": law.c6,
        "p9": law.p9,
        "V": jnp.asarray(1.1),
        "tau": jnp.asarray(tau),
        "R": model.R,
        "I": model.I,
        "k": model.k,
        "l": model.l,
        "y0": model.initial_state(1.1),
    }


def trajectory(p, solver=None, checkpoint_every=None):
    law = eqx.tree_at(
        lambda a: (a.c1, a.p1, a.c3, a.c6, a.p9), pj.AdhesionLaw(), (p["c1"], p["p1"], p["c3"], p["c6"], p["p9"])
    )
    model = pj.PeelingModel(R=p["R"], I=p["I"], k=p["k"], l=p["l"], adhesion=law)
    ode = pj.HomogenizedODE(model, p["V"], p["tau"])
    solver = pj.AlphaMethod() if solver is None else solver
    return integrate_alpha(ode, solver, p["y0"], 0.0, T_FINAL, N_STEPS, checkpoint_every=checkpoint_every)


def loss(p, solver=None, checkpoint_every=None):
    """A smooth scalar of the valid part: mean of v² + α + ω·u, the masked states set to 0 first."""
    sol = trajectory(p, solver, checkpoint_every)
    ys = jnp.where(sol.valid[:, None], sol.ys, 0.0)  # double where: NaN never reaches the gradient
    return jnp.sum(ys[:, 3] ** 2 + 10.0 * ys[:, 0] + ys[:, 1] * ys[:, 2]) / jnp.maximum(jnp.sum(sol.valid), 1)


@pytest.fixture(scope="module")
def grad_fn():
    return jax.jit(jax.value_and_grad(loss))


@pytest.fixture(scope="module")
def forward_fn():
    return jax.jit(loss)


@pytest.fixture(scope="module")
def smooth(grad_fn):
    p = params0(0.1)
    value, grad = grad_fn(p)
    return p, value, grad


def _bump(p, name, index, eps):
    q = dict(p)
    if name == "y0":
        q["y0"] = p["y0"].at[index].add(eps)
    else:
        q[name] = p[name] + eps
    return q


@pytest.mark.parametrize("name", NAMES)
def test_gradient_matches_central_differences(smooth, forward_fn, name):
    """Relative error ≤ 1e-5 against central differences (τ = 0.1, 41 steps, the run completes)."""
    p, value, grad = smooth
    indices = [0, 1, 2] if name == "y0" else [None]  # v0 = 1e-10·V: its derivative is checked via V
    for index in indices:
        x = p[name] if index is None else p[name][index]
        # y0 = (α0, ω0, u0) are tiny (α0 ≈ 8e-9): a relative step drowns in round-off; use absolute steps.
        eps = (1e-7, 1e-9, 1e-7)[index] if index is not None else 1e-6 * max(abs(float(x)), 1e-3)
        fd = (forward_fn(_bump(p, name, index, eps)) - forward_fn(_bump(p, name, index, -eps))) / (2 * eps)
        g = grad[name] if index is None else grad[name][index]
        assert np.isfinite(float(g))
        # Parameters: 1e-5 relative (the bound). y0 sits at the non-Lipschitz start
        # (ω0 = 1.1e-9): central differences there are good to ~2e-5 only (measured), so 1e-4.
        rel = 1e-5 if index is None else 1e-4
        assert abs(float(g) - float(fd)) <= rel * abs(float(fd)) + 1e-9 * abs(float(value)), (name, index, g, fd)


def test_forward_mode_equals_reverse_mode_and_newton_is_not_unrolled(smooth):
    """jvp(loss)·d = ∇loss·d, and the linearised (tangent) program has no while_loop.

    The tangent program is what reverse mode transposes: without a while_loop in it, neither
    Newton's iterations nor the subdivision retries are differentiated, only one linear
    solve per (sub)step (implicit function theorem).
    """
    p, value, grad = smooth
    rng = np.random.default_rng(1)
    direction = jax.tree_util.tree_map(lambda a: jnp.asarray(rng.standard_normal(np.shape(a))) * jnp.abs(a) * 1e-2, p)
    primal, f_jvp = jax.linearize(jax.jit(loss), p)
    tangent = jax.jit(f_jvp)(direction)
    expected = sum(jnp.sum(grad[k] * direction[k]) for k in p)
    assert float(primal) == pytest.approx(float(value), rel=1e-12)
    assert float(tangent) == pytest.approx(float(expected), rel=1e-9)

    # The reverse pass recomputes each step (uniform_mesh rematerializes them): the linear program
    # holds the steps' Newton loops again, as primal values; none of them may take a tangent.
    tangent_loops, primitives = _loops_on_tangents(jax.make_jaxpr(f_jvp)(direction).jaxpr)
    assert tangent_loops == 0
    assert "scan" in primitives  # the steps are there


def _loops_on_tangents(jaxpr, depends=None, primitives=None):
    """(the while loops with an input that depends on the jaxpr's inputs, the primitives seen):
    dependence followed through scans (to a fixed point over the carry), conds and calls."""
    primitives = set() if primitives is None else primitives
    depends = [True] * len(jaxpr.invars) if depends is None else depends
    tainted = {v for v, d in zip(jaxpr.invars, depends) if d}
    loops = 0

    def on(var):
        return not isinstance(var, jax.extend.core.Literal) and var in tainted

    for eqn in jaxpr.eqns:
        primitives.add(eqn.primitive.name)
        inputs = [on(v) for v in eqn.invars]
        if eqn.primitive.name == "while":
            loops += any(inputs)
            outputs = [any(inputs)] * len(eqn.outvars)
        elif eqn.primitive.name == "scan":
            body, n_consts, n_carry = eqn.params["jaxpr"].jaxpr, eqn.params["num_consts"], eqn.params["num_carry"]
            while True:  # the carry's dependence to a fixed point
                found, _ = _loops_on_tangents(body, inputs, set())
                outs = _outputs_on(body, inputs)
                carry = [a or b for a, b in zip(inputs[n_consts : n_consts + n_carry], outs[:n_carry])]
                if carry == inputs[n_consts : n_consts + n_carry]:
                    break
                inputs = inputs[:n_consts] + carry + inputs[n_consts + n_carry :]
            loops += _loops_on_tangents(body, inputs, primitives)[0]
            outputs = outs
        elif eqn.primitive.name == "cond":
            outputs = [False] * len(eqn.outvars)
            for branch in eqn.params["branches"]:
                loops += _loops_on_tangents(branch.jaxpr, inputs[1:], primitives)[0]
                outputs = [a or b for a, b in zip(outputs, _outputs_on(branch.jaxpr, inputs[1:]))]
        else:
            subs = list(jax.extend.core.jaxprs_in_params(eqn.params))
            for sub in subs:
                same = len(sub.invars) == len(inputs)
                loops += _loops_on_tangents(sub, inputs if same else [any(inputs)] * len(sub.invars), primitives)[0]
            outputs = [any(inputs)] * len(eqn.outvars)
        tainted.update(v for v, d in zip(eqn.outvars, outputs) if d)
    return loops, primitives


def _outputs_on(jaxpr, depends):
    """Which outputs of ``jaxpr`` depend on its inputs marked in ``depends`` (calls: all or none)."""
    tainted = {v for v, d in zip(jaxpr.invars, depends) if d}
    for eqn in jaxpr.eqns:
        if any(not isinstance(v, jax.extend.core.Literal) and v in tainted for v in eqn.invars):
            tainted.update(eqn.outvars)
    return [not isinstance(v, jax.extend.core.Literal) and v in tainted for v in jaxpr.outvars]


def test_stop_early_run_has_finite_gradients(grad_fn):
    """τ = 1e-3 stops at t ≈ 0.17 s (an impasse); the loss over the valid part has finite gradients."""
    p = params0(1e-3)
    sol = trajectory(p)
    assert int(sol.status) != 0 and float(sol.t_stop) < 0.3
    assert not bool(jnp.all(sol.valid))
    value, grad = grad_fn(p)
    leaves = jax.tree_util.tree_leaves(grad)
    assert np.isfinite(float(value))
    assert all(np.all(np.isfinite(np.asarray(g))) for g in leaves)
    assert any(np.any(np.asarray(g) != 0) for g in leaves)


@pytest.mark.slow
def test_checkpointing_keeps_values_and_gradients():
    """checkpoint_every changes neither the trajectory nor the gradient (beyond rounding) (slow:
    two reverse-mode programs compile for ~50 s)."""
    solver = pj.AlphaMethod(max_subdivisions=0)  # a smaller program: this test only checks the chunking
    p = params0(0.1)
    sub = {k: p[k] for k in ("c1", "V")}

    def f(q, chunk):
        return loss({**p, **q}, solver, chunk)

    plain = jax.jit(jax.value_and_grad(lambda q: f(q, None)))(sub)
    chunked = jax.jit(jax.value_and_grad(lambda q: f(q, 6)))(sub)  # 41 = 6·6 + 5: chunks and a tail
    assert float(chunked[0]) == pytest.approx(float(plain[0]), rel=1e-13)
    for k in sub:
        assert float(chunked[1][k]) == pytest.approx(float(plain[1][k]), rel=1e-10)
    a = trajectory(p, solver, None)
    b = trajectory(p, solver, "sqrt")
    np.testing.assert_array_equal(np.asarray(a.ys), np.asarray(b.ys))
    with pytest.raises(ValueError, match="checkpoint_every"):
        trajectory(p, solver, 0)


def test_safe_pow_reverse_mode():
    """safe_pow's custom JVP (symbolic zeros) transposes: grad = the analytic derivative, 0 at x ≤ 0."""
    gx, gp = jax.grad(lambda x, q: pj.safe_pow(x, q), argnums=(0, 1))(2.0, 0.35)
    assert float(gx) == pytest.approx(0.35 * 2.0 ** (-0.65), rel=1e-14)
    assert float(gp) == pytest.approx(2.0**0.35 * np.log(2.0), rel=1e-14)
    g0 = jax.grad(lambda x, q: pj.safe_pow(x, q), argnums=(0, 1))(-1.0, 0.35)
    assert all(float(g) == 0.0 for g in g0)
