"""The switching stepper (``solver="auto"``, τ > 0): Tsit5 while the homogenized ODE is non-stiff,
the α-method where it is stiff. Its stiffness estimates against exact values, the long runs that
exhausted Tsit5 finished in fewer attempts than the α-method alone, the stats, the accuracy of a
run that switched, and (slow) derivatives through a switch against central differences."""

from __future__ import annotations

import json

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import run_cli

import peeljax as pj
from peeljax.integrators import SwitchingStepper, integrator_for
from peeljax.integrators.switching import TSIT5_STABILITY_BOUND, spectral_radius_bound, tsit5_stiffness


def _tsit5_stability_function(z: complex) -> complex:
    tableau = diffrax.Tsit5.tableau
    stages = len(tableau.a_lower) + 1
    A = np.zeros((stages, stages))
    for i, row in enumerate(tableau.a_lower):
        A[i + 1, : len(row)] = np.asarray(row)
    b = np.asarray(tableau.b_sol)
    return 1 + z * b @ np.linalg.solve(np.eye(stages) - z * A, np.ones(stages))


def test_the_stability_bound_is_where_tsit5_stops_being_stable():
    assert abs(_tsit5_stability_function(-0.99 * TSIT5_STABILITY_BOUND)) < 1
    assert abs(_tsit5_stability_function(-1.01 * TSIT5_STABILITY_BOUND)) > 1
    assert abs(abs(_tsit5_stability_function(-TSIT5_STABILITY_BOUND)) - 1) < 1e-2


@pytest.mark.parametrize("h", [1e-3, 0.01, 0.05])
def test_hairers_estimate_is_h_times_the_eigenvalue_on_a_linear_ode(h):
    lam = -100.0
    term = diffrax.ODETerm(lambda t, y, args: lam * y)
    solver = diffrax.Tsit5()
    y0 = jnp.array([1.0, -2.0])
    state = solver.init(term, 0.0, h, y0, None)
    *_, dense, _, _ = solver.step(term, 0.0, h, y0, None, state, False)
    interpolation = solver.interpolation_cls(t0=0.0, t1=h, **dense)
    np.testing.assert_allclose(float(tsit5_stiffness(interpolation, jnp.ones(2))), abs(lam) * h, rtol=1e-10)


def test_the_spectral_radius_bound_is_an_upper_bound_close_to_it():
    rng = np.random.default_rng(0)
    for _ in range(20):
        M = rng.normal(size=(4, 4))
        scale = 10.0 ** rng.uniform(-6, 2, size=4)
        badly_scaled = M * scale[:, None] / scale[None, :]  # the same eigenvalues, a norm 10⁸ larger
        rho = np.max(np.abs(np.linalg.eigvals(M)))
        bound = float(spectral_radius_bound(jnp.asarray(badly_scaled), jnp.asarray(scale)))
        assert rho * (1 - 1e-12) <= bound <= 1.2 * rho


def test_auto_is_the_switching_stepper_at_tau_above_zero_and_the_dae_default_at_zero():
    assert integrator_for("auto", t_final=1.0).settings()["method"] == "switching-tsit5-alpha"
    assert integrator_for("auto", dae=True, t_final=1.0).settings() == integrator_for(dae=True, t_final=1.0).settings()
    with pytest.raises(ValueError, match="'auto'"):
        integrator_for("automatic", t_final=1.0)
    with pytest.raises(ValueError, match="to_stiff"):
        SwitchingStepper(to_stiff=0)
    with pytest.raises(ValueError, match="tau > 0"):
        integrator_for(SwitchingStepper(), dae=True, t_final=1.0)


def test_the_command_line_names_the_switching_stepper():
    code, out, err = run_cli(["simulate", "--tau", "0.1", "--t-final", "0.2", "--solver", "auto", "--json"])
    assert code == 0, err
    record = json.loads(out)
    assert record["method"] == "switching-tsit5-alpha" and record["method_option"] == "auto"
    code, out, err = run_cli(["simulate", "--tau", "0.1", "--t-final", "0.2", "--json"])
    assert code == 0, err
    assert json.loads(out)["method"] == "switching-tsit5-alpha"


def _attempts(sol) -> int:
    return int(sol.stats["accepted_steps"]) + int(sol.stats["rejected_steps"])


@pytest.mark.parametrize("V, tau, t_final", [(1.1, 0.01, 1e9), (4.0, 0.1, 1e5)])
def test_long_runs_switch_to_the_alpha_method_and_take_fewer_attempts(V, tau, t_final):
    """Tsit5 alone used up 10⁷ attempts on the 10⁹ s run and 2.9·10⁶ on the 10⁵ s one
    (``benchmarks/results/switching.md``): once v has settled its steps stay ~τ."""
    ts = np.linspace(0.0, t_final, 5)
    auto = pj.simulate(V=V, tau=tau, t_final=t_final, ts=ts, solver="auto")
    alpha = pj.simulate(V=V, tau=tau, t_final=t_final, ts=ts, solver="alpha")
    assert auto.status_name == alpha.status_name == "completed"
    assert _attempts(auto) <= 2 * _attempts(alpha)
    stats = auto.stats
    assert int(stats["tsit5_steps"]) + int(stats["alpha_steps"]) == int(stats["accepted_steps"])
    assert int(stats["stepper_switches"]) >= 1 and int(stats["alpha_steps"]) > 0
    assert 0 < float(stats["first_switch_at"]) <= float(stats["last_switch_at"]) < t_final
    # the same steady peeling (α → 0 is a neutral direction: where it ends depends on the path
    # to within the runs' error, rtol 1e-6; measured 6e-6 relative in u at V = 1.1)
    np.testing.assert_allclose(np.asarray(auto.ys[-1]), np.asarray(alpha.ys[-1]), rtol=1e-4, atol=1e-9)


def test_a_run_that_switched_is_as_accurate_as_its_tolerance():
    """P1 (V = 1.1, τ = 0.01, 3 s) switches to the α-method once v settles (at ~2.6 s): v within
    1e-4 of a tight α-method run on every output time."""
    ts = np.linspace(0.0, 3.0, 301)
    auto = pj.simulate(V=1.1, tau=0.01, t_final=3.0, ts=ts, solver="auto", rtol=1e-6)
    tight = pj.simulate(V=1.1, tau=0.01, t_final=3.0, ts=ts, solver="alpha", rtol=1e-10, atol=1e-13)
    assert int(auto.stats["stepper_switches"]) >= 1
    assert float(auto.stats["first_switch_at"]) < 3.0
    assert np.max(np.abs(np.asarray(auto.ys[:, 3]) - np.asarray(tight.ys[:, 3]))) < 1e-4


def _end_state(p, rtol, adjoint="reverse"):
    """y(4 s) (log v) and the run's switches and whether it completed. No fold is reached in
    the 4 s: ``fold="stop"`` ends nothing (the run's completing says so) and compiles no jump
    machinery, which more than doubles a program's compilation."""
    c1, V, tau = p
    model = eqx.tree_at(lambda m: m.adhesion.c1, pj.PeelingModel(), c1)
    sol = pj.simulate(
        model, V=V, tau=tau, t_final=4.0, ts=jnp.array([0.0, 4.0]), rtol=rtol, atol=rtol * 1e-3, solver="auto",
        adjoint=adjoint, fold="stop",
    )  # fmt: skip
    return jnp.concatenate([sol.ys[-1, :3], jnp.log(sol.ys[-1, 3:])]), (sol.stats["stepper_switches"], sol.completed)


def _forward(p, rtol):
    """y(4 s), its Jacobian by forward mode (the plain loop), and the run's switches and whether
    it completed. The tolerance is one of the packed numbers, not a constant of the program: one
    compiled program gives the derivative at 1e-9 and the differences' values at 1e-10."""
    run = lambda q: _end_state(q, rtol, "forward")  # noqa: E731
    tangent = lambda e: jax.jvp(run, (p,), (e,), has_aux=True)  # noqa: E731
    value, jacobian, (switches, completed) = jax.vmap(tangent, out_axes=(None, 1, None))(jnp.eye(3))
    return np.asarray(value), np.asarray(jacobian), int(switches) if bool(completed) else 0


@pytest.mark.slow
def test_derivatives_through_a_switch_match_central_differences():
    """V = 2, τ = 0.05 to 4 s switches to the α-method at ~2.8 s (rtol 1e-9 and 1e-10 alike):
    forward and reverse mode of y(4 s) w.r.t. (c1, V, τ) against central differences, every
    run completed and switched. The forward-mode program gives the differences' values too (no
    program for the run alone)."""
    p0 = np.array([400.0, 2.0, 0.05])
    _, forward, switches = _forward(jnp.asarray(p0), 1e-9)
    assert switches >= 1  # (0 also where the run did not complete)
    reverse = np.asarray(jax.jacrev(lambda p: _end_state(p, 1e-9)[0])(jnp.asarray(p0)))
    assert np.all(np.isfinite(reverse))
    np.testing.assert_allclose(reverse, forward, rtol=1e-8, atol=1e-12 * np.max(np.abs(forward)))
    for k, relative_step in enumerate((1e-4, 1e-4, 1e-3)):
        e = np.zeros(3)
        e[k] = relative_step * p0[k]
        (up, _, up_switches), (down, _, down_switches) = (_forward(jnp.asarray(p0 + s * e), 1e-10) for s in (1, -1))
        assert up_switches >= 1 and down_switches >= 1
        difference = (up - down) / (2 * e[k])
        scale = np.maximum(np.abs(difference), 1e-3 * np.max(np.abs(difference)))
        assert np.all(np.abs(forward[:, k] - difference) / scale < 1e-4), (k, forward[:, k], difference)
