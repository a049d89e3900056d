"""peeljax.sweep and least_tau on the error-controlled α-method (the default): every lane is
the run ``simulate`` makes, window statistics are time integrals, tolerances are part of a
sweep's identity.

Short runs (t_final = 0.4 s) at V ∈ {1.1, 2}, τ ∈ {1e-3, 1e-2}: at τ = 1e-3 the step size
collapses (at t ≈ 0.19 s for V = 1.1, the fold of the paper's Fig. 2), at τ = 1e-2 the runs
complete.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import peeljax
from peeljax import StopReason, simulate
from peeljax.integrators.dense import output_times

T_FINAL, SAVE_DT, RTOL, ATOL = 0.4, 0.05, 1e-6, 1e-9
V_AXIS, TAU_AXIS = [1.1, 2.0], [1e-3, 1e-2]
WINDOW = (0.25, 1.0)


def adaptive_sweep(**kwargs):
    options = {
        "V": V_AXIS,
        "tau": TAU_AXIS,
        "t_final": T_FINAL,
        "rtol": RTOL,
        "atol": ATOL,
        "save_dt": SAVE_DT,
        "window": WINDOW,
        "chunk": 4,
        "progress": False,
        "fold": "stop",  # the paper's stops: the small τ lanes end at their first fold
    } | kwargs
    return peeljax.sweep(**options)


@pytest.fixture(scope="module")
def swept():
    return adaptive_sweep()


def test_each_lane_is_the_simulate_run(swept):
    """Same steps, same stops, same states (to rounding: vmap/shard_map may fuse differently)."""
    ts = output_times(SAVE_DT, T_FINAL)
    np.testing.assert_array_equal(swept.ts, ts)
    assert swept.settings["method"] == "switching-tsit5-alpha" and swept.settings["rtol"] == RTOL
    np.testing.assert_array_equal(swept.completed, swept.tau == 1e-2)
    for i in range(len(swept)):
        run = simulate(V=swept.V[i], tau=swept.tau[i], t_final=T_FINAL, ts=ts, rtol=RTOL, atol=ATOL, fold="stop")
        assert swept.status[i] == int(run.status)
        assert swept.t_stop[i] == pytest.approx(float(run.t_stop), rel=1e-12)
        assert swept.accepted_steps[i] == int(run.stats["accepted_steps"])
        assert swept.rejected_steps[i] == int(run.stats["rejected_steps"])
        assert swept.newton_iterations[i] == int(run.stats["newton_iterations"])
        np.testing.assert_allclose(swept.ys[i], np.asarray(run.ys), rtol=1e-9, atol=0.0, equal_nan=True)
        if int(run.status) == 0:  # the last output time is t_final = t_stop
            assert swept.v_final[i] == pytest.approx(float(np.asarray(run.ys)[-1, 3]), rel=1e-9)
    # the default stepper (Tsit5 there) reaches the impasse point; the α-method alone stalled short of it
    assert set(swept.status[~swept.completed].tolist()) == {int(StopReason.IMPASSE)}
    assert 0.1 < swept.t_stop[(swept.V == 1.1) & (swept.tau == 1e-3)][0] < 0.3


def test_window_covered_time(swept):
    w0, w1 = WINDOW[0] * T_FINAL, WINDOW[1] * T_FINAL
    expected = np.clip(np.minimum(swept.t_stop, w1) - w0, 0.0, None)
    np.testing.assert_allclose(swept.window_time, expected)
    assert np.all(swept.window_count[swept.completed] > 0)


@pytest.mark.slow
def test_window_statistics_are_time_integrals():
    """Mean, std, min and max of v over the window against a fine uniform mesh (h = 1/40000 s)
    and the trapezoidal rule on it, at V = 2, τ = 0.02 (v overshoots and oscillates: the
    steps are far from uniform, so averages over step points would be biased)."""
    V, tau, t_final, window = 2.0, 0.02, 0.5, (0.2, 0.9)
    result = peeljax.sweep(V=V, tau=tau, t_final=t_final, window=window, rtol=1e-9, atol=1e-12, progress=False)
    fine = simulate(V=V, tau=tau, dt=1 / 40000, t_final=t_final)
    t, v = np.asarray(fine.ts), np.asarray(fine.ys)[:, 3]
    inside = (t >= window[0] * t_final - 1e-12) & (t <= window[1] * t_final + 1e-12)
    t, v = t[inside], v[inside]
    span = t[-1] - t[0]
    mean = np.trapezoid(v, t) / span
    std = np.sqrt(np.trapezoid((v - mean) ** 2, t) / span)
    assert result.completed[0]
    assert result.v_mean[0] == pytest.approx(mean, rel=1e-6)
    assert result.v_std[0] == pytest.approx(std, rel=1e-5)
    assert result.v_min[0] == pytest.approx(v.min(), rel=1e-4)
    assert result.v_max[0] == pytest.approx(v.max(), rel=1e-4)
    # The mean of the step points differs: the steps crowd where v changes fast.
    run = simulate(V=V, tau=tau, t_final=t_final, rtol=1e-9, atol=1e-12)
    points = np.asarray(run.ys)[np.asarray(run.valid)][:, 3]
    times = np.asarray(run.ts)[np.asarray(run.valid)]
    points = points[(times >= window[0] * t_final) & (times <= window[1] * t_final)]
    assert abs(points.mean() - mean) > 100 * abs(result.v_mean[0] - mean)


def test_lane_batch_changes_speed_not_results(swept):
    together = adaptive_sweep(lane_batch=4)
    np.testing.assert_array_equal(together.status, swept.status)
    np.testing.assert_array_equal(together.accepted_steps, swept.accepted_steps)
    for key in ("t_stop", "v_mean", "v_std", "v_min", "v_max", "v_final", "ys"):
        np.testing.assert_allclose(getattr(together, key), getattr(swept, key), rtol=1e-9, atol=0.0, equal_nan=True)


def test_resume_with_other_tolerances_is_refused(tmp_path):
    out = tmp_path / "s.npz"
    first = adaptive_sweep(V=[2.0], tau=[1e-2], save_dt=None, out=out)
    meta = json.loads((tmp_path / "s.npz.chunks" / "meta.json").read_text())
    assert meta["settings"]["rtol"] == RTOL and meta["settings"]["atol"] == ATOL
    again = adaptive_sweep(V=[2.0], tau=[1e-2], save_dt=None, out=out)
    assert again.computed_chunks == () and again.v_mean[0] == first.v_mean[0]
    with pytest.raises(ValueError, match="rtol"):
        adaptive_sweep(V=[2.0], tau=[1e-2], save_dt=None, out=out, rtol=1e-5)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"save_every": 2}, "save_every counts uniform-mesh steps"),
        ({"dt": 0.01}, "rtol applies to error control"),
        ({"rtol": 1.5}, r"rtol must lie in \(0, 1\)"),
        ({"atol": 0.0}, r"atol must lie in \(0, inf\)"),
        ({"save_dt": 1.0}, r"save_dt must lie in \(0, t_final\]"),
        ({"window": (0.5, 0.5)}, "w0 < w1 with error control"),
        ({"lane_batch": 0}, "lane_batch must be a positive integer"),
        ({"max_steps": 0}, "max_steps must be a positive integer"),
        ({"save_dt": 1e-4, "memory_limit": 1e5}, "a larger save_dt, now 0.0001"),
    ],
)
def test_bad_input_is_refused_before_compiling(options, message, no_compilation):
    with pytest.raises(ValueError, match=message):
        adaptive_sweep(**options)


@pytest.mark.slow
def test_least_tau_with_error_control_agrees_with_single_runs():
    """τ* on the adaptive method: the run at τ* completes, the one at tau_below stops (step
    size collapsed or impasse), as single ``simulate`` runs with the same tolerances."""
    found = peeljax.least_tau(V=[1.1], t_final=0.5, tau_range=(5e-4, 5e-2), tau_rtol=0.1, n_points=4)
    assert found.settings["method"] == "switching-tsit5-alpha" and found.settings["rtol"] == 1e-6
    assert found.found[0]
    tau_star, tau_below = float(found.tau_star[0]), float(found.tau_below[0])
    assert tau_below >= tau_star * (1 - 0.1) * (1 - 1e-9)
    assert int(simulate(V=1.1, tau=tau_star, t_final=0.5, fold="stop").status) == 0
    below = simulate(V=1.1, tau=tau_below, t_final=0.5, fold="stop")
    assert int(below.status) in (StopReason.STALLED, StopReason.IMPASSE)
    assert float(below.t_stop) == pytest.approx(float(found.t_stop_below[0]), rel=1e-9)
