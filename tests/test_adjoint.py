"""Reverse mode by tangents of the few perturbed inputs (``peeljax/integrators/adjoint.py``).

``jax.grad`` of a run with the default ``adjoint="reverse"`` takes k ≤ limit tangents of the
plain loop (the run's forward mode) and contracts the cotangent with them; more perturbed
numbers take the checkpointed loop's pullback. Both are checked here against forward mode.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import peeljax as pj
from peeljax.integrators.adjoint import reverse_by_tangents


def _toy(kinds):
    """A 'run': a loop of the given kind, recorded at trace time; its output has an integer, a
    string and a NaN row (past a stop; its tangent is NaN too in the plain loop, as where a
    stopped run's NaN state goes on through arithmetic)."""

    def solve(inputs, kind):
        kinds.append(kind)
        x, y = inputs
        padding = jnp.nan * x if kind == "lax" else jnp.full_like(x, jnp.nan)
        rows = jnp.stack([x**2 * y[0], jnp.sin(y[1]) * x, padding])
        return {"rows": rows, "count": jnp.asarray(3), "label": "toy"}

    return solve


@pytest.mark.parametrize("limit, kind", [(3, "lax"), (2, "checkpointed")])
def test_tangents_or_the_checkpointed_pullback_by_the_number_perturbed(limit, kind):
    kinds = []
    solve = _toy(kinds)
    x, y = jnp.asarray(1.5), jnp.array([2.0, 0.3])

    def loss(x, y):
        out = reverse_by_tangents(solve, (x, y), limit)
        assert out["label"] == "toy" and int(out["count"]) == 3
        return out["rows"][0] + 2.0 * out["rows"][1]  # the NaN row gets a zero cotangent

    gx, gy = jax.grad(loss, argnums=(0, 1))(x, y)  # 3 perturbed numbers
    assert kinds[-1] == kind
    np.testing.assert_allclose(gx, 2 * x * y[0] + 2 * jnp.sin(y[1]), rtol=1e-14)
    np.testing.assert_allclose(gy, [x**2, 2 * x * jnp.cos(y[1])], rtol=1e-14)
    # one perturbed number takes tangents (limit ≥ 1)
    kinds.clear()
    g = jax.grad(lambda x: loss(x, y))(x)
    assert kinds[-1] == "lax"
    np.testing.assert_allclose(g, gx, rtol=1e-14)
    # without a derivative the plain loop runs
    kinds.clear()
    reverse_by_tangents(solve, (x, y), limit)
    assert kinds == ["lax"]


# The runs below: 0.05 s at τ = 0.01, which reach no fold (a run stopped at one would end in NaN
# with NaN derivatives, which the finiteness checks refuse). The default stepper ("auto": Tsit5,
# switching to the α-method where the ODE turns stiff) takes Tsit5 throughout them, so Tsit5 with
# fold="stop" is the same run (the same derivatives, measured) in programs without the switch and
# the jump machinery, which compile ~4× faster (the forward-mode program 15 s against 62 s for
# "auto" with "stop", under load). The dispatch (tangents or the checkpointed loop,
# ``peeljax/simulate.py``) is the same for every stepper and fold policy; "auto"'s checkpointed
# pullback through 14 jumps: ``tests/test_gradient_matrix.py::test_reverse_mode_is_forward_mode``.
RUN = {"V": 1.1, "tau": 0.01, "t_final": 0.05, "ts": jnp.array([0.0, 0.05]), "solver": "tsit5", "fold": "stop"}


def _run(c1, adjoint, **law):
    model = pj.PeelingModel(adhesion=eqx.tree_at(lambda a: a.c1, pj.AdhesionLaw(**law), c1))
    return pj.simulate(model, adjoint=adjoint, **RUN).ys[-1]


@pytest.mark.slow
def test_grad_of_a_run_is_its_forward_mode():
    """One φ coefficient perturbed: reverse mode is the forward-mode derivative of the same
    program (tangents), to round-off (slow: 40 s on 2 busy cores, compiling both
    derivative programs; the fast tier checks the dispatch on a toy run above)."""
    c1 = jnp.asarray(400.0)
    reverse = jax.jacrev(lambda c: _run(c, "reverse"))(c1)
    forward = jax.jacfwd(lambda c: _run(c, "forward"))(c1)
    assert np.all(np.isfinite(reverse)) and np.max(np.abs(reverse)) > 0
    np.testing.assert_allclose(reverse, forward, rtol=1e-12, atol=1e-15 * float(np.max(np.abs(forward))))


@pytest.mark.slow
def test_many_perturbed_numbers_take_the_checkpointed_loop_and_agree():
    """All 14 of φ's coefficients perturbed (more than the limit): the checkpointed loop's pullback,
    the same derivative as forward mode of the plain loop (slow: 50 s on 2 busy cores, mostly
    compiling the checkpointed program; the fast tier checks the dispatch on a toy run above)."""

    def end(law, adjoint):
        return pj.simulate(pj.PeelingModel(adhesion=law), adjoint=adjoint, **RUN).ys[-1, 3]

    law = pj.AdhesionLaw()
    reverse = eqx.filter_grad(lambda l: end(l, "reverse"))(law)
    forward = eqx.filter_jacfwd(lambda l: end(l, "forward"))(law)
    r = np.array(jax.tree.leaves(eqx.filter(reverse, eqx.is_inexact_array)))
    f = np.array(jax.tree.leaves(eqx.filter(forward, eqx.is_inexact_array)))
    assert r.size == 14 and np.all(np.isfinite(r))
    np.testing.assert_allclose(r, f, rtol=1e-7, atol=1e-10 * np.max(np.abs(f)))
