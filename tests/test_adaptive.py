"""The error-controlled α-method (issue 11): its error estimate, order, accuracy, stops and gradients."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import LinearODE

import peeljax as pj
from peeljax.homogenized import HomogenizedODE
from peeljax.integrators.adaptive import alpha_attempt, error_constant
from peeljax.integrators.alpha import alpha_start
from peeljax.integrators.dense import hermite
from peeljax.solution import StopReason

GRID = np.linspace(0.0, 3.0, 301)


GENERAL = pj.AlphaMethod(log_components=())


def fitted_slope(x, y):
    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


def _constant_steps(ode, solver, y0, h, n):
    """n α-method steps of size h from y0 (a_0 = ψ'ψ); returns the carried ODE and the last state."""
    ode_c, state = alpha_start(ode, solver, y0)

    def body(state, _):
        new, _, _, _ = alpha_attempt(ode_c, solver, state, h)
        return new, None

    state, _ = jax.lax.scan(body, state, None, length=n)
    return ode_c, state


# ---------------------------------------------------------------- the error estimate
def test_error_constant():
    assert float(error_constant(0.0)) == pytest.approx(1 / 3)
    for rho in (0.0, 0.3, 0.9):
        gamma, beta = pj.alpha_coefficients(rho)
        b = beta / gamma
        assert float(error_constant(rho)) == pytest.approx(b / 2 + (0.5 - b) * (0.5 - gamma) - 1 / 6)


@pytest.mark.parametrize("rho", [0.0, 0.5])
def test_estimate_matches_the_true_local_error_on_a_linear_ode(rho):
    """From the exact y(t_n) with the a_n the run carries, one step's error against C·h²·(a_{n+1} − a_n).

    Also PETSc TSALPHA's estimate (y_{n+1} − 2y_n + y_{n−1})/2 for comparison: it estimates
    h²·y''/2, the error of a first-order method, and overestimates the α-method's error by a
    ratio that grows like 1/h.
    """
    lam = jnp.array([-1.0, 0.7])
    ode = LinearODE(lam)
    solver = pj.AlphaMethod(rho=rho, log_components=())
    y0 = jnp.array([1.0, 1.0])
    ratios, petsc_ratios = [], []
    for h in (0.1, 0.05, 0.025, 0.0125):
        n = round(1.0 / h)
        ode_c, state = _constant_steps(ode, solver, y0, h, n)
        t_n = n * h
        exact = lambda t: y0 * jnp.exp(lam * t)  # noqa: E731
        state = eqx.tree_at(lambda s: (s.y, s.psi), state, (exact(t_n), lam * exact(t_n)))
        new, estimate, solved, _ = alpha_attempt(ode_c, solver, state, h)
        assert bool(solved)
        true_error = new.y - exact(t_n + h)
        ratios.append(np.asarray(estimate / true_error))
        petsc = (new.y - 2 * exact(t_n) + exact(t_n - h)) / 2
        petsc_ratios.append(np.asarray(petsc / true_error))
    ratios = np.array(ratios)
    assert np.all((ratios > 0.5) & (ratios < 2.0)), ratios
    assert np.all(np.abs(ratios[-1] - 1) < np.abs(ratios[0] - 1) + 1e-12)  # tends to 1 as h → 0
    petsc_ratios = np.abs(np.array(petsc_ratios))
    assert np.all(petsc_ratios[-1] > 5 * np.abs(ratios[-1]))
    assert np.all(petsc_ratios[-1] / petsc_ratios[0] > 4)  # ∝ 1/h over an 8-fold refinement


@pytest.mark.slow
def test_estimate_matches_the_true_local_error_on_the_peeling_ode():
    """The same on the peeling ODE in (α, ω, u, log v) at t_n = 0.6 s of the V = 1.1, τ = 0.1 run:
    25 steps of size h from the exact state at t_n − 25h build the scheme's a_n, then one step
    from the exact state at t_n is compared with the exact state at t_n + h (one reference run,
    rtol 1e-13, gives every exact state)."""
    model = pj.PeelingModel()
    V, tau, t_n, n = 1.1, 0.1, 0.6, 25
    hs = (4e-3, 2e-3, 1e-3)
    times = sorted({0.0, *(round(t_n - n * h, 12) for h in hs), t_n, *(round(t_n + h, 12) for h in hs)})
    ref = pj.simulate_reference(model, V=V, tau=tau, dt=None, ts=times, t_final=times[-1], rtol=1e-13, atol=1e-15)
    exact = dict(zip(times, np.asarray(ref.ys)))

    def in_log(y):
        return jnp.asarray(np.concatenate([y[:3], np.log(y[3:])]))

    solver = pj.AlphaMethod()
    ode = HomogenizedODE(model, V, tau)
    steps = eqx.filter_jit(_constant_steps)  # one compilation: h traced, n static
    ratios = []
    for h in hs:
        ode_c, state = steps(ode, solver, jnp.asarray(exact[round(t_n - n * h, 12)]), jnp.asarray(h), n)
        exact_n = in_log(exact[t_n])
        state = eqx.tree_at(lambda s: (s.y, s.psi), state, (exact_n, ode_c(exact_n)))
        new, estimate, solved, _ = alpha_attempt(ode_c, solver, state, h)
        assert bool(solved)
        true_error = np.asarray(new.y) - np.asarray(in_log(exact[round(t_n + h, 12)]))
        big = np.abs(true_error) > 1e-3 * np.max(np.abs(true_error))  # components above round-off
        ratios.append(np.asarray(estimate)[big] / true_error[big])
    for r in ratios:
        assert np.all((r > 0.5) & (r < 2.0)), ratios
    assert np.max(np.abs(ratios[-1] - 1)) < 0.25


# ---------------------------------------------------------------- the variable mesh
def test_second_order_on_a_variable_mesh_without_correcting_a():
    """A mesh whose steps alternate h and 2h (ratio 2 at every step), halved three times: slope 2."""
    lam = jnp.array([-2.0, 1.0])
    ode = LinearODE(lam)
    y0 = jnp.array([1.0, 1.0])
    errors, ns = [], []
    for k in range(4):
        base = 1.0 / (30 * 2**k)
        hs = jnp.asarray(np.tile([base, 2 * base], 10 * 2**k))  # sums to 1
        ode_c, state = alpha_start(ode, GENERAL, y0)

        def body(state, h):
            new, _, _, _ = alpha_attempt(ode_c, GENERAL, state, h)
            return new, None

        state, _ = jax.lax.scan(body, state, hs)
        errors.append(float(jnp.max(jnp.abs(state.y - y0 * jnp.exp(lam * jnp.sum(hs))))))
        ns.append(len(hs))
    assert fitted_slope(ns, errors) == pytest.approx(-2.0, abs=0.15)


# ---------------------------------------------------------------- dense output
def test_hermite_is_exact_on_cubics():
    p = lambda t: 1 - 2 * t + 0.5 * t**2 + 3 * t**3  # noqa: E731
    dp = lambda t: -2 + t + 9 * t**2  # noqa: E731
    t = jnp.linspace(0.2, 0.7, 7)
    t0, t1 = jnp.asarray(0.2), jnp.asarray(0.7)
    out = hermite(t0, t1 - t0, p(t0)[None], dp(t0)[None], p(t1)[None], dp(t1)[None], t)
    np.testing.assert_allclose(out[:, 0], p(t), rtol=1e-13)


def test_output_on_a_grid_and_at_the_steps():
    ts = np.linspace(0.0, 0.5, 51)
    dense = pj.simulate(V=1.1, tau=0.1, t_final=0.5, rtol=1e-6, ts=ts)
    # (max_steps as the analysis test below: one compiled program for both)
    steps = pj.simulate(V=1.1, tau=0.1, t_final=0.5, rtol=1e-6, max_steps=20_000)
    assert bool(dense.completed) and bool(steps.completed)
    assert dense.ys.shape == (51, 4) and bool(jnp.all(dense.valid))
    np.testing.assert_array_equal(np.asarray(dense.ts), ts)
    n = int(steps.stats["accepted_steps"])
    # max_steps + 1 rows, and a row for each jump's second side (none here)
    assert steps.ys.shape[0] >= 20_001 and int(jnp.sum(steps.valid)) == n + 1
    t = np.asarray(steps.ts)[np.asarray(steps.valid)]
    assert t[0] == 0.0 and t[-1] == 0.5 and np.all(np.diff(t) > 0)
    assert np.all(np.isnan(np.asarray(steps.ys)[~np.asarray(steps.valid)]))
    # The same run: the dense output at the step points is the step's value (output times
    # do not move the steps).
    v_steps = np.asarray(steps.v)[np.asarray(steps.valid)]
    at_steps = pj.simulate(V=1.1, tau=0.1, t_final=0.5, rtol=1e-6, ts=t)
    np.testing.assert_allclose(np.asarray(at_steps.v), v_steps, rtol=1e-9)
    assert float(dense.v[-1]) == pytest.approx(v_steps[-1], rel=1e-12)
    assert int(dense.stats["steps"]) == int(dense.stats["accepted_steps"]) == n
    assert (
        float(steps.stats["step_size_min"])
        <= float(steps.stats["step_size_mean"])
        <= float(steps.stats["step_size_max"])
    )


# ---------------------------------------------------------------- accuracy
@pytest.fixture(scope="module")
def references():
    model = pj.PeelingModel()
    return {
        (V, tau): pj.simulate_reference(model, V=V, tau=tau, dt=0.01, t_final=3.0, rtol=1e-11, atol=1e-13)
        for V, tau in ((1.1, 0.01), (1.1, 0.1), (2.0, 0.01), (4.0, 0.01))
    }


@pytest.mark.slow
def test_error_falls_with_the_tolerance_at_second_order(references):
    """The α-method, rtol = 1e-3 … 1e-8 (atol = 1e-3·rtol): max |Δv| on the 301-point grid falls monotonically,
    as (accepted steps)^−2."""
    ref = np.asarray(references[(1.1, 0.01)].v)
    errors, steps = [], []
    for rtol in (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8):
        sol = pj.simulate(V=1.1, tau=0.01, t_final=3.0, rtol=rtol, atol=1e-3 * rtol, ts=GRID, solver="alpha")
        assert bool(sol.completed)
        errors.append(float(np.max(np.abs(np.asarray(sol.v) - ref))))
        steps.append(int(sol.stats["accepted_steps"]))
    assert all(b < a for a, b in zip(errors, errors[1:])), errors
    assert fitted_slope(steps, errors) == pytest.approx(-2.0, abs=0.3)


@pytest.mark.slow
@pytest.mark.parametrize(("V", "tau"), [(1.1, 0.01), (1.1, 0.1), (2.0, 0.01), (4.0, 0.01)])
def test_accuracy_at_tight_tolerance(references, V, tau):
    """At rtol = 1e-7 the max |Δv| over [0, 3 s], t = 0 included, is ≤ 1e-4."""
    sol = pj.simulate(V=V, tau=tau, t_final=3.0, rtol=1e-7, ts=GRID)
    assert bool(sol.completed)
    assert float(np.max(np.abs(np.asarray(sol.v) - np.asarray(references[(V, tau)].v)))) <= 1e-4


# ---------------------------------------------------------------- stops
def test_stops_honestly_at_small_tau():
    """V = 1.1, τ = 1e-3, fold="stop" (the paper's behaviour): the run stops in (0.1, 0.3) s at
    the impasse or with a collapsed step."""
    sol = pj.simulate(V=1.1, tau=1e-3, t_final=3.0, rtol=1e-4, ts=GRID, fold="stop")
    assert int(sol.status) in (StopReason.IMPASSE, StopReason.STALLED), sol.reason
    assert 0.1 < float(sol.t_stop) < 0.3
    steps = int(sol.stats["accepted_steps"]) + int(sol.stats["rejected_steps"])
    assert steps < 5000
    valid = np.asarray(sol.valid)
    assert np.all(np.asarray(sol.ts)[valid] <= float(sol.t_stop))
    assert np.all(np.isnan(np.asarray(sol.ys)[~valid])) and np.all(np.isfinite(np.asarray(sol.ys)[valid]))
    assert "step size collapsed" in StopReason.STALLED.message


def test_max_steps_is_its_own_reason():
    sol = pj.simulate(V=1.1, tau=0.1, t_final=3.0, max_steps=40, ts=GRID)
    assert int(sol.status) == StopReason.MAX_STEPS
    assert float(sol.t_stop) < 3.0
    assert int(sol.stats["accepted_steps"]) + int(sol.stats["rejected_steps"]) == 40


# ---------------------------------------------------------------- gradients
def _loss_and_completed(params, adjoint, t_final=0.5, rtol=1e-10, fold=None, solver=None):
    """mean v² over 26 output times, as a function of (V, τ, c1 of φ), and whether the run completed."""
    V, tau, c1 = params
    model = pj.PeelingModel(adhesion=pj.AdhesionLaw(c1=c1))
    ts = np.linspace(0.0, t_final, 26)
    sol = pj.simulate(
        model, V=V, tau=tau, t_final=t_final, rtol=rtol, atol=1e-13, ts=ts, adjoint=adjoint, fold=fold, solver=solver
    )
    return jnp.mean(jnp.where(sol.valid, sol.v, 0.0) ** 2), sol.completed


def _loss(params, adjoint, t_final=0.5, rtol=1e-10, fold=None):
    return _loss_and_completed(params, adjoint, t_final, rtol, fold)[0]


def _alpha_loss(params, adjoint):
    """``_loss`` over 0.25 s by the α-method itself (``"auto"`` would run Tsit5 throughout: v
    is not stiff there), and whether the run completed. No fold is reached in 0.25 s, so
    ``fold="stop"`` ends nothing: it leaves out the jump machinery, which would more than
    double the programs' compilation (measured for the run alone: 6 s of CPU, against 15 s with
    jumps and 26 s with ``"auto"`` and jumps)."""
    return _loss_and_completed(params, adjoint, t_final=0.25, fold="stop", solver="alpha")


@pytest.mark.slow
def test_gradients_agree_with_central_differences():
    """Reverse (tangents through the plain loop: three perturbed numbers) and forward (plain loop)
    mode of the error-controlled α-method against central differences, with respect to V, τ and
    a coefficient of φ, at rtol = 1e-10."""
    params = jnp.array([1.1, 0.1, 400.0])
    # Two compiled programs in all: the differences reuse the reverse-mode program's value.
    value_and_grad = jax.jit(jax.value_and_grad(_alpha_loss, has_aux=True), static_argnums=1)
    (_, completed), grad = value_and_grad(params, "reverse")
    forward, completed_forward = jax.jit(jax.jacfwd(_alpha_loss, has_aux=True), static_argnums=1)(params, "forward")
    assert bool(completed) and bool(completed_forward)
    grad, forward = np.asarray(grad), np.asarray(forward)
    for k, step in enumerate((1e-5, 1e-6, 1e-3)):
        (up, up_completed), _ = value_and_grad(params.at[k].add(step), "reverse")
        (down, down_completed), _ = value_and_grad(params.at[k].add(-step), "reverse")
        assert bool(up_completed) and bool(down_completed)
        fd = (float(up) - float(down)) / (2 * step)
        assert grad[k] == pytest.approx(fd, rel=1e-5), k
        assert forward[k] == pytest.approx(fd, rel=1e-5), k


@pytest.mark.slow
def test_gradients_are_finite_across_a_stop():
    loss = lambda tau: _loss(jnp.stack([1.1, tau, 400.0]), "reverse", t_final=0.5, rtol=1e-4, fold="stop")  # noqa: E731
    sol = pj.simulate(V=1.1, tau=1e-3, t_final=0.5, rtol=1e-4, ts=np.linspace(0, 0.5, 26), fold="stop")
    assert not bool(sol.completed)
    value, grad = jax.value_and_grad(loss)(1e-3)
    assert np.isfinite(float(value)) and np.isfinite(float(grad))


# ---------------------------------------------------------------- input
@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(rtol=0.0), "rtol"),
        (dict(rtol=1.0), "rtol"),
        (dict(rtol=float("nan")), "rtol"),
        (dict(atol=0.0), "atol"),
        (dict(atol=float("inf")), "atol"),
        (dict(dt=0.01, rtol=1e-6), "rtol"),
        (dict(dt=0.01, atol=1e-6), "atol"),
        (dict(ts=[0.0, 4.0]), "ts"),
        (dict(ts=[0.5, 0.1]), "ts"),
        (dict(dtmin=-1.0), "dtmin"),
        (dict(max_steps=0), "max_steps"),
        (dict(adjoint="backward"), "adjoint"),
        (dict(checkpoint_every=10), "checkpoint_every"),
    ],
)
def test_bad_adaptive_input_is_rejected_before_compilation(no_compilation, kwargs, name):
    with pytest.raises(ValueError, match=name):
        pj.simulate(**kwargs)


def test_a_callable_phi_runs_like_the_adhesion_law():
    """A φ given as a Python function (a non-array leaf: the filter_jit path) gives the same run."""

    def phi(v, V):
        return (
            400 * v**0.35
            + 110 * v**0.15
            + 130 * jnp.exp(v / 11)
            - 2 * V**1.5
            - (415 - 45 * V**0.4 - 0.35 * V**2.15) * v**0.5
        )

    ts = np.linspace(0.0, 0.5, 6)
    law = pj.simulate(V=1.1, tau=0.1, t_final=0.5, ts=ts)
    function = pj.simulate(pj.PeelingModel(adhesion=phi), V=1.1, tau=0.1, t_final=0.5, ts=ts)
    assert bool(function.completed)
    np.testing.assert_allclose(np.asarray(function.v), np.asarray(law.v), rtol=1e-9)


@pytest.mark.parametrize(
    ("build", "name"),
    [
        (lambda: pj.AlphaMethod(rho=1.5), "rho"),
        (lambda: pj.AlphaMethod(newton_kappa=0.0), "newton_kappa"),
        (lambda: pj.AlphaMethod(chord_iterations=0), "chord_iterations"),
        (lambda: pj.PIController(rtol=0.0), "rtol"),
        (lambda: pj.PIController(atol=-1.0), "atol"),
        (lambda: pj.PIController(safety=1.5), "safety"),
        (lambda: pj.PIController(factormax=0.5), "factormax"),
    ],
)
def test_solver_and_controller_check_their_numbers(build, name):
    with pytest.raises(ValueError, match=name):
        build()


def test_traced_settings_are_not_checked_at_construction():
    assert float(jax.jit(lambda r: pj.PIController(rtol=r).rtol)(1e-3)) == 1e-3
    assert float(jax.jit(lambda r: pj.AlphaMethod(rho=r).rho)(0.3)) == 0.3


def test_analysis_of_the_accepted_steps_equals_that_on_a_grid():
    """analyze() on the NaN-padded step points of error control: same oscillation period and
    amplitude as on a fine output grid of the same run."""
    grid = pj.simulate(V=1.1, tau=0.005, t_final=3.0, ts=np.linspace(0.0, 3.0, 3001))
    steps = pj.simulate(V=1.1, tau=0.005, t_final=3.0, max_steps=20_000)
    a, b = pj.analyze(grid, V=1.1, tau=0.005), pj.analyze(steps, V=1.1, tau=0.005)
    # a damped oscillation about V, no slips after the transient: the period of v's oscillation
    assert np.isfinite(b.oscillation_period) and b.oscillation_period == pytest.approx(a.oscillation_period, rel=1e-2)
    assert b.amplitude == pytest.approx(a.amplitude, rel=1e-2)


@pytest.mark.slow
@pytest.mark.parametrize("fold", ["stop", "jump"])
def test_vmap_over_tau_equals_single_runs(fold):
    """Each lane of a vmapped error-controlled run is the single run (a stopped lane included,
    or with fold="jump" a lane with 40-odd jumps). The vmapped program is fused differently, so
    its rounding differs; at a jump that difference grows like its square root (the stick → slip
    fold is reached almost tangentially, docs/theory.md), hence 1e-6 there and 1e-12 without."""
    grid = np.linspace(0.0, 1.0, 11)
    taus = jnp.array([1e-3, 0.01, 0.1])
    batch = jax.vmap(lambda tau: pj.simulate(V=1.1, tau=tau, t_final=1.0, ts=grid, fold=fold))(taus)
    for i, tau in enumerate((1e-3, 0.01, 0.1)):
        single = pj.simulate(V=1.1, tau=tau, t_final=1.0, ts=grid, fold=fold)
        assert int(batch.status[i]) == int(single.status)
        assert int(batch.stats["accepted_steps"][i]) == int(single.stats["accepted_steps"])
        jumps = 0 if single.jumps is None else int(single.jumps.count)
        assert (jumps > 0) == (fold == "jump" and tau == 1e-3)
        if jumps:
            assert int(batch.jumps.count[i]) == jumps
        rtol = 1e-6 if jumps else 1e-12
        lane = jax.tree_util.tree_map(lambda a: a[i], batch).without_padding()  # as simulate returns it
        np.testing.assert_allclose(np.asarray(lane.v), np.asarray(single.v), rtol=rtol)


def test_the_ode_contract_is_a_type():
    """peeljax.ODE names what the integrators take; the peeling ODE, its log form and a test ODE meet it."""
    ode = HomogenizedODE(pj.PeelingModel(), 1.1, 0.01)
    assert isinstance(ode, pj.ODE)
    assert isinstance(pj.LogTransformedODE(ode, (3,)), pj.ODE)
    assert isinstance(LinearODE(jnp.asarray([-1.0])), pj.ODE)
    assert not isinstance(pj.PeelingModel(), pj.ODE)


def test_reverse_mode_checkpoints_fit_a_memory_budget():
    """The checkpointed loop keeps at most CHECKPOINT_BYTES of carries: a dense output with room
    for 10⁴ jumps (2·10⁴ rows, ~1 MB a carry) gets ~240 checkpoints, not equinox's 4471 for
    10⁷ steps (10.7 GB for one jax.grad, measured); a small carry keeps equinox's default; the
    jump record, a buffer, is not counted."""
    from peeljax.integrators.adaptive import CHECKPOINT_BYTES, reverse_checkpoints

    big = {"rows": jnp.zeros((20_000, 4)), "t": jnp.zeros(20_000)}
    n = reverse_checkpoints(big, None, 10_000_000)
    assert 16 <= n and n * (20_000 * 5 * 8) <= CHECKPOINT_BYTES
    small = {"y": jnp.zeros(4), "record": jnp.zeros((10_000, 6))}
    assert reverse_checkpoints(small, lambda c: c["record"], 10_000_000) == 4471
    assert reverse_checkpoints(small, None, 10_000_000) < 4471
