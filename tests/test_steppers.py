"""One error-controlled loop, any stepper (issue 27): the α-method and diffrax's Runge–Kutta
solvers through the same loop, against the independent jump reference, with their orders
measured, gradients against central differences and bad input refused before compiling."""

from __future__ import annotations

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import LinearODE
from jump_reference import reference_jump_run

import peeljax as pj
from peeljax.integrators import PIController, RungeKutta, integrate_adaptive, integrator_for, stepper_named
from peeljax.integrators.events import FoldEvents

T_FIRST20 = 0.45  # the first 20 jumps at V = 1.1 happen before 0.41 s


@pytest.fixture(scope="module")
def reference():
    return reference_jump_run(1.1, T_FIRST20, rtol=1e-11, atol=1e-13)


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["alpha", "tsit5", "dopri5", "dopri8", "kvaerno5"])
def test_every_stepper_jumps_as_the_reference(reference, solver):
    """fold='jump' at rtol 1e-8: the reference's jump count and directions, the first 20 jump
    times within 1e-5 s; fold='stop' ends at the first jump's time."""
    sol = pj.simulate(V=1.1, tau=0, t_final=T_FIRST20, rtol=1e-8, atol=1e-11, ts=[0.0, T_FIRST20], solver=solver)
    assert sol.status_name == "completed", sol.reason
    ours = sol.jumps.as_numpy()
    assert ours["jump_t"].size == reference["jump_t"].size >= 20
    np.testing.assert_array_equal(ours["jump_up"], reference["jump_up"])
    assert np.max(np.abs(ours["jump_t"][:20] - reference["jump_t"][:20])) < 1e-5
    stopped = pj.simulate(V=1.1, tau=0, t_final=T_FIRST20, rtol=1e-8, atol=1e-11, ts=[0.0, T_FIRST20], solver=solver,
                          fold="stop")  # fmt: skip
    assert stopped.reason.startswith("a fold of phi was reached")
    assert abs(float(stopped.t_stop) - reference["jump_t"][0]) < 1e-5


def test_tau_zero_defaults_to_tsit5_and_rho_keeps_the_alpha_method():
    assert integrator_for(dae=True, t_final=1.0).settings()["method"] == "diffrax-Tsit5"
    assert integrator_for(dae=True, t_final=1.0, rho=0.5).settings()["method"] == "alpha-adaptive"
    assert integrator_for(t_final=1.0).settings()["method"] == "switching-tsit5-alpha"
    assert integrator_for(t_final=1.0, rho=0.5).settings()["method"] == "alpha-adaptive"
    # the DAE runs in pseudo-time with log v carried (DesingularizedDAE); the α-method carries
    # the DAE's v itself (solved, never integrated); the homogenized ODE log v
    dae = integrator_for(dae=True, t_final=1.0)
    assert dae.carried_log == (3,) and float(dae.stepper.time_scale) == pj.desingularized.DEFAULT_TIME_SCALE
    assert integrator_for("alpha", dae=True, t_final=1.0).carried_log == ()
    assert integrator_for(RungeKutta(diffrax.Tsit5(), ()), dae=True, t_final=1.0).stepper.time_scale is None
    assert integrator_for("tsit5", t_final=1.0).carried_log == (3,)


@pytest.mark.parametrize("solver, order", [("alpha", 2), ("tsit5", 5), ("dopri8", 8)])
def test_each_stepper_has_its_order_in_the_loop(solver, order):
    """On y' = λy, the global error of the loop falls like (accepted steps)^−p, p the method's order."""
    ode = LinearODE(jnp.array([-1.0, -3.0]))
    y0 = jnp.array([1.0, 2.0])
    stepper = stepper_named(solver, dae=True)
    rtols = {"alpha": (1e-4, 1e-5, 1e-6, 1e-7), "tsit5": (1e-5, 1e-6, 1e-7, 1e-8), "dopri8": (1e-6, 1e-7, 1e-8, 1e-9)}
    steps, errors = [], []
    run = jax.jit(lambda c: integrate_adaptive(ode, stepper, y0, 0.0, 2.0, controller=c, ts=jnp.array([2.0])))
    for rtol in rtols[solver]:
        sol = run(PIController(rtol=rtol, atol=rtol * 1e-3))
        steps.append(int(sol.stats["accepted_steps"]))
        errors.append(float(np.max(np.abs(np.asarray(sol.ys[-1]) - np.asarray(y0) * np.exp(2.0 * np.array([-1.0, -3.0]))))))
    slope = -np.polyfit(np.log(steps), np.log(errors), 1)[0]
    # at least the order (a few steps of Dopri8 show a steeper pre-asymptotic slope)
    assert order - 0.6 < slope < order + 3, (steps, errors, slope)


@pytest.mark.slow
def test_tsit5_gradients_match_central_differences():
    """d/dV of v at the end of a homogenized run (τ = 0.1, no fold reached; reverse mode) and of
    a transversal jump time (the first slip's end) of the DAE (forward mode, what the table fit
    uses), against central differences of the runs themselves."""

    # Two compiled programs in all: each derivative's program also gives the differences' values.
    # No fold in the homogenized run: fold="stop" ends nothing (it completes) and compiles no jumps.
    @jax.jit
    @jax.value_and_grad
    def end_v(V):
        sol = pj.simulate(V=V, tau=0.1, t_final=0.2, rtol=1e-10, atol=1e-13, ts=np.array([0.0, 0.2]),
                          solver="tsit5", fold="stop")  # fmt: skip
        return jnp.where(sol.completed, sol.ys[-1, 3], jnp.nan)

    eps = 1e-5
    fd = (end_v(1.1 + eps)[0] - end_v(1.1 - eps)[0]) / (2 * eps)
    assert np.isfinite(float(fd))
    assert float(end_v(1.1)[1]) == pytest.approx(float(fd), rel=1e-5)

    def second_jump(V):
        sol = pj.simulate(V=V, tau=0, t_final=0.18, rtol=1e-11, atol=1e-14, ts=np.array([0.0, 0.18]),
                          solver="tsit5", adjoint="forward", max_jumps=8)  # fmt: skip
        return sol.jumps.t[1] - sol.jumps.t[0]  # the first slip's duration: transversal at its end

    value_and_tangent = jax.jit(lambda V: jax.jvp(second_jump, (V,), (1.0,)))
    eps = 1e-4
    fd = (value_and_tangent(1.1 + eps)[0] - value_and_tangent(1.1 - eps)[0]) / (2 * eps)
    forward = value_and_tangent(1.1)[1]
    assert np.isfinite(float(forward)) and float(forward) != 0.0
    assert float(forward) == pytest.approx(float(fd), rel=2e-3)


def test_bad_solvers_are_refused_before_compiling(no_compilation):
    with pytest.raises(ValueError, match=r"solver must be one of \['auto', 'alpha', 'tsit5'"):
        pj.simulate(V=1.1, tau=0, solver="rk4")
    with pytest.raises(ValueError, match="uniform mesh"):
        pj.simulate(V=1.1, tau=0, solver="tsit5", dt=0.01)
    with pytest.raises(ValueError, match="max_steps must be a positive integer"):
        pj.simulate(V=1.1, tau=0, solver="tsit5", max_steps=2**31)
    with pytest.raises(TypeError, match="Runge-Kutta"):
        RungeKutta(diffrax.ImplicitEuler())


def test_no_wall_at_100_000_attempts_with_output_at_times(no_compilation):
    """max_steps=None: 10⁷ attempts where nothing is kept per step, 100 000 for step output."""
    from peeljax.integrators.select import resolve_max_steps

    assert resolve_max_steps(None, keeps_steps=False) == 10_000_000
    assert resolve_max_steps(None, keeps_steps=True) == 100_000
    assert resolve_max_steps(50, keeps_steps=False) == 50


def test_sweep_lane_is_simulate_with_a_runge_kutta_stepper():
    """A sweep's lane takes the steps and jumps of simulate with the same stepper."""
    res = pj.sweep(V=[1.1], tau=0, t_final=0.3, progress=False, solver="dopri5", rtol=1e-7)
    sol = pj.simulate(V=1.1, tau=0, t_final=0.3, adjoint="forward", max_jumps=2048, solver="dopri5", rtol=1e-7,
                      ts=[0.0, 0.3])  # fmt: skip
    n = int(sol.jumps.count)
    assert n > 5 and int(res.jumps["jump_count"][0]) == n
    np.testing.assert_allclose(res.jumps["jump_t"][0, :n], sol.jumps.as_numpy()["jump_t"], rtol=0, atol=1e-7)
    assert int(res.accepted_steps[0]) == int(sol.stats["accepted_steps"])


def test_fold_events_on_an_implicit_solver_run_in_the_loop():
    """Kvaerno3 (ESDIRK, its Newton tolerances the controller's) through a fold, one jump."""
    ode = pj.ConstrainedDAE(pj.PeelingModel(), 1.1)
    sol = jax.jit(
        lambda: integrate_adaptive(
            ode, RungeKutta(diffrax.Kvaerno3(), ()), pj.PeelingModel().initial_state(1.1), 0.0, 0.167,
            controller=PIController(rtol=1e-7, atol=1e-10), ts=jnp.array([0.0, 0.167]), events=FoldEvents("jump", 4),
        )  # fmt: skip
    )()
    assert int(sol.status) == 0 and int(sol.jumps.count) == 1
    assert float(sol.jumps.t[0]) == pytest.approx(0.16633, abs=2e-4)
