"""Runs carried through the folds of φ: jumps at constant force, against an independent
scipy reference (``tests/jump_reference.py``), continuity, convergence (τ → 0, m → 0, the
tolerance), the order between jumps, bad input, gradients and sweep lanes."""

from __future__ import annotations

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jump_reference import reference_jump_run

import peeljax as pj
from peeljax.alternatives.inertial import integrate_inertial
from peeljax.integrators.select import DEFAULT_MAX_JUMPS
from peeljax.solution import StopReason

MODEL = pj.PeelingModel()


def _jumps(sol) -> dict:
    return sol.jumps.as_numpy()


def _slope(x, y) -> float:
    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


# ---------------------------------------------------------------------------- against scipy
@pytest.fixture(scope="module")
def reference():
    """The scipy reference (LSODA, rtol 1e-10) at V = 1.1 and 2 over [0, 3] s."""
    return {V: reference_jump_run(V, 3.0, rtol=1e-10, atol=1e-12) for V in (1.1, 2.0)}


@pytest.mark.slow
@pytest.mark.parametrize("V", [1.1, 2.0])
def test_dae_jumps_agree_with_scipy_events(reference, V):
    """τ = 0 at rtol 1e-8: the jump count equals the reference's, the first 20 jump times
    agree to 1e-5 s, directions alternate, and the repeat time agrees with its orbit."""
    sol = pj.simulate(V=V, tau=0, t_final=3.0, rtol=1e-8, atol=1e-10, max_steps=1_000_000)
    assert sol.status_name == "completed", sol.reason
    ours, ref = _jumps(sol), reference[V]
    assert ours["jump_t"].size == ref["jump_t"].size
    np.testing.assert_array_equal(ours["jump_up"], ref["jump_up"])
    assert np.max(np.abs(ours["jump_t"][:20] - ref["jump_t"][:20])) < 1e-5
    # V = 2's orbit settles slowly (its long stick still drifts by 0.2 ms a repeat at 1.5 s).
    ours_cycles = pj.cycle_statistics(sol, 3.0, transient=2.0)
    ref_cycles = pj.cycle_statistics(ref, 3.0, transient=2.0)
    assert ours_cycles.repeat is not None and ref_cycles.repeat is not None
    assert ours_cycles.repeat.events == ref_cycles.repeat.events
    assert ours_cycles.repeat.period == pytest.approx(ref_cycles.repeat.period, rel=1e-5)


@pytest.mark.slow
def test_jump_times_converge_as_the_tolerance_tightens(reference):
    """The first 10 jump times approach the reference's as rtol falls (1e-5 … 1e-8)."""
    ref = reference[1.1]["jump_t"][:10]
    errors = []
    for rtol in (1e-5, 1e-6, 1e-7, 1e-8):
        sol = pj.simulate(V=1.1, tau=0, t_final=0.45, rtol=rtol, atol=rtol * 1e-2, max_steps=400_000)
        errors.append(np.max(np.abs(_jumps(sol)["jump_t"][:10] - ref)))
    assert all(b < a for a, b in zip(errors, errors[1:])), errors
    assert errors[-1] < 1e-5


# ---------------------------------------------------------------------------- the jumps themselves
@pytest.fixture(scope="module")
def stick_slip():
    """V = 1.1, τ = 0 over [0, 1] s at its accepted steps."""
    return pj.simulate(V=1.1, tau=0, t_final=1.0, rtol=1e-7, atol=1e-9)


def test_x_and_the_force_are_continuous_across_every_jump(stick_slip):
    """At each jump x is unchanged (the row at the jump is the state before it), G(x) equals
    φ(v⁺, V) to round-off right after it, v⁺ lies on the other stable branch (∂φ/∂v > 0), and
    stick → slip and slip → stick alternate."""
    sol, jumps = stick_slip, _jumps(stick_slip)
    assert jumps["jump_t"].size > 20
    ts, ys = np.asarray(sol.ts), np.asarray(sol.ys)
    folds = pj.phi_folds(MODEL, 1.1)
    keys = ("jump_t", "jump_up", "jump_v_before", "jump_v_after", "jump_G", "jump_F")
    for t, up, v_before, v_after, G, F in zip(*(jumps[key] for key in keys)):
        row = int(np.flatnonzero(ts == t)[0])
        x = ys[row, :3]
        assert float(MODEL.shear_force(x)) == pytest.approx(G, rel=1e-12)
        assert float(MODEL.tension(x[2], x[0])) == pytest.approx(F, rel=1e-12)
        assert float(MODEL.phi(v_after, 1.1)) == pytest.approx(G, rel=1e-9)
        assert float(jax.grad(MODEL.phi)(v_after, 1.1)) > 0
        if up:  # from the stick branch's end to the slip branch
            assert v_before == pytest.approx(float(folds.v_max), rel=1e-4) and v_after > float(folds.v_min)
            assert G == pytest.approx(float(folds.phi_max), rel=1e-9)
        else:
            assert v_before == pytest.approx(float(folds.v_min), rel=1e-4) and v_after < float(folds.v_max)
            assert G == pytest.approx(float(folds.phi_min), rel=1e-9)
        # (v near a fold moves like the square root of G's distance to it.) The next accepted
        # state continues from x on the new branch: x moves by what ẋ = f(x, v⁺) allows.
        after = ys[row + 1]
        rate = np.abs(np.asarray(MODEL.f(jnp.asarray(x), v_after, 1.1)))
        assert np.all(np.abs(after[:3] - x) <= 4 * rate * (ts[row + 1] - t) + 1e-9)
        assert (after[3] > np.sqrt(folds.v_max * folds.v_min)) == up
    assert np.all(jumps["jump_up"][::2]) and not np.any(jumps["jump_up"][1::2])


def test_the_dae_keeps_its_constraint_exactly(stick_slip):
    """τ = 0: G(x) − φ(v, V) vanishes along the whole run (v is solved, not integrated)."""
    ys = np.asarray(stick_slip.ys)[np.asarray(stick_slip.valid)]
    residual = np.asarray(jax.vmap(lambda y: MODEL.constraint(y[:3], y[3], 1.1))(jnp.asarray(ys)))
    assert np.max(np.abs(residual)) < 1e-8


def test_a_bounded_number_of_steps_per_jump(stick_slip):
    """Each fold is located on the step that crosses it: the run takes a bounded number of step
    attempts per jump (measured: ~100–200 at rtol 1e-7), never a collapse of the step size."""
    assert stick_slip.status_name == "completed", stick_slip.reason
    attempts = int(stick_slip.stats["accepted_steps"]) + int(stick_slip.stats["rejected_steps"])
    per_jump = attempts / int(stick_slip.stats["jumps"])
    assert per_jump < 400, per_jump


@pytest.mark.slow
def test_stop_at_the_fold_is_the_papers_behaviour():
    """fold="stop": the DAE stops at its first fold, where the jump run makes its first jump."""
    stop = pj.simulate(V=1.1, tau=0, t_final=1.0, fold="stop")
    jump = pj.simulate(V=1.1, tau=0, t_final=0.2, max_jumps=1)
    assert int(stop.status) == StopReason.FOLD and int(stop.jumps.count) == 0
    assert float(stop.t_stop) == pytest.approx(float(_jumps(jump)["jump_t"][0]), abs=1e-12)


@pytest.mark.slow
def test_max_jumps_stops_and_keeps_what_it_computed():
    sol = pj.simulate(V=1.1, tau=0, t_final=1.0, max_jumps=3, ts=np.linspace(0, 1, 101))
    assert int(sol.status) == StopReason.MAX_JUMPS
    assert "max_jumps" in sol.reason
    assert int(sol.jumps.count) == 3
    assert float(sol.t_stop) > float(_jumps(sol)["jump_t"][-1])
    valid = np.asarray(sol.valid)
    assert valid[0] and not valid[-1]
    assert np.all(np.isfinite(np.asarray(sol.ys)[valid])) and np.all(np.isnan(np.asarray(sol.ys)[~valid]))


def test_the_jump_record_grows_to_the_run_unless_its_size_is_given(monkeypatch):
    """max_jumps=None (the default): a run that fills the record's first size runs again with
    room for its jumps (the same run as with that size given; a Simulator's call alike); under
    memory_limit it stops as a given size does; traced, the size is fixed before the run (10⁴)."""
    simulate_module = importlib.import_module("peeljax.simulate")
    monkeypatch.setattr(simulate_module, "FIRST_MAX_JUMPS", 8)
    ts = np.linspace(0, 1, 101)
    grown = pj.simulate(V=1.1, tau=0, t_final=1.0, ts=ts)
    assert grown.status_name == "completed" and int(grown.jumps.count) > 8
    size = grown.jumps.max_jumps
    assert size >= 32 and size & (size - 1) == 0 and size >= int(grown.jumps.count)
    given = pj.simulate(V=1.1, tau=0, t_final=1.0, ts=ts, max_jumps=size)
    np.testing.assert_array_equal(_jumps(grown)["jump_t"], _jumps(given)["jump_t"])
    np.testing.assert_array_equal(np.asarray(grown.ys), np.asarray(given.ys))
    monkeypatch.setattr(importlib.import_module("peeljax.bound"), "FIRST_MAX_JUMPS", 8)
    bound = pj.Simulator(t_final=1.0, ts=ts)(1.1, 0.0)  # (its own programs: the rows merged in them)
    np.testing.assert_array_equal(_jumps(bound)["jump_t"], _jumps(grown)["jump_t"])
    np.testing.assert_array_equal(np.asarray(bound.ys), np.asarray(grown.ys))
    # (101 + 2·8 rows) × 400 B + 8 slots × 48 B fit in 5·10⁴ B, a record of 32 or more does not
    capped = pj.simulate(V=1.1, tau=0, t_final=1.0, ts=ts, memory_limit=5e4)
    assert int(capped.status) == StopReason.MAX_JUMPS and int(capped.jumps.count) == 8
    assert "max_jumps" in capped.reason
    traced = jax.eval_shape(lambda V: pj.simulate(V=V, tau=0, t_final=1.0, ts=ts).jumps.t, 1.1)
    assert traced.shape == (DEFAULT_MAX_JUMPS,)


def test_folds_searched_at_the_first_jump_give_the_same_run(monkeypatch):
    """At τ > 0 a run on concrete inputs searches φ's folds at its first jump, not before the
    run (a run without a jump skips the search): the same bits, jumps included, as a run that
    searched them first. Traced (under ``vmap``: its ``lax.cond`` runs both branches) they are
    searched before the run."""
    simulate_module = importlib.import_module("peeljax.simulate")
    monkeypatch.setattr(simulate_module, "KEPT_SIMULATORS", 0)  # each call takes simulate's own route
    integrator_for = simulate_module.integrator_for
    asked = []

    def recording(*args, **options):
        asked.append(options["folds_at_first_jump"])
        return integrator_for(*args, **options)

    monkeypatch.setattr(simulate_module, "integrator_for", recording)
    ts = np.linspace(0.0, 0.5, 51)
    later = pj.simulate(V=1.1, tau=1e-3, t_final=0.5, ts=ts)
    monkeypatch.setattr(simulate_module, "integrator_for", lambda *a, **o: integrator_for(*a, **{**o, "folds_at_first_jump": False}))
    first = pj.simulate(V=1.1, tau=1e-3, t_final=0.5, ts=ts)
    assert asked == [True] and int(later.stats["jumps"]) > 4
    for a, b in zip(jax.tree_util.tree_leaves(later), jax.tree_util.tree_leaves(first)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    monkeypatch.setattr(simulate_module, "integrator_for", recording)
    jax.eval_shape(jax.vmap(lambda V: pj.simulate(V=V, tau=1e-3, t_final=0.5, ts=ts).ys), jnp.array([1.1, 2.0]))
    assert asked == [True, False]


@pytest.mark.slow
def test_no_fold_no_jump():
    """V = 6 m/s: the paper's φ has no fold there, so nothing jumps."""
    sol = pj.simulate(V=6.0, tau=0, t_final=0.5)
    assert sol.status_name == "completed" and int(sol.stats["jumps"]) == 0
    assert not bool(pj.phi_folds(MODEL, 6.0).exist)


# ---------------------------------------------------------------------------- convergence
def _up_times(sol, n):
    jumps = _jumps(sol)
    return jumps["jump_t"][jumps["jump_up"]][:n]


@pytest.mark.slow
def test_the_homogenized_ode_converges_to_the_dae_as_tau_falls():
    """τ = 1e-4, 3e-5, 1e-5 with jumps at every fold: the first five stick → slip times approach
    τ = 0's, the error falling with τ (about linearly)."""
    dae = _up_times(pj.simulate(V=1.1, tau=0, t_final=0.35, rtol=1e-8, atol=1e-10), 5)
    errors = []
    for tau in (1e-4, 3e-5, 1e-5):
        sol = pj.simulate(V=1.1, tau=tau, t_final=0.35, rtol=1e-7, atol=1e-10, max_steps=400_000)
        assert sol.status_name == "completed", sol.reason
        errors.append(np.max(np.abs(_up_times(sol, 5) - dae)))
    assert errors[0] > errors[1] > errors[2], errors
    assert 0.6 < _slope((1e-4, 3e-5, 1e-5), errors) < 1.4, errors


@pytest.mark.slow
def test_the_inertial_model_converges_to_the_dae_as_the_mass_falls():
    """m·v̇ = G − φ (de2005missing): the first stick → slip time approaches the jump solution's
    as m falls (1e-4, 3e-5, 1e-5 kg; measured 1.6e-3, 9.2e-4, 5.5e-4 s late, about as √m);
    the slip is where v first crosses between the folds."""
    t_jump = float(_up_times(pj.simulate(V=1.1, tau=0, t_final=0.2, rtol=1e-8, atol=1e-10), 1)[0])
    split = float(np.sqrt(pj.phi_folds(MODEL, 1.1).v_max * pj.phi_folds(MODEL, 1.1).v_min))
    errors = []
    for m in (1e-4, 3e-5, 1e-5):
        sol = integrate_inertial(MODEL, V=1.1, m=m, dt=1e-5, t_final=0.2, rtol=1e-7, atol=1e-9)
        assert sol.status_name == "completed", sol.reason
        ts, v = np.asarray(sol.ts), np.asarray(sol.v)
        first = int(np.argmax(v > split))
        assert v[first] > split
        errors.append(ts[first] - t_jump)
    assert all(e > 0 for e in errors), errors  # inertia delays the slip
    assert errors[0] > errors[1] > errors[2], errors
    assert 0.3 < _slope((1e-4, 3e-5, 1e-5), errors) < 0.7, errors


@pytest.mark.slow
def test_second_order_between_jumps():
    """Before the first fold (t ≤ 0.15 s) the α-method's error at t = 0.15 s falls as the second
    power of the number of steps (a measured slope), as on any smooth stretch."""
    ts = np.array([0.0, 0.15])
    exact = pj.simulate(V=1.1, tau=0, t_final=0.15, rtol=1e-12, atol=1e-14, ts=ts, solver="dopri8")
    steps, errors = [], []
    for rtol in (1e-5, 1e-6, 1e-7, 1e-8):
        sol = pj.simulate(V=1.1, tau=0, t_final=0.15, rtol=rtol, atol=rtol * 1e-3, ts=ts, solver="alpha")
        steps.append(int(sol.stats["accepted_steps"]))
        errors.append(float(np.max(np.abs(np.asarray(sol.ys)[-1, :3] - np.asarray(exact.ys)[-1, :3]))))
    assert 1.6 < -_slope(steps, errors) < 2.6, (steps, errors)


# ---------------------------------------------------------------------------- input, gradients, sweeps
@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(max_jumps=0), "max_jumps"),
        (dict(max_jumps=2.5), "max_jumps"),
        (dict(fold="slide"), "fold"),
        (dict(tau=-1e-3), "tau"),
        (dict(tau=0, fold="follow"), "fold"),
        (dict(tau=0, dt=0.01), "tau=0"),
        (dict(fold="jump", dt=0.01), "fold"),
        (dict(tau=0, truncation=1), "truncation"),
    ],
)
def test_bad_jump_input_is_rejected_before_compilation(no_compilation, kwargs, name):
    with pytest.raises(ValueError, match=name):
        pj.simulate(**kwargs)


@pytest.mark.slow
def test_sweep_lanes_jump_as_simulate_does():
    """Each lane of a τ = 0 sweep takes the jumps of the same run alone (forward-mode loop) and
    keeps the last ``max_jumps`` of them (a ring buffer, 64 by default), in time order."""
    Vs = [0.35, 1.1, 2.0]
    res = pj.sweep(V=Vs, tau=0, t_final=1.0, progress=False, grid="pairs")
    ring = res.jumps["jump_t"].shape[1]
    assert ring == 64
    slips = []
    for i, V in enumerate(Vs):
        sol = pj.simulate(V=V, tau=0, t_final=1.0, adjoint="forward", max_jumps=2048)
        n = int(sol.jumps.count)
        assert int(res.jumps["jump_count"][i]) == n
        kept = min(n, ring)
        # The same steps; a lane's branch roots are computed batched, which rounds differently
        # (~1e-12 in log v), and a jump time moves like the square root of a state's error.
        np.testing.assert_allclose(res.jumps["jump_t"][i, :kept], _jumps(sol)["jump_t"][n - kept :], rtol=0, atol=1e-7)
        # The window's events are its slips, counted in the loop: each stick → slip jump of the run in [0.5, 1] s.
        up, t = _jumps(sol)["jump_up"], _jumps(sol)["jump_t"]
        slips.append(int(np.sum(up & (t >= 0.5) & (t <= 1.0))))
    assert int(res.jumps["jump_count"][2]) > ring  # the ring has wrapped: its oldest jumps were dropped
    np.testing.assert_array_equal(res.events, slips)


def test_a_landing_below_phi_at_rest_is_a_fully_stuck_tape():
    """Where G(x) < φ(0⁺, V) the stick branch has no root: the jump from the slip branch lands
    at v = 0 (stuck), the DAE's ψ is finite there (x moves with v = 0), and once G is back above
    φ(0⁺, V) v leaves 0 continuously on the stick branch."""
    V = 1.1
    dae = pj.ConstrainedDAE(MODEL, V).with_folds()
    phi_zero = float(dae.folds.phi_zero)
    stuck_x = jnp.array([0.1, 0.0, float(MODEL.stretch_for_force(0.1, phi_zero - 5.0))])
    slipping = jnp.concatenate([stuck_x, jnp.array([9.0])])
    jump = dae.jump(slipping)
    assert not bool(jump.up) and float(jump.v_after) == 0.0
    evaluation = dae.evaluate(jump.y)
    assert np.all(np.isfinite(np.asarray(evaluation.psi)))
    np.testing.assert_allclose(np.asarray(evaluation.psi[:3]), np.asarray(MODEL.f(stuck_x, 0.0, V)), rtol=1e-12)
    for excess, expected_positive in ((-1e-3, False), (1e-3, True)):
        x = stuck_x.at[2].set(float(MODEL.stretch_for_force(0.1, phi_zero + excess)))
        v = float(dae.velocity(jnp.concatenate([x, jnp.array([0.0])])))
        assert (v > 0) == expected_positive and v < 1e-6
