"""peeljax.AlphaSolver: the α-method as a diffrax solver, on a linear system and on the peeling ODE."""

from __future__ import annotations

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import peeljax as pj
from peeljax.homogenized import HomogenizedODE

A = jnp.array([[-1.0, 2.0], [-2.0, -1.0]])
Y0 = jnp.array([1.0, 0.0])


def _linear(t, y, args):
    return A @ y


def _exact(t):
    return jax.scipy.linalg.expm(A * t) @ Y0


def test_second_order_on_constant_steps():
    errors = []
    ns = (50, 100, 200)
    for n in ns:
        sol = diffrax.diffeqsolve(diffrax.ODETerm(_linear), pj.AlphaSolver(), 0.0, 2.0, 2.0 / n, Y0)
        errors.append(float(jnp.max(jnp.abs(sol.ys[-1] - _exact(2.0)))))
    slope = np.polyfit(np.log(ns), np.log(errors), 1)[0]
    assert slope == pytest.approx(-2.0, abs=0.1)


def test_error_control_on_a_linear_system():
    ts = jnp.linspace(0.0, 2.0, 11)
    exact = jax.vmap(_exact)(ts)
    errors = []
    for rtol in (1e-4, 1e-6, 1e-8):
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(_linear),
            pj.AlphaSolver(rho=0.5),
            0.0,
            2.0,
            0.01,
            Y0,
            saveat=diffrax.SaveAt(ts=ts),
            stepsize_controller=diffrax.PIDController(rtol=rtol, atol=1e-3 * rtol),
        )
        errors.append(float(jnp.max(jnp.abs(sol.ys - exact))))
    assert errors[0] < 1e-2 and errors[1] < errors[0] / 10 and errors[2] < errors[1] / 10, errors


@pytest.mark.slow
def test_on_the_peeling_ode_in_log_v():
    """(α, ω, u, log v) with diffrax's PID controller agrees with the reference and with peeljax's own driver."""
    model = pj.PeelingModel()
    V, tau = 1.1, 0.1
    ode = pj.LogTransformedODE(HomogenizedODE(model, V, tau), (3,))
    z0 = model.initial_state(V)
    z0 = z0.at[3].set(jnp.log(z0[3]))
    grid = np.linspace(0.0, 3.0, 301)
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(lambda t, z, args: ode(z)),
        pj.AlphaSolver(),
        0.0,
        3.0,
        1e-6,
        z0,
        saveat=diffrax.SaveAt(ts=jnp.asarray(grid)),
        stepsize_controller=diffrax.PIDController(rtol=1e-6, atol=1e-9),
        max_steps=100_000,
    )
    reference = pj.simulate_reference(model, V=V, tau=tau, dt=0.01, t_final=3.0, rtol=1e-11, atol=1e-13)
    own = pj.simulate(model, V=V, tau=tau, t_final=3.0, rtol=1e-6, atol=1e-9, ts=grid)
    v = np.exp(np.asarray(sol.ys[:, 3]))
    assert np.max(np.abs(v - np.asarray(reference.v))) < 1e-4
    assert np.max(np.abs(v - np.asarray(own.v))) < 1e-4


def test_rho_is_checked_at_construction():
    with pytest.raises(ValueError, match="rho"):
        pj.AlphaSolver(rho=1.5)
