"""Where a derivative does not exist, the gradient says so: NaN, with the reason in the result.

Two cases: the values a run did not reach (rows past a stop, jump slots it did not fill: NaN
values, whose derivative used to be a finite 0), and whatever follows a grazing of a fold within
the run's error (a jump appears or vanishes under any perturbation: ``stats["grazed_at"]``).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import peeljax as pj

TS = jnp.array([0.0, 0.3, 0.6])


def _v_at(sol, t):
    """v at the output row of time t (not a jump's row; the rows' layout differs under tracing)."""
    return sol.ys[jnp.argmax((sol.ts == t) & ~sol.after_jump), 3]


@pytest.mark.parametrize("adjoint", ["reverse", pytest.param("checkpointed", marks=pytest.mark.slow), "forward"])
def test_values_past_a_stop_have_nan_derivatives_and_those_before_it_do_not(adjoint):
    def run(c1):
        model = eqx.tree_at(lambda m: m.adhesion.c1, pj.PeelingModel(), c1)
        return pj.simulate(model, V=1.1, tau=0.0, t_final=0.5, ts=jnp.array([0.0, 0.1, 0.5]), max_steps=50,
                           adjoint=adjoint)  # fmt: skip

    sol = run(400.0)
    assert sol.status == pj.StopReason.MAX_STEPS and np.asarray(sol.valid).tolist() == [True, True, False]
    assert int(sol.jumps.count) == 0
    if adjoint == "forward":
        derivative = lambda q: jax.jvp(lambda c: q(run(c)), (400.0,), (1.0,))[1]  # noqa: E731
    else:
        derivative = lambda q: jax.grad(lambda c: q(run(c)))(400.0)  # noqa: E731
    before, after = derivative(lambda s: s.ys[1, 3]), derivative(lambda s: s.ys[2, 3])
    assert np.isfinite(before) and before != 0.0
    assert np.isnan(after)  # was 0.0: a finite wrong number
    assert np.isnan(derivative(lambda s: s.jumps.t[0]))  # a slot the run did not fill
    # a gradient of what exists stays finite, whatever NaN values sit beside it
    assert np.isfinite(derivative(lambda s: jnp.sum(jnp.where(s.valid, s.ys[:, 3], 0.0))))


def _grazing_speed():
    """1e-6 m/s below the speed (found to 1e-15) where two jumps appear in 0.6 s at τ = 0: the
    tape comes back towards a fold and turns away within ~1e-7 of its scale, well inside the
    grazing threshold (1e-5 at rtol 1e-6) and well outside round-off (programs that differ in it,
    as a jitted and a plain call do, would take different sides at 1e-15)."""
    simulator = pj.Simulator(pj.PeelingModel(), t_final=0.6, ts=jnp.array([0.0, 0.6]))
    jumps = lambda V: int(simulator(V=V, tau=0.0).stats["jumps"])  # noqa: E731
    low, high = 1.100, 1.102
    assert jumps(low) == 34 and jumps(high) == 36
    for _ in range(42):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if jumps(middle) == 34 else (low, middle)
    return low - 1e-6


def _grazing_run(V, adjoint="reverse"):
    return pj.simulate(V=V, tau=0.0, t_final=0.6, ts=TS, adjoint=adjoint)


def test_a_grazing_within_the_runs_error_makes_what_follows_it_undefined():
    """Forward mode; reverse mode is the next test (slow: its programs compile for ~30 s)."""
    V = _grazing_speed()
    sol = _grazing_run(V)
    stats = {k: float(v) for k, v in sol.stats.items()}
    assert 1e-9 < stats["fold_closest_miss"] < 1e-6, stats  # of the fold distance's scale
    assert stats["grazed_at"] == stats["fold_closest_miss_t"]
    assert 0.3 < stats["grazed_at"] < 0.6, stats
    tangent = jax.jvp(lambda V: jnp.stack([_v_at(_grazing_run(V, "forward"), t) for t in (0.3, 0.6)]), (V,), (1.0,))[1]
    assert np.isfinite(tangent[0]) and np.isnan(tangent[1])


@pytest.mark.slow
def test_a_grazing_makes_what_follows_it_undefined_in_reverse_mode():
    V = _grazing_speed()
    gradient = jax.jacrev(lambda V: jnp.stack([_v_at(_grazing_run(V), 0.3), _v_at(_grazing_run(V), 0.6)]))(V)
    assert np.isfinite(gradient[0]) and np.isnan(gradient[1])
    # the jump record: the jumps before the grazing keep their derivatives
    sol = _grazing_run(V)
    n = int(sol.jumps.count)
    assert np.all(np.asarray(sol.jumps.t[:n]) < float(sol.stats["grazed_at"]))
    assert np.all(np.isfinite(np.asarray(jax.jacrev(lambda V: _grazing_run(V).jumps.t[:n])(V))))


def test_a_near_miss_outside_the_runs_error_keeps_its_derivatives():
    # V = 1.1: the same slip's end misses the fold by 1.9e-4 of its scale (~0.015 N), above the
    # grazing threshold (10·rtol): the derivative exists and is the central difference's
    sol = pj.simulate(V=1.1, tau=0.0, t_final=0.6, ts=TS)
    stats = {k: float(v) for k, v in sol.stats.items()}
    assert 1e-4 < stats["fold_closest_miss"] < 1e-3 and np.isnan(stats["grazed_at"]), stats
    end = lambda V: _v_at(pj.simulate(V=V, tau=0.0, t_final=0.6, ts=TS, rtol=1e-10, atol=1e-13), 0.6)  # noqa: E731
    gradient = float(jax.grad(end)(1.1))
    h = 1e-6
    difference = (float(end(1.1 + h)) - float(end(1.1 - h))) / (2 * h)
    assert abs(gradient - difference) < 1e-4 * abs(difference), (gradient, difference)


@pytest.mark.slow
def test_a_singular_passage_followed_makes_what_follows_it_undefined():
    """(slow: compiles fold="follow"'s programs.) jax.grad's default (``adjoint="reverse"``: with
    one parameter it takes tangents through the plain loop); ``adjoint="forward"`` is the same
    tangent computation (``tests/test_adjoint.py``), and its own program here was cut for CI's time."""
    # fold="follow" at τ = 1e-3 follows the first slip's singular passage (J_t and F̃·f vanish
    # together, t = 0.1729 s): one of several solutions of the DAE there, chosen by round-off.
    # Measured (rtol 1e-10): v(0.18 s) over c1 ± 0.04 in 17 steps scatters over 3 % (1.387 to 1.428 m/s) with no trend.
    def run(c1, adjoint="reverse"):
        model = eqx.tree_at(lambda m: m.adhesion.c1, pj.PeelingModel(), c1)
        return pj.simulate(model, V=1.1, tau=1e-3, t_final=0.18, ts=jnp.array([0.0, 0.15, 0.18]), fold="follow",
                           adjoint=adjoint)  # fmt: skip

    sol = run(400.0)
    assert sol.status_name == "completed"
    assert 0.15 < float(sol.stats["singular_passage_at"]) < 0.18

    def before_and_after(sol):  # both output rows from one run (one run per mode differentiated)
        return jnp.stack([_v_at(sol, 0.15), _v_at(sol, 0.18)])

    gradient = jax.jacrev(lambda c: before_and_after(run(c)))(400.0)
    assert np.isfinite(gradient[0]) and np.isnan(gradient[1])
    # with the default fold="jump" the same instant is a jump, and no passage is recorded
    assert np.isnan(float(pj.simulate(V=1.1, tau=1e-3, t_final=0.18, ts=jnp.array([0.0, 0.18])).stats["singular_passage_at"]))
