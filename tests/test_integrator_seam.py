"""The integrator seam (issue 13 §1): one contract, three integrators, every driver takes any.

``integrator_for`` turns the user's options into a :class:`UniformMesh`, an
:class:`ErrorControl` or a :class:`DiffraxIntegrator`; ``simulate``, ``sweep``, ``least_tau``
and ``fit_adhesion`` accept a diffrax solver where they accept an ``AlphaMethod``.
"""

from __future__ import annotations

import diffrax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import LinearODE

import peeljax as pj
from peeljax.integrators import (
    AbstractIntegrator,
    DenseOutput,
    DiffraxIntegrator,
    RungeKutta,
    ErrorControl,
    EveryNthPoint,
    UniformMesh,
    integrator_for,
)

LAM = jnp.array([-1.0, -3.0])
Y0 = jnp.array([1.0, 2.0])
T_FINAL = 1.0
TS = jnp.linspace(0.0, T_FINAL, 11)


def exact(ts):
    return Y0 * np.exp(np.outer(ts, LAM))


def test_integrator_for_builds_each_integrator_and_checks_its_options():
    assert isinstance(integrator_for(dt=0.01, t_final=1.0), UniformMesh)
    control = integrator_for(rtol=1e-5, t_final=1.0)
    assert isinstance(control, ErrorControl) and float(control.controller.rtol) == 1e-5
    # a diffrax Runge–Kutta solver is a stepper of the one loop; other diffrax solvers run in diffrax's
    reference = integrator_for(diffrax.Kvaerno5(), rtol=1e-5, t_final=1.0)
    assert isinstance(reference, ErrorControl) and isinstance(reference.method, RungeKutta)
    assert float(reference.controller.rtol) == 1e-5 and reference.settings()["method"] == "diffrax-Kvaerno5"
    assert isinstance(integrator_for("kvaerno5").method, RungeKutta)
    own = integrator_for(diffrax.ImplicitEuler(), rtol=1e-5, t_final=1.0)
    assert isinstance(own, DiffraxIntegrator) and float(own.rtol) == 1e-5
    for integrator in (control, reference):
        assert isinstance(integrator, AbstractIntegrator) and integrator.dense_output
    assert isinstance(integrator_for(dt=0.01), AbstractIntegrator) and not UniformMesh.dense_output
    assert integrator_for(dt=0.01).carried_log == (3,) and reference.carried_log == (3,) and own.carried_log == ()
    with pytest.raises(ValueError, match="dt .*α-method's"):
        integrator_for(diffrax.Kvaerno5(), dt=0.01)
    with pytest.raises(ValueError, match="solver must be one of .*'tsit5'"):
        integrator_for("Kvaerno5")
    with pytest.raises(TypeError, match="solver must be one of"):
        integrator_for(3.0)
    with pytest.raises(ValueError, match="adjoint"):
        integrator_for(adjoint="backward")
    with pytest.raises(ValueError, match="rho"):
        integrator_for(rho=1.5)
    # the integrators check their own numbers when built directly
    with pytest.raises(ValueError, match="n_steps"):
        UniformMesh(pj.AlphaMethod(), 0)
    with pytest.raises(ValueError, match="max_steps"):
        ErrorControl(max_steps=0)
    with pytest.raises(TypeError, match="diffrax.AbstractSolver"):
        DiffraxIntegrator(pj.AlphaMethod())


@pytest.mark.parametrize(
    "integrator, tol",
    [
        (UniformMesh(pj.AlphaMethod(log_components=()), 400), 2e-5),
        (ErrorControl(pj.AlphaMethod(log_components=()), pj.PIController(rtol=1e-8, atol=1e-10)), 5e-6),
        (DiffraxIntegrator(diffrax.Kvaerno5(), rtol=1e-8, atol=1e-10), 2e-6),
    ],
    ids=["uniform", "error-control", "diffrax"],
)
def test_every_integrator_meets_the_contract(integrator, tol):
    """On y' = λy each integrator reaches t_final, reports it, and matches the exact solution,
    at its own points (ts=None) and, with dense output, at given times."""
    ode = LinearODE(LAM)
    own = integrator.integrate(ode, Y0, 0.0, T_FINAL)
    assert int(own.status) == 0 and float(own.t_stop) == pytest.approx(T_FINAL)
    valid = np.asarray(own.valid)
    assert valid[0] and np.isnan(np.asarray(own.ys)[~valid]).all()
    np.testing.assert_allclose(np.asarray(own.ys)[valid], exact(np.asarray(own.ts)[valid]), atol=tol)
    settings = integrator.settings()
    assert isinstance(settings, dict) and "solver" in settings
    if not integrator.dense_output:
        with pytest.raises(ValueError, match="ts must be None"):
            integrator.integrate(ode, Y0, 0.0, T_FINAL, TS)
        # observe() takes the steps integrate() takes: every mesh point, bit for bit
        run = integrator.observe(ode, Y0, 0.0, T_FINAL, EveryNthPoint(1, integrator.n_steps + 1))
        assert int(run.status) == 0 and float(run.t_stop) == pytest.approx(T_FINAL)
        assert int(run.accepted_steps) == integrator.n_steps
        np.testing.assert_array_equal(np.asarray(run.record.y), np.asarray(own.ys))
        return
    at_ts = integrator.integrate(ode, Y0, 0.0, T_FINAL, TS)
    assert np.asarray(at_ts.valid).all()
    np.testing.assert_allclose(np.asarray(at_ts.ys), exact(np.asarray(TS)), atol=tol)
    # observe() takes the steps integrate() takes, and its dense output is integrate()'s
    run = integrator.observe(ode, Y0, 0.0, T_FINAL, DenseOutput(TS))
    assert int(run.status) == 0 and float(run.t_stop) == pytest.approx(T_FINAL)
    assert int(run.accepted_steps) == int(at_ts.stats["accepted_steps"])
    np.testing.assert_allclose(np.asarray(run.record.y), np.asarray(at_ts.ys), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.asarray(run.y_final), exact(np.array([T_FINAL]))[0], atol=tol)


def test_a_diffrax_solver_with_a_uniform_mesh_is_refused_before_compiling(no_compilation):
    with pytest.raises(ValueError, match="error control"):
        pj.simulate(dt=0.01, solver=diffrax.Kvaerno5())
    with pytest.raises(ValueError, match="error control"):
        pj.sweep(V=1.1, tau=0.01, dt=0.01, solver=diffrax.Kvaerno5(), progress=False)


@pytest.mark.slow
def test_simulate_sweep_and_least_tau_take_a_diffrax_solver():
    """The peeling problem through the same calls with Kvaerno5: a small sweep whose lanes are
    the runs ``simulate`` makes with that solver (saved states; Kvaerno5's dense output is the
    cubic Hermite interpolant the sweep's observer uses), whose window statistics agree with
    the α-method's, and τ* with Tsit5."""
    kwargs = dict(V=[1.1, 2.0], tau=[0.01, 0.1], t_final=0.5, save_dt=0.1, progress=False)
    reference = pj.sweep(**kwargs, solver=diffrax.Kvaerno5())
    alpha = pj.sweep(**kwargs)
    assert reference.settings["method"] == "diffrax-Kvaerno5" and reference.completed.all()
    np.testing.assert_allclose(reference.v_mean, alpha.v_mean, rtol=1e-4)
    np.testing.assert_allclose(reference.v_std, alpha.v_std, rtol=1e-2, atol=1e-5)
    assert (reference.events == alpha.events).all()
    for V, tau, ys, alpha_ys in zip(reference.V, reference.tau, reference.ys, alpha.ys):
        single = pj.simulate(V=V, tau=tau, t_final=0.5, ts=reference.ts, solver=diffrax.Kvaerno5())
        assert single.method == "diffrax-Kvaerno5" and bool(single.completed)
        np.testing.assert_allclose(ys, np.asarray(single.ys), rtol=1e-9)
        np.testing.assert_allclose(ys, alpha_ys, rtol=1e-3, atol=1e-5)
    found = pj.least_tau(V=[1.1], t_final=0.3, n_points=4, tau_rtol=0.3, solver=diffrax.Tsit5())
    assert found.settings["method"] == "diffrax-Tsit5" and found.found.all()


@pytest.mark.slow
def test_fit_takes_a_diffrax_solver():
    """A short fit with diffrax's Tsit5 in place of the α-method: from data made with c1 = 440
    (start 400), L-BFGS recovers c1 through diffrax's gradients."""
    true = pj.AdhesionLaw(c1=440.0)
    ts = np.linspace(0.0, 0.3, 31)
    data = pj.simulate(pj.PeelingModel(adhesion=true), V=1.1, tau=0.1, t_final=0.3, ts=ts, rtol=1e-9, atol=1e-12)
    obs = pj.Observation(V=1.1, t=np.asarray(data.ts), v=np.asarray(data.v))
    result = pj.fit_adhesion(
        obs, tau=0.1, free=["c1"], optimizer="lbfgs", steps=8, progress=False, rtol=1e-8, atol=1e-11,
        solver=diffrax.Tsit5(),
    )  # fmt: skip
    assert result.settings["method"] == "diffrax-Tsit5" and result.t_stop == [0.3]
    assert float(result.adhesion.c1) == pytest.approx(440.0, rel=1e-3)
    assert result.final_loss < 1e-6 * result.initial_loss
