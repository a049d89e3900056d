"""peeljax.analysis: event detection on known series, and the stick-slip picture of real runs.

The real runs are short (≤ 0.3 s of the paper's step 1/82 s) and shared through module fixtures.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import peeljax as pj
from peeljax import analysis as A

H = 1 / 82
T_SHORT = 24 / 82  # 24 steps of exactly the paper's h = 1/82 s


@pytest.fixture(scope="module")
def stopping_run():
    """V = 1.1, τ = 1e-3 at h = 1/82: the paper's early stop (J_t → 0 near t ≈ 0.17 s)."""
    solution = pj.simulate(V=1.1, tau=1e-3, dt=H, t_final=T_SHORT)
    return solution, A.analyze(solution, V=1.1, tau=1e-3)


# ---------------------------------------------------------------------------- host helpers
def test_crossings_and_oscillation_of_a_sinusoid():
    ts = np.linspace(0.0, 10.0, 4001)
    x = 2.0 + 0.5 * np.sin(2 * np.pi * ts / 1.25)
    up = A.crossings(ts, x - 2.0, "up")
    down = A.crossings(ts, x - 2.0, "down")
    assert np.allclose(np.diff(up), 1.25, atol=1e-6) and np.allclose(np.diff(down), 1.25, atol=1e-6)
    osc = A.oscillation(ts, x, t_start=2.0)
    assert osc["period"] == pytest.approx(1.25, rel=1e-4)
    assert osc["amplitude"] == pytest.approx(0.5, rel=1e-4)
    assert osc["mean"] == pytest.approx(2.0, abs=0.05)  # 6.4 cycles in the window
    assert osc["decay"] == pytest.approx(1.0, abs=1e-3)
    t_max, x_max, _t_min, x_min = A.local_extrema(ts, x)
    assert np.allclose(x_max, 2.5, atol=1e-5) and np.allclose(x_min, 1.5, atol=1e-5)
    assert np.allclose(np.diff(t_max), 1.25, atol=5e-3)


def test_damped_oscillation_has_decay_below_one_and_nan_stops_crossings():
    ts = np.linspace(0.0, 10.0, 2001)
    x = np.exp(-0.3 * ts) * np.cos(2 * np.pi * ts)
    assert A.oscillation(ts, x)["decay"] < 0.2
    x_nan = x.copy()
    x_nan[1000:] = np.nan
    assert A.crossings(ts, x_nan).max() < ts[1000]
    short = A.oscillation(ts[:2], x[:2])
    assert np.isnan(short["period"]) and np.isnan(short["amplitude"])


def test_phi_extrema_match_the_documented_values():
    v_top, v_bottom = A.phi_extrema(V=1.1)
    assert v_top == pytest.approx(0.524, abs=1e-3) and v_bottom == pytest.approx(8.49, abs=1e-2)
    grad = jax.grad(lambda v: pj.PeelingModel().phi(v, 1.1))
    assert abs(float(grad(v_top))) < 1e-6 and abs(float(grad(v_bottom))) < 1e-6
    assert all(np.isnan(A.phi_extrema(V=8.0)))  # φ is monotone at V = 8


# ---------------------------------------------------------------------------- real runs
def test_structure_matches_the_integrator_diagnostics(stopping_run):
    solution, analysis = stopping_run
    valid = np.asarray(solution.valid)
    np.testing.assert_allclose(analysis.schur[valid], np.asarray(solution.diagnostics.schur)[valid], rtol=1e-9)
    np.testing.assert_array_equal(analysis.local_index[valid], np.asarray(solution.diagnostics.local_index)[valid])


def test_phases_follow_the_sign_of_dphi_dv(stopping_run):
    _, a = stopping_run
    v_top, _ = A.phi_extrema(V=1.1)
    ok = a.valid
    assert not np.any(a.stick & a.slip)
    # below the maximum of φ the tape sticks, above it (up to the minimum) it slips
    np.testing.assert_array_equal(a.stick[ok], a.v[ok] < v_top)
    np.testing.assert_array_equal(a.branch[ok], np.where(a.v[ok] < v_top, 0, 1))
    # the start (v0 = 1e-10·V) is a stick phase; the one stick → slip event is where v passes v_top
    assert a.stick[0] and a.stick_to_slip.size == 1
    i = np.searchsorted(a.ts, a.stick_to_slip[0])
    assert a.v[i - 1] < v_top <= a.v[i]


def test_early_stop_is_a_near_singular_point(stopping_run):
    """Theorem 3 (`bif`) / the paper's Fig. 2 remark: at τ = 1e-3 the run ends where J_t passes through 0."""
    solution, a = stopping_run
    assert not bool(solution.completed)
    assert 0.15 < float(solution.t_stop) < 0.19
    assert a.schur_sign_changes.size >= 1
    t_bif = a.bifurcation_times[-1]
    assert t_bif <= float(solution.t_stop) + 1e-12 and t_bif > a.stick_to_slip[0]
    assert a.summary()["n_bifurcation_points"] == a.bifurcation_times.size


@pytest.mark.slow
def test_batched_analysis_equals_single_analyses():
    taus = np.array([0.01, 0.1])
    batch = jax.vmap(lambda tau: pj.simulate(V=1.1, tau=tau, dt=H, t_final=T_SHORT))(taus)
    results = A.analyze(batch, V=1.1, tau=taus)
    assert isinstance(results, list) and len(results) == 2
    for i, tau in enumerate(taus):
        single = A.analyze(jax.tree.map(lambda x, i=i: x[i], batch), V=1.1, tau=tau)
        np.testing.assert_allclose(results[i].schur, single.schur, rtol=1e-12)
        assert results[i].tau == tau
    # larger τ: larger |J_t| (Lemma 1 with τ·F̃(𝐈 − τ∂f/∂x)⁻¹∂f/∂v < 0 here), index 1 throughout
    assert results[1].min_abs_schur > results[0].min_abs_schur
    assert results[1].max_local_index == 1


def test_bad_threshold_is_rejected(stopping_run):
    solution, _ = stopping_run
    with pytest.raises(ValueError, match="threshold"):
        A.analyze(solution, threshold=0.0)


@pytest.mark.slow
def test_bifurcation_diagram_shapes_and_late_extrema():
    with pytest.raises(ValueError, match="engine"):
        A.bifurcation_diagram([1.1], engine="gpu")
    diagram = A.bifurcation_diagram([1.1, 4.0], tau=0.01, dt=H, t_final=T_SHORT, t_transient=0.1)
    assert diagram.V.shape == (2,) and len(diagram.v_max) == 2 and len(diagram.v_min) == 2
    assert diagram.completed.all()
    for v_max, v_min in zip(diagram.v_max, diagram.v_min):
        if v_max.size and v_min.size:
            assert v_max.max() >= v_min.min()
    loop = A.bifurcation_diagram([1.1, 4.0], tau=0.01, dt=H, t_final=T_SHORT, t_transient=0.1, engine="loop")
    for a, b in zip(diagram.v_max, loop.v_max):
        np.testing.assert_allclose(a, b, rtol=1e-12)  # the sweep engine and single runs agree


def test_phi_extrema_and_the_sweep_slip_velocity_are_one_search():
    """v̂ is found one way (structure.phi_extremum): on the host by phi_extrema, in the graph by the sweeps."""
    from peeljax.sweeps import slip_velocity

    model = pj.PeelingModel()
    for V in (1.1, 2.0, 4.0):
        top, _ = A.phi_extrema(model, V)
        assert float(slip_velocity(model, jnp.asarray(V))) == pytest.approx(top, rel=1e-13)
    assert float(slip_velocity(model, jnp.asarray(8.0))) == np.inf  # no maximum: no events


def test_both_folds_by_one_search_are_each_kinds_own_search():
    """phi_max_and_min (one grid, one loop for both brackets) gives phi_extremum's value for each
    kind, to the bit, traced under vmap, and its derivative in V (implicit function theorem)."""
    from peeljax.structure import phi_extremum, phi_max_and_min

    model = pj.PeelingModel()
    Vs = jnp.array([0.3, 1.1, 4.0, 8.0])  # 8 m/s: no fold (NaN)
    both = jax.vmap(lambda V: jnp.stack(phi_max_and_min(model, V)))(Vs)
    for k, kind in enumerate(("max", "min")):
        one = np.array([float(phi_extremum(model, V, kind)) for V in Vs])
        np.testing.assert_array_equal(np.asarray(both[:, k]), one)
    assert np.isnan(both[-1]).all() and np.isfinite(both[:-1]).all()
    grad = jax.grad(lambda V: phi_max_and_min(model, V)[1])(1.1)
    h = 1e-6
    fd = (float(phi_max_and_min(model, 1.1 + h)[1]) - float(phi_max_and_min(model, 1.1 - h)[1])) / (2 * h)
    assert float(grad) == pytest.approx(fd, rel=1e-5)


def test_analyze_takes_the_runs_ode_truncation_included():
    """analyze(solution, ode) equals the keyword form, and honours the ODE's truncation: its J_t
    is the one the α-method used (diagnostics.schur), not the exact one."""
    model = pj.PeelingModel()
    sol = pj.simulate(model, V=1.1, tau=0.01, dt=0.01, t_final=0.3, truncation=2)
    ode = pj.HomogenizedODE(model, 1.1, 0.01, truncation=2)
    a = A.analyze(sol, ode)
    valid = np.asarray(sol.valid)
    np.testing.assert_allclose(a.schur[valid], np.asarray(sol.diagnostics.schur)[valid], rtol=1e-9)
    b = A.analyze(sol, model, V=1.1, tau=0.01, truncation=2)
    np.testing.assert_array_equal(a.schur, b.schur)
    exact = A.analyze(sol, model, V=1.1, tau=0.01)
    assert np.nanmax(np.abs(exact.schur[valid] - a.schur[valid])) > 0  # the truncation is not ignored
    with pytest.raises(ValueError, match="not both"):
        A.analyze(sol, ode, tau=0.1)


# ---------------------------------------------------------------------------- time averages and τ = 0
def test_time_average_weights_by_time_and_takes_jumps_exactly():
    """x = t on [0, 0.5), 3 + t after (a jump of 3 at 0.5, between samples); samples crowded
    in [0.4, 0.5): the trapezoid in t with the jump inserted is exact for this piecewise-linear
    x, the plain mean of the samples is not."""
    ts = np.concatenate([np.linspace(0.0, 0.4, 3), np.linspace(0.41, 0.49, 50), [0.7, 1.0]])
    x = np.where(ts < 0.5, ts, 3.0 + ts)
    jump = (np.array([0.5]), np.array([0.5]), np.array([3.5]))
    exact = 0.5 + 3.0 * 0.5  # ∫_0^1 t dt + 3·0.5
    assert A.time_average(ts, x, jumps=jump) == pytest.approx(exact, rel=1e-12)
    assert abs(A.time_average(ts, x) - exact) > 0.1  # the jump drawn as a ramp from 0.49 to 0.7
    assert abs(np.mean(x) - exact) > 1.0
    # a window cut inside: [0.2, 0.6] and [0.5, 1] (the window starts on the jump: after it)
    assert A.time_average(ts, x, 0.2, 0.6, jumps=jump) == pytest.approx(((0.36 - 0.04) / 2 + 3 * 0.1) / 0.4)
    assert A.time_average(ts, x, 0.5, 1.0, jumps=jump) == pytest.approx(3.75)
    # NaN samples are left out; too few samples give NaN
    x_nan = x.copy()
    x_nan[-1] = np.nan
    assert A.time_average(ts, x_nan, jumps=jump) == pytest.approx(A.time_average(ts[:-1], x[:-1], jumps=jump))
    assert np.isnan(A.time_average(ts[:1], x[:1]))


@pytest.fixture(scope="module")
def dae_runs():
    """V = 1.1 at τ = 0 (the DAE with jumps) to t = 0.3 s (18 jumps): error control's accepted
    steps, and the same run on a uniform output grid of 1e-5 s (the reference)."""
    steps = pj.simulate(V=1.1, tau=0.0, t_final=0.3)
    fine = pj.simulate(V=1.1, tau=0.0, t_final=0.3, ts=np.linspace(0.0, 0.3, 30001))
    return steps, fine


@pytest.mark.slow
def test_tau0_analysis_agrees_with_the_jump_record(dae_runs):
    """On the DAE the sign rule sees no slip (v jumps over the middle branch): phases, events,
    the stick fraction, the period and the repeat come from the jump record."""
    steps, _ = dae_runs
    a = A.analyze(steps, V=1.1, tau=0.0, t_transient=0.1)
    record = steps.jumps.as_numpy()
    whole = pj.cycle_statistics(steps, float(steps.t_stop))
    late = pj.cycle_statistics(steps, float(steps.t_stop), transient=0.1)
    assert whole.slips >= 8 and late.slips >= 5
    assert a.stick_fraction == pytest.approx(whole.stick_fraction, rel=1e-12)
    assert a.slip_fraction == pytest.approx(1.0 - whole.stick_fraction, rel=1e-12)
    assert 0.85 < a.stick_fraction < 0.97  # stuck most of the time, not 100 %
    np.testing.assert_array_equal(a.stick_to_slip, record["jump_t"][record["jump_up"]])
    np.testing.assert_array_equal(a.slip_to_stick, record["jump_t"][~record["jump_up"]])
    assert a.slips == late.slips and a.period == pytest.approx(late.slip_interval.mean, rel=1e-12)
    assert a.repeat_verdict == late.verdict and a.cycles == late
    # each output time on the branch the jumps say: slipping between an up jump and the next down one
    i_up = np.searchsorted(a.ts, record["jump_t"][record["jump_up"]], side="right")
    assert a.slip[i_up].all() and (a.v[i_up] > 1.0).all()
    assert not (a.stick & a.slip).any() and (a.stick | a.slip)[a.valid].all()
    assert a.fraction("stick") == a.stick_fraction
    summary = a.summary()
    assert summary["stick_fraction"] == a.stick_fraction and summary["repeat_verdict"] == late.verdict


@pytest.mark.slow
def test_tau0_time_mean_matches_the_fine_uniform_output(dae_runs):
    """v's mean over error control's steps is the time average: within 1 % of ∫v dt/T on a
    uniform 1e-5 s grid of the same run (measured 0.4 %); the plain mean of the steps is 3×."""
    steps, fine = dae_runs
    j = fine.jumps.as_numpy()
    reference = A.time_average(fine.ts, fine.ys[:, 3], 0.0, 0.3, jumps=(j["jump_t"], j["jump_v_before"], j["jump_v_after"]))
    a = A.analyze(steps, V=1.1, tau=0.0, t_transient=0.0)
    assert a.v_mean == pytest.approx(reference, rel=1e-2)
    assert np.nanmean(np.where(steps.valid, steps.ys[:, 3], np.nan)) > 2 * reference
    # the uniform run's own analysis: the same jump-record numbers
    b = A.analyze(fine, V=1.1, tau=0.0, t_transient=0.0)
    assert b.v_mean == pytest.approx(reference, rel=1e-12)
    assert b.stick_fraction == pytest.approx(a.stick_fraction, rel=1e-6)


def test_tau_positive_phases_are_time_fractions(stopping_run):
    """τ > 0 keeps the sign rule; on its uniform mesh the time fractions are the count fractions
    but for the half weights of the two end points."""
    _, a = stopping_run
    ok = a.valid
    n = int(ok.sum())
    w = np.ones(n)
    w[[0, -1]] = 0.5
    assert a.stick_fraction == pytest.approx(np.sum(w * a.stick[ok]) / w.sum(), rel=1e-12)
    assert a.stick_fraction + a.slip_fraction == pytest.approx(1.0)
    # one stick → slip after the transient (v passes v̂ once): no period, too few to tell a repeat
    assert a.cycles is None and a.slips == 1 and np.isnan(a.period)
    assert a.repeat_verdict == "too few repeats to tell"
    assert a.v_mean == pytest.approx(A.time_average(a.ts, a.v, a.t_transient, a.t_stop), rel=1e-12)
