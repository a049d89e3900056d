"""Gradients through the jumps: jump times and forces against central differences.

The derivative of a jump time is the implicit function theorem's on its fold event (on
ġ = 0 at the tangential first slip); see docs/fitting.md "Gradients through the jumps" for the
measured agreement at tighter tolerances than run here.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import peeljax as pj
from peeljax.adhesion import AdhesionLaw

RTOL = 1e-10


def _simulate(p, *, t_final, y0=None, adjoint="reverse", rtol=RTOL):
    law = eqx.tree_at(lambda a: a.c1, AdhesionLaw(), p[0])
    model = pj.PeelingModel(adhesion=law)
    return pj.simulate(
        model, V=p[1], tau=0.0, t_final=t_final, rtol=rtol, atol=rtol * 1e-3, ts=jnp.array([0.0, t_final]),
        adjoint=adjoint, max_jumps=64, max_steps=400_000, y0=y0,
    )  # fmt: skip


def _jumps(p, **options):
    return _simulate(p, **options).jumps


def _central(f, p, k, eps):
    e = np.zeros(2)
    e[k] = eps
    return (np.asarray(f(p + e)) - np.asarray(f(p - e))) / (2 * eps)


@pytest.mark.slow
def test_first_jump_times_and_force_drop_match_central_differences():
    """From the paper's start (its first slip is tangential: a folded singularity): the first
    8 jump times and the first slip's force drop, d/dc1 and d/dV, reverse mode."""
    p0 = jnp.array([400.0, 1.1])

    def quantities(p):
        jumps = _jumps(p, t_final=0.22)
        return jnp.concatenate([jumps.t[:8], (jumps.F[0] - jumps.F[1])[None]])

    jac = np.asarray(jax.jacrev(quantities)(p0))
    for k, eps, tol in ((0, 0.1, 3e-3), (1, 1e-4, 5e-3)):
        fd = _central(quantities, p0, k, eps)
        assert np.all(np.isfinite(jac[:, k]))
        np.testing.assert_allclose(jac[:, k], fd, rtol=tol)
    # the first slip comes later with a larger c1 (φ's maximum rises)
    assert jac[0, 0] > 0


@pytest.mark.slow
def test_transversal_jumps_agree_in_both_modes_and_with_differences():
    """From a state on the cycle every jump is transversal: reverse mode through the checkpointed
    loop and forward mode agree, and both match central differences."""
    p0 = jnp.array([400.0, 1.1])
    # the program of the previous test's central differences (t_final is traced)
    start = _simulate(p0, t_final=0.175)
    assert start.status_name == "completed"
    y0 = start.ys[-1]

    def times(p, adjoint="reverse"):
        return _jumps(p, t_final=0.05, y0=y0, adjoint=adjoint).t[:4]

    def value_and_tangent(c):  # the differences' values: this program's primal outputs (none of their own)
        return jax.jvp(lambda c: times(jnp.array([c, 1.1]), "forward"), (c,), (1.0,))

    reverse = np.asarray(jax.jacrev(lambda p: times(p, "checkpointed"))(p0))[:, 0]
    forward = np.asarray(value_and_tangent(400.0)[1])
    np.testing.assert_allclose(reverse, forward, rtol=1e-3)  # measured: 2.2e-4 at the 4th jump
    h = 0.1
    central = (np.asarray(value_and_tangent(400.0 + h)[0]) - np.asarray(value_and_tangent(400.0 - h)[0])) / (2 * h)
    np.testing.assert_allclose(reverse, central, rtol=2e-3)


@pytest.mark.slow
def test_jump_ending_a_slow_slip_tangentially_matches_central_differences():
    """V = 4.9: a 123 ms slip near the unstable steady sliding ends at φ's minimum with Ġ → 0
    (jump 81 from the paper's start; jumps 80 and 82 around it). Its time's derivative is taken
    from two reference states before the fold, extrapolated to the fold (tangential_fold); from
    the single reference 1e-3·rtol deep it was 1.2e2 off (relative) at rtol 1e-8, measured
    5.1e-3 now."""
    p0 = jnp.array([400.0, 4.9])

    def times(p, rtol=1e-8):
        law = eqx.tree_at(lambda a: a.c1, AdhesionLaw(), p[0])
        sol = pj.simulate(
            pj.PeelingModel(adhesion=law), V=p[1], tau=0.0, t_final=0.22, rtol=rtol, atol=rtol * 1e-2,
            ts=jnp.array([0.0, 0.22]), adjoint="forward", max_jumps=256, max_steps=400_000,
        )  # fmt: skip
        return sol.jumps.t[80:83]

    forward = np.asarray(jax.jvp(lambda c: times(jnp.array([c, 4.9])), (400.0,), (1.0,))[1])
    fd = _central(lambda p: times(p, 1e-12), p0, 0, 2.5e-6)
    assert np.all(np.isfinite(forward))
    np.testing.assert_allclose(forward, fd, rtol=2e-2)
