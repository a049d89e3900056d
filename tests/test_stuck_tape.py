"""The fully stuck tape at τ > 0 (issue 30, item 3): below the floor v_s = 1e-12·V the
homogenized ODE continues φ linearly in log v (``peeljax.homogenized``), so a run through a
stuck phase neither stalls nor differs from the DAE's (τ = 0) by more than O(τ), a run that
stays above the floor is unchanged bit for bit, and gradients through a stuck phase are finite
and match central differences."""

from __future__ import annotations

import functools

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import peeljax as pj
from peeljax.homogenized import STUCK_FLOOR_FACTOR, Evaluation, _jump, floor_of
from peeljax.integrators import RungeKutta, integrator_for
from peeljax.model import PAPER_ALPHA0, PAPER_V0_FACTOR
from peeljax.simulate import _run
from peeljax.structure import jacobians, schur_complement
from peeljax._arrays import float_array

MODEL = pj.PeelingModel()
V = 1.1
FLOOR = STUCK_FLOOR_FACTOR * V


@functools.cache
def _folds():
    return eqx.filter_jit(pj.phi_folds)(MODEL, V)  # compiled: eagerly its search loops take seconds


def _stuck_start(G0: float, tau: float):
    """A fully stuck tape at G = G0 < φ(0⁺, V): v_low at τ = 0 (the DAE), on ψ's continuation at τ > 0."""
    x0 = jnp.array([PAPER_ALPHA0, 0.0, float(MODEL.stretch_for_force(PAPER_ALPHA0, G0))])
    v0 = _folds().v_low if tau == 0 else pj.HomogenizedODE(MODEL, V, tau).stuck_velocity(x0)
    return jnp.concatenate([x0, jnp.asarray(v0)[None]])


def _simulate(tau: float, t_final: float, y0, **options):
    """pj.simulate at V = 1.1 with output at 1001 times and y0 given: every forward α-method run of
    this module has the same compiled shape (tolerances, τ and t_final are traced), so it compiles once."""
    return pj.simulate(V=V, tau=tau, t_final=t_final, y0=y0, ts=np.linspace(0.0, t_final, 1001), **options)


def _shear(ys):
    return np.asarray(jax.vmap(lambda y: MODEL.shear_force(y[:3]))(jnp.asarray(ys)))


def test_phi_is_continued_below_the_floor_c1_and_linear_in_log_v():
    continued = pj.HomogenizedODE(MODEL, V, 3.3e-3).continued_model
    v_s, phi_s, slope = floor_of(MODEL.adhesion, V)
    assert float(v_s) == FLOOR and float(phi_s) == float(MODEL.phi(FLOOR, V))

    def log_slope(phi, v):
        return float(jax.jvp(lambda w: phi(jnp.exp(w), V), (jnp.log(v),), (1.0,))[1])

    # C¹ at the floor: value and ∂/∂(log v) from both sides agree (the ψ of a step across it is continuous)
    below = FLOOR * (1 - 1e-9)
    np.testing.assert_allclose(float(continued.phi(below, V)), float(MODEL.phi(below, V)), rtol=1e-15)
    np.testing.assert_allclose(log_slope(continued.phi, below), log_slope(MODEL.phi, FLOOR), rtol=1e-8)
    # above it φ itself, bit for bit; below it linear in log v, increasing, finite as v → 0
    for v in (FLOOR, 1e-6, 0.3, 9.0):
        assert float(continued.phi(v, V)) == float(MODEL.phi(v, V))
    for v in (1e-20, 1e-60, 1e-200):
        np.testing.assert_allclose(float(continued.phi(v, V)), float(phi_s + slope * np.log(v / FLOOR)), rtol=1e-12)
        np.testing.assert_allclose(log_slope(continued.phi, v), float(slope), rtol=1e-12)
    # the slope at the floor (0.27 N): 1.8 N of φ lie between v_s and v → 0⁺ (φ(0⁺) = 127.69 N at V = 1.1)
    assert 0.25 < float(slope) < 0.3 and 1.7 < float(phi_s - _folds().phi_zero) < 1.9


def test_a_stuck_state_moves_as_with_v_zero_at_a_bounded_rate_and_a_jump_lands_on_it():
    tau = 3.3e-3
    y = _stuck_start(100.0, tau)  # 29.5 N below φ(v_s): 108 e-folds below the floor
    v = float(y[3])
    _, phi_s, slope = floor_of(MODEL.adhesion, V)
    np.testing.assert_allclose(np.log(v / FLOOR), (100.0 - float(phi_s)) / float(slope), rtol=1e-12)

    @jax.jit
    def at(y):  # compiled: φ's folds and the jump's root search are loops
        ode = pj.HomogenizedODE(MODEL, V, tau).with_folds()
        return ode.evaluate(y), ode.jump(y.at[3].set(9.0))

    evaluation, jump = at(y)
    assert np.all(np.isfinite(np.asarray(evaluation.psi)))
    np.testing.assert_allclose(np.asarray(evaluation.psi[:3]), np.asarray(MODEL.f(y[:3], 0.0, V)), rtol=1e-12, atol=1e-20)
    # d(log v)/dt = F̃·f/(K + O(τ·v)): G's rate over the continuation's slope, not ~v^(−0.15)
    np.testing.assert_allclose(float(evaluation.psi[3]) / v, float(evaluation.drive) / float(slope), rtol=1e-9)
    # J_t reported at its floor value (same sign, bounded): the impasse predictor sees no impasse
    assert -1e12 < float(evaluation.J) < -1e11  # −K/v_s
    # a jump down from the slip branch at this x lands there; the record says "fully stuck" (0)
    assert not bool(jump.up) and float(jump.v_after) == 0.0
    np.testing.assert_allclose(float(jump.y[3]), v, rtol=1e-12)


@pytest.mark.slow
def test_the_stuck_phases_approach_the_dae_as_tau_goes_to_zero():
    """From G = 100 N, 27.7 N below φ(0⁺, 1.1), the pull raises G at ~1100 N/s: the tape is stuck
    until ~0.025 s, then leaves. The time v passes 1e-9 m/s (just off the floor) is the DAE's
    to 4e-9 s whatever τ; the time v passes 1e-3 m/s (the tape moving) differs from the DAE's by
    O(τ): measured 2.3e-5, 7.5e-6, 2.5e-6 s at τ = 1e-2, 3e-3, 1e-3 (order 0.93, 0.99)."""
    ts = np.linspace(0.0, 0.1, 1001)
    taus = (0.0, 1e-2, 3e-3, 1e-3)

    def crossing(sol, level):  # the first upward crossing, log-linear between output times
        v = np.asarray(sol.v)
        k = int(np.flatnonzero(v > level)[0])
        theta = np.log(level / v[k - 1]) / np.log(v[k] / v[k - 1])
        return ts[k - 1] + theta * (ts[k] - ts[k - 1])

    leave, moving = {}, {}
    for tau in taus:
        # τ = 0: the DAE in time, whose every output solves v (in pseudo-time an output inside
        # the step that releases the tape keeps the stuck v: 1.2e-8 m/s at most there)
        in_time = {"solver": RungeKutta(diffrax.Tsit5(), ())} if tau == 0 else {}
        sol = _simulate(tau, 0.1, _stuck_start(100.0, tau), rtol=1e-8, atol=1e-11, **in_time)
        assert sol.status_name == "completed"
        G, v = _shear(sol.ys), np.asarray(sol.v)
        stuck = ts <= 0.02
        assert np.all(G[stuck] < float(_folds().phi_zero)) and np.all(v[stuck] < 1e-15)
        assert np.all(np.diff(G[stuck]) > 0)  # the pull loads the stuck tape
        leave[tau], moving[tau] = crossing(sol, 1e-9), crossing(sol, 1e-3)
    assert 0.029 < leave[0.0] < 0.031 and 0.08 < moving[0.0] < 0.085
    for tau in taus[1:]:
        assert abs(leave[tau] - leave[0.0]) < 1e-8
    errors = np.array([abs(moving[tau] - moving[0.0]) for tau in taus[1:]])
    orders = np.log(errors[:-1] / errors[1:]) / np.log(np.array(taus[1:-1]) / np.array(taus[2:]))
    assert np.all(np.diff(errors) < 0) and np.all((orders > 0.7) & (orders < 1.3)), (errors, orders)


@pytest.mark.slow
def test_the_failing_command_runs_to_t_final():
    """``peeljax simulate --V 1.1 --tau 0.0033 --t-final 3`` stopped at t = 0.388 s (step size
    collapsed, v = 5e-54) after 8972 accepted steps; it now completes, through 98 jumps of which
    several land fully stuck."""
    # the CLI's settings (output at 1001 times rather than the steps: the same steps)
    sol = _simulate(0.0033, 3.0, MODEL.initial_state(V))
    assert sol.status_name == "completed" and float(sol.t_stop) == 3.0
    assert np.asarray(sol.v).min() < 1e-20  # it went through stuck phases
    jumps = sol.jumps.as_numpy()
    assert jumps["jump_t"].size > 50 and np.sum(jumps["jump_v_after"] == 0.0) >= 2


@pytest.mark.slow
def test_a_sweep_lane_through_a_stuck_phase_completes():
    """The README's sweep lane at V = 1.1, τ = 3.3e-3 stopped at 0.388 s; over [0, 0.5] s it
    lands fully stuck twice and completes."""
    res = pj.sweep(V=1.1, tau=3.3e-3, t_final=0.5, progress=False)
    assert bool(res.completed[0]) and float(res.t_stop[0]) == 0.5
    jumps = res.jumps
    n = int(jumps["jump_count"][0])
    assert n >= 10 and np.sum(jumps["jump_v_after"][0, :n] == 0.0) >= 2


class _PlainODE(pj.HomogenizedODE):
    """The homogenized ODE as it was before the floor: φ itself everywhere, jumps lifted to v_s."""

    def evaluate(self, y):
        jac = jacobians(self.model, y[:3], y[3], self.V)
        J = schur_complement(jac, self.tau)
        drive = jnp.dot(jac.F_tilde, jac.f)
        return Evaluation(psi=jnp.concatenate([jac.f, (-drive / J)[None]]), J=J, drive=drive)

    def jump(self, y):
        return _jump(self.model, self.V, self.folds, y, floor=PAPER_V0_FACTOR * self.V)


@pytest.mark.slow
def test_a_run_that_never_sticks_is_unchanged():
    """V = 2, τ = 3e-3 from the paper's start (100× above the floor) over 0.15 s: stick, slip at
    0.139 s and re-stick above the floor at 0.144 s; every state and jump time is the same bit for
    bit with and without the floor."""
    t_final, V_ = 0.15, 2.0
    y0, ts = MODEL.initial_state(V_), np.linspace(0.0, t_final, 1001)
    integrator = integrator_for(None, t_final=t_final, max_steps=10_000_000)  # simulate's, with ts
    new = pj.simulate(V=V_, tau=3e-3, t_final=t_final, y0=y0, ts=ts)
    old = _run(integrator, _PlainODE(MODEL, V_, 3e-3), y0, float_array(t_final), jnp.asarray(ts)).without_padding()
    assert new.status_name == old.status_name == "completed" and int(new.stats["jumps"]) >= 2
    assert np.asarray(new.v).min() >= V_ * PAPER_V0_FACTOR
    np.testing.assert_array_equal(np.asarray(new.ys), np.asarray(old.ys))
    np.testing.assert_array_equal(new.jumps.as_numpy()["jump_t"], old.jumps.as_numpy()["jump_t"])


@pytest.mark.slow
def test_gradients_through_a_stuck_phase_are_finite_and_match_central_differences():
    """jax.grad with respect to c1 and V of a loss at 0.03 s, after a stuck phase of ~0.011 s
    from G = 115 N (τ = 3e-3): the depth below the floor, the time the tape leaves and its climb
    are all differentiated (asserted to 1e-4 of central differences at rtol 1e-10: 5e-5 measured;
    at rtol 1e-8 the differences' own noise is 2e-4)."""
    tau, t_final = 3e-3, 0.03

    def loss(params):
        c1, V_ = params[0], params[1]
        model = eqx.tree_at(lambda m: m.adhesion.c1, MODEL, c1)
        x0 = jnp.array([PAPER_ALPHA0, 0.0, model.stretch_for_force(PAPER_ALPHA0, 115.0)])
        y0 = jnp.concatenate([x0, pj.HomogenizedODE(model, V_, tau).stuck_velocity(x0)[None]])
        ts = np.linspace(0.0, t_final, 1001)
        sol = pj.simulate(model, V_, tau, t_final=t_final, y0=y0, ts=ts, rtol=1e-10, atol=1e-13)
        y = sol.ys[-1]
        return jnp.log(y[3]) + 1e3 * y[2], y[3]

    p0 = jnp.array([400.0, V])
    value_and_grad = jax.jit(jax.value_and_grad(loss, has_aux=True))  # one program: also the differences' values
    (_, v_final), grad = value_and_grad(p0)
    assert float(v_final) > 1e-7  # it left the floor
    grad = np.asarray(grad)
    assert np.all(np.isfinite(grad))
    eps = np.array([0.04, 1e-4])

    def value(p):
        return float(value_and_grad(p)[0][0])

    central = [(value(p0.at[k].add(eps[k])) - value(p0.at[k].add(-eps[k]))) / (2 * eps[k]) for k in range(2)]
    np.testing.assert_allclose(grad, central, rtol=1e-4)
