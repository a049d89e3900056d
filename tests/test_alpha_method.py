"""The α-method's measured properties (issue: core §4 a–f)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import LinearODE

import peeljax as pj
from peeljax.homogenized import Evaluation
from peeljax.solution import StopReason


class FoldODE(eqx.Module):
    """p' = 1 (a clock), q' = 0, with J = 1/2 − p and a chosen F̃·f: J crosses zero at p = 1/2."""

    drive_vanishes: bool = eqx.field(static=True)
    tau: float = 0.5

    def evaluate(self, y):
        J = 0.5 - y[0]
        drive = J if self.drive_vanishes else jnp.asarray(1.0)
        return Evaluation(psi=jnp.array([1.0, 0.0]), J=J, drive=drive)

    def __call__(self, y):
        return self.evaluate(y).psi


GENERAL = dict(log_components=())
PAPER_DT = 1 / 82


def fitted_order(hs, errors):
    return float(np.polyfit(np.log(hs), np.log(errors), 1)[0])


@pytest.fixture(scope="module")
def paper_runs():
    """The paper's setting, V = 1.1, h = 1/82 s, t ∈ [0, 3 s], at three τ (one compilation)."""
    model = pj.PeelingModel()
    return {tau: pj.simulate(model, V=1.1, tau=tau, dt=PAPER_DT, t_final=3.0) for tau in (0.1, 0.01, 1e-3)}


# ---------------------------------------------------------------- coefficients and stability (b)
def test_coefficients_match_the_paper():
    gamma, beta = pj.alpha_coefficients(0.0)
    assert float(gamma) == pytest.approx(1.5) and float(beta) == pytest.approx(1.0)
    gamma, beta = pj.alpha_coefficients(0.5)
    assert float(gamma) == pytest.approx(2 / 1.5 - 0.5) and float(beta) == pytest.approx(1 / 2.25)


@pytest.mark.parametrize("rho", [0.0, 0.25, 0.5, 0.9])
def test_spectral_radius_at_infinity_equals_rho(rho):
    # For ρ = 0 the limit matrix is a Jordan block (double eigenvalue 0), so the radius
    # approaches 0 like |z|^(-1/2): check the approach and the value far out.
    deviations = []
    for z in (-1e4, -1e8, -1e12, -1e14):
        radius = np.max(np.abs(np.linalg.eigvals(np.asarray(pj.amplification_matrix(rho, z)))))
        deviations.append(abs(radius - rho))
    assert deviations[-1] < 1e-6
    assert all(later <= earlier + 1e-15 for earlier, later in zip(deviations, deviations[1:]))


@pytest.mark.parametrize("rho", [0.0, 0.5])
def test_stable_on_the_negative_real_axis(rho):
    for z in -np.logspace(-3, 8, 60):
        assert np.max(np.abs(np.linalg.eigvals(np.asarray(pj.amplification_matrix(rho, z))))) <= 1.0 + 1e-12


@pytest.mark.parametrize("rho", [0.0, 0.5])
def test_amplification_matrix_is_the_integrators_step(rho):
    """One step of the integrator on y' = λy reproduces the matrix's first row (s_0 = h·a_0/λ = z·y_0)."""
    lam, h = -7.0, 0.3
    z = lam * h
    sol = pj.integrate_alpha(LinearODE(jnp.array([lam])), pj.AlphaMethod(rho=rho, **GENERAL), jnp.ones(1), 0.0, h, 1)
    expected = np.asarray(pj.amplification_matrix(rho, z)) @ np.array([1.0, z])
    assert float(sol.ys[1, 0]) == pytest.approx(expected[0], rel=1e-12)


# ---------------------------------------------------------------- order of convergence (a)
@pytest.mark.parametrize("rho", [0.0, 0.5])
def test_second_order_on_linear_test_equation(rho):
    lam = jnp.array([-1.0, -3.0, 0.5, -10.0])
    y0 = jnp.ones(4)
    hs, errors = [], []
    for k in range(5):  # four halvings
        n = 10 * 2**k
        sol = pj.integrate_alpha(LinearODE(lam), pj.AlphaMethod(rho=rho, **GENERAL), y0, 0.0, 1.0, n)
        errors.append(float(jnp.max(jnp.abs(sol.ys[-1] - jnp.exp(lam) * y0))))
        hs.append(1.0 / n)
    assert 1.8 <= fitted_order(hs, errors) <= 2.2


def _literal_paper_step(y, a, lam, h, rho):
    """The update exactly as printed (h·a_n and (ψ_{n+1} − ψ_n)/γ) with a_0 = dψ/dt(0)."""
    gamma, beta = (float(c) for c in pj.alpha_coefficients(rho))
    b = beta / gamma
    y_new = (y + (1 - b) * h * lam * y + (0.5 - b) * h * a) / (1 - b * h * lam)
    a_new = (lam * y_new - lam * y) / gamma + (1 - 1 / gamma) * a
    return y_new, a_new


def test_literal_printed_update_is_first_order():
    """Backs the docs' claim: taken literally, the printed form loses the second order."""
    lam, hs, errors = -2.0, [], []
    for k in range(5):
        n = 20 * 2**k
        h, y, a = 1.0 / n, 1.0, lam**2
        for _ in range(n):
            y, a = _literal_paper_step(y, a, lam, h, 0.0)
        hs.append(h)
        errors.append(abs(y - np.exp(lam)))
    assert 0.8 <= fitted_order(hs, errors) <= 1.2


@pytest.mark.slow
def test_second_order_on_the_peeling_ode_from_a_smooth_state():
    """From the τ = 0.01 reference state at t = 0.6 s (past the non-Lipschitz start), over 1 s."""
    model = pj.PeelingModel()
    start = pj.simulate_reference(model, V=1.1, tau=0.01, dt=0.1, t_final=0.6, rtol=1e-12, atol=1e-14)
    y_start = start.ys[-1]
    reference = pj.simulate_reference(model, V=1.1, tau=0.01, dt=0.01, t_final=1.0, y0=y_start, rtol=1e-13, atol=1e-15)
    ref = np.asarray(reference.ys)
    for rho in (0.0, 0.5):
        hs, errors = [], []
        for k in range(5):  # four halvings
            n = 100 * 2**k
            sol = pj.simulate(model, V=1.1, tau=0.01, dt=1.0 / n, t_final=1.0, rho=rho, y0=y_start)
            assert bool(sol.completed)
            ys = np.asarray(sol.ys)[:: n // 100]
            errors.append(np.max(np.abs(ys - ref) / (1e-3 + np.abs(ref))))
            hs.append(1.0 / n)
        order = fitted_order(hs, errors)
        assert 1.8 <= order <= 2.2, (rho, order, errors)


# ---------------------------------------------------------------- agreement with diffrax (c)
@pytest.mark.slow
@pytest.mark.parametrize("tau", [0.1, 0.01])
def test_agrees_with_diffrax_and_error_shrinks_with_h(tau):
    model = pj.PeelingModel()
    reference = pj.simulate_reference(model, V=1.1, tau=tau, dt=0.01, t_final=3.0, rtol=1e-11, atol=1e-13)
    assert bool(reference.completed)
    errors = []
    for n in (246, 492, 984, 1968):
        sol = pj.simulate(model, V=1.1, tau=tau, dt=3.0 / n, t_final=3.0)
        assert bool(sol.completed)
        v = np.interp(np.asarray(reference.ts), np.asarray(sol.ts), np.asarray(sol.v))
        errors.append(np.max(np.abs(v - np.asarray(reference.v))))
    assert all(later < earlier for earlier, later in zip(errors, errors[1:])), errors
    assert errors[-1] < 5e-3, errors


# ---------------------------------------------------------------- the paper's runs (d, e, f)
def test_v_settles_to_the_pull_velocity_at_large_tau(paper_runs):
    sol = paper_runs[0.1]
    assert bool(sol.completed)
    assert abs(float(sol.v[-1]) - 1.1) < 1e-3


def test_gets_through_the_non_lipschitz_start_at_the_papers_step(paper_runs):
    sol = paper_runs[0.01]
    assert bool(sol.completed) and float(sol.t_stop) == pytest.approx(3.0)
    assert bool(jnp.all(jnp.isfinite(sol.ys))) and bool(jnp.all(sol.v > 0))
    # The safeguard that carries it through is recorded: the first steps are subdivided.
    assert int(sol.stats["subdivided_steps"]) > 0
    assert int(sol.diagnostics.newton_iterations[1]) > int(sol.diagnostics.newton_iterations[-1])


def test_stops_early_at_small_tau_and_masks_what_follows(paper_runs):
    sol = paper_runs[1e-3]
    assert int(sol.status) != StopReason.COMPLETED and sol.status_name == "stopped"
    t_stop = float(sol.t_stop)
    assert 0.1 < t_stop < 0.25  # J_t reaches zero near t ≈ 0.17 s
    assert isinstance(sol.reason, str) and sol.reason != "completed"
    valid = np.asarray(sol.valid)
    ts = np.asarray(sol.ts)
    assert ts[valid].max() == pytest.approx(t_stop)
    assert np.all(np.isnan(np.asarray(sol.ys)[~valid])) and np.all(np.isfinite(np.asarray(sol.ys)[valid]))
    # |J_t| has collapsed by orders of magnitude from its value early in the run.
    schur = np.abs(np.asarray(sol.diagnostics.schur)[valid])
    assert schur[-1] < 1e-2 * schur[5]


def test_diagnostics_have_one_entry_per_time(paper_runs):
    sol = paper_runs[0.01]
    n = sol.ts.shape[0]
    d = sol.diagnostics
    for field in (d.newton_iterations, d.newton_correction, d.schur, d.local_index, d.condition):
        assert field.shape == (n,)
    assert np.all(np.asarray(d.local_index) >= 1)
    assert np.all(np.asarray(d.newton_correction)[1:] <= 1.0 + 1e-9)  # converged to Newton's tolerance
    assert np.all(np.asarray(d.newton_iterations)[1:] >= 1)


def test_impasse_point_stops_with_its_reason():
    """J_t crosses zero while F̃·f does not: dv/dt blows up, the run must stop there."""
    solver = pj.AlphaMethod(**GENERAL)
    sol = pj.integrate_alpha(FoldODE(drive_vanishes=False), solver, jnp.array([0.0, 1.0]), 0.0, 1.0, 10)
    assert int(sol.status) == StopReason.IMPASSE
    assert float(sol.t_stop) == pytest.approx(0.5)
    assert "impasse" in sol.reason


def test_crossing_where_the_drive_vanishes_too_may_pass():
    solver = pj.AlphaMethod(**GENERAL)
    sol = pj.integrate_alpha(FoldODE(drive_vanishes=True), solver, jnp.array([0.0, 1.0]), 0.0, 1.0, 10)
    assert bool(sol.completed)


def test_condition_number_on_request():
    sol = pj.simulate(V=1.1, tau=0.1, dt=0.05, t_final=0.5, solver=pj.AlphaMethod(condition_number=True))
    cond = np.asarray(sol.diagnostics.condition)[1:]
    assert np.all(np.isfinite(cond)) and np.all(cond >= 1.0)


def test_no_recompilation_and_vmap_over_tau():
    taus = jnp.array([0.2, 0.05])

    def final_v(tau):
        return pj.simulate(V=1.1, tau=tau, dt=0.05, t_final=0.5).v[-1]

    batched = jax.vmap(final_v)(taus)
    singles = jnp.array([final_v(t) for t in taus])
    np.testing.assert_allclose(np.asarray(batched), np.asarray(singles), rtol=1e-12)


def test_batch_with_a_stopped_lane_equals_single_runs():
    # No lax.cond: a stopped lane does no Newton iteration, in a batch as alone, and the
    # running lanes are unaffected by it.
    taus = jnp.array([1e-3, 0.05])

    def run(tau):
        sol = pj.simulate(V=1.1, tau=tau, dt=1 / 82, t_final=0.5)
        return sol.ys, sol.status, sol.diagnostics.newton_iterations

    ys_b, status_b, its_b = jax.vmap(run)(taus)
    for i, tau in enumerate(taus):
        ys, status, its = run(tau)
        np.testing.assert_allclose(np.asarray(ys_b[i]), np.asarray(ys), rtol=1e-10, atol=1e-14, equal_nan=True)
        assert int(status_b[i]) == int(status)
        np.testing.assert_array_equal(np.asarray(its_b[i]), np.asarray(its))
    assert int(status_b[0]) != 0 and int(status_b[1]) == 0
    stopped_at = int(np.argmax(~np.isfinite(np.asarray(ys_b[0])[:, 3])))
    assert np.all(np.asarray(its_b[0])[stopped_at + 1 :] == 0)
