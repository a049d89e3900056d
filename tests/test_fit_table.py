"""Stick-slip statistics of a run, the uncertainties of a least-squares fit, and the table fit."""

import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize
import scipy.stats

from peeljax.fit import StickSlipTable, fit_stick_slip, jump_statistics, phi_relative_error
from peeljax.measurements.statistics import window_scatter
from peeljax.measurements.stick_slip_table import STATISTICS
from peeljax.fit.levenberg_marquardt import CONVERGED, STOP_REASONS, LevenbergMarquardt
from peeljax.fit.uncertainty import quantile, uncertainty_from_jacobian
from peeljax.solution import JumpRecord

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


def _record(events):
    """A JumpRecord of (t, up, F) triples (8 slots)."""
    record = JumpRecord.empty(8)
    for t, up, F in events:
        record = record.record(jnp.asarray(True), t, up, 0.1, 1.0, F, F)
    return record


def test_jump_statistics_of_a_known_record():
    # slips at 1.0, 2.0, 3.0 (F 10, 12, 14), re-sticks 0.25 s later (F 4, 6), one outside the window
    events = [(0.5, False, 0.0), (1.0, True, 10.0), (1.25, False, 4.0), (2.0, True, 12.0), (2.25, False, 6.0),
              (3.0, True, 14.0), (3.5, False, 100.0)]  # fmt: skip
    F = jnp.linspace(0.9, 3.2, 2001) ** 2  # F = t²: its mean over the whole cycles [1, 3] is 13/3
    values, available = jump_statistics(_record(events), F, 0.9, 3.2)
    got = dict(zip(STATISTICS, np.asarray(values)))
    assert np.all(np.asarray(available))
    assert got["F_mean"] == pytest.approx(13 / 3, rel=1e-5)
    assert got["F_slip"] == pytest.approx(12.0)
    assert got["F_stick"] == pytest.approx(5.0)
    assert got["period"] == pytest.approx(1.0)
    assert got["slip_duration"] == pytest.approx(0.25)


def test_window_scatter_is_the_spread_over_the_cycles_per_cycle():
    """s/n: the record above: F at the slips 10, 12, 14 → 2/3; at the re-sticks 4, 6 → √2/2; equal
    gaps and slip durations → 0; F_mean (whole cycles) → 0."""
    events = [(0.5, False, 0.0), (1.0, True, 10.0), (1.25, False, 4.0), (2.0, True, 12.0), (2.25, False, 6.0),
              (3.0, True, 14.0), (3.5, False, 100.0)]  # fmt: skip
    got = np.asarray(window_scatter(_record(events), 0.9, 3.2))
    np.testing.assert_allclose(got, [0.0, 2 / 3, np.sqrt(2) / 2, 0.0, 0.0], atol=1e-12)
    uneven = [(1.0, True, 10.0), (1.2, False, 4.0), (2.0, True, 12.0), (2.5, False, 6.0), (4.0, True, 14.0)]
    gaps, durations = np.array([1.0, 2.0]), np.array([0.2, 0.5])
    got = np.asarray(window_scatter(_record(uneven), 0.0, 5.0))
    np.testing.assert_allclose(got[3:], [np.std(gaps, ddof=1) / 2, np.std(durations, ddof=1) / 2])


def test_tapered_statistics_are_continuous_where_a_slip_crosses_the_window_edge():
    """A slip (F 30 at its jump, against 10 and 12 inside) moving from just inside the window's
    end to just outside: the plain mean of F_slip jumps by 6, the tapered one by < 1e-6; the
    gaps' mean likewise. With no slip near an edge, taper and plain means agree."""
    def stats(t_last, taper):
        events = [(1.0, True, 10.0), (1.25, False, 4.0), (2.0, True, 12.0), (2.25, False, 6.0), (t_last, True, 30.0)]
        return np.asarray(jump_statistics(_record(events), jnp.ones(101), 0.5, 3.0, taper=taper)[0])

    inside, outside = stats(3.0 - 1e-9, 0.0), stats(3.0 + 1e-9, 0.0)
    assert inside[1] - outside[1] == pytest.approx(52 / 3 - 11)
    inside, outside = stats(3.0 - 1e-9, 0.25), stats(3.0 + 1e-9, 0.25)
    np.testing.assert_allclose(inside[1:4], outside[1:4], atol=1e-6)
    middle = [(1.5, True, 10.0), (1.6, False, 4.0), (1.75, True, 12.0), (1.85, False, 6.0), (2.0, True, 14.0)]
    plain, tapered = (np.asarray(jump_statistics(_record(middle), jnp.ones(101), 0.0, 3.5, taper=x)[0]) for x in (0, 0.2))
    np.testing.assert_allclose(tapered[1:], plain[1:], rtol=1e-12)
    with pytest.raises(ValueError, match="taper"):
        fit_stick_slip(StickSlipTable.from_dict(V=[1.0, 2.0], F_mean=[200.0, 220.0], period=[0.05, 0.02]), taper=0.7)


def test_jump_statistics_without_slips_has_only_the_mean_force():
    values, available = jump_statistics(JumpRecord.empty(4), jnp.asarray([3.0, 5.0]), 0.0, 1.0)
    assert np.asarray(available).tolist() == [True, False, False, False, False]
    assert np.all(np.isfinite(np.asarray(values)))


def test_covariance_of_a_linear_fit_is_the_textbook_one():
    """r = J·θ − y: Cov = s²(JᵀJ)⁻¹ (as numpy's lstsq-based formula), c = θ-scaled values."""
    rng = np.random.default_rng(0)
    J = rng.normal(size=(30, 3))
    r = rng.normal(size=30)
    unc = uncertainty_from_jacobian(J, r, np.ones(3), ("a", "b", "c"), scaled=True)
    s2 = r @ r / 27
    np.testing.assert_allclose(unc.covariance, s2 * np.linalg.inv(J.T @ J), rtol=1e-10)
    np.testing.assert_allclose(np.diag(unc.correlation), 1.0)
    assert unc.undetermined == ()
    assert unc.quantile(0.95) == pytest.approx(scipy.stats.t.ppf(0.975, 27), rel=1e-3)
    # the table prints the 95 % interval it computes, value ± t₀.₉₇₅·σ
    lo, hi = unc.intervals(0.95)["a"]
    assert hi - unc.values[0] == pytest.approx(unc.quantile(0.95) * unc.standard_errors[0])
    assert "95 % interval" in unc.table() and f"[{lo:.6g}, {hi:.6g}]" in unc.table()


def test_a_coefficient_the_data_cannot_see_is_named():
    J = np.zeros((10, 2))
    J[:, 0] = np.arange(10.0)
    unc = uncertainty_from_jacobian(J, np.ones(10), np.array([2.0, 3.0]), ("c1", "c3"), scaled=True)
    assert unc.undetermined == ("c3",)
    assert np.isinf(unc.standard_errors[1]) and np.isfinite(unc.standard_errors[0])
    assert "not determined by the data: c3" in unc.table()


def test_covariance_is_scaled_by_chi2_per_dof_only_where_the_sigma_are_too_small():
    """'auto' scales by max(1, χ²/dof) (curve_fit's scaling, never below the σ given); True always
    (curve_fit's default), False never; the summary says which."""
    rng = np.random.default_rng(1)
    J = rng.normal(size=(40, 2))
    unit = np.linalg.inv(J.T @ J)
    for factor in (3.0, 0.5):
        r = factor * rng.normal(size=40)
        ratio = float(r @ r) / 38
        got = {rule: uncertainty_from_jacobian(J, r, np.ones(2), ("a", "b"), scaled=rule) for rule in ("auto", True, False)}
        np.testing.assert_allclose(got["auto"].covariance, max(1.0, ratio) * unit, rtol=1e-10)
        np.testing.assert_allclose(got[True].covariance, ratio * unit, rtol=1e-10)
        np.testing.assert_allclose(got[False].covariance, unit, rtol=1e-10)
        assert got["auto"].chi2_dof == pytest.approx(ratio) and got["auto"].scaled == (ratio > 1)
        assert ("covariance scaled by chi2/dof" in got["auto"].table()) == (ratio > 1)
        assert (ratio > 1) == (factor > 1)  # the draws are what they claim
    with pytest.raises(ValueError, match="scale_covariance"):
        uncertainty_from_jacobian(J, r, np.ones(2), ("a", "b"), scaled="sometimes")


def test_singular_directions_name_the_combination_the_data_determine():
    """Two coefficients seen only through their product: log a + log b is determined (its standard
    error 1/S_1), log a − log b is not; the summary lists the combinations."""
    J = np.zeros((20, 2))
    J[:, 0] = J[:, 1] = np.linspace(1.0, 2.0, 20)
    J[:, 1] += 1e-3 * np.linspace(-1.0, 1.0, 20)  # nearly, not exactly, one direction
    unc = uncertainty_from_jacobian(J, np.zeros(20), np.ones(2), ("c1", "c6"), scaled=False)
    (best, best_err), (worst, worst_err) = unc.combinations()
    assert best == "+0.71·log c1 +0.71·log c6" and worst == "+0.71·log c1 -0.71·log c6"
    assert best_err == pytest.approx(1 / np.linalg.svd(J, compute_uv=False)[0], rel=1e-12)
    assert worst_err > 1e3 * best_err and unc.max_correlation() > 0.99
    assert "+0.71·log c1 +0.71·log c6" in unc.table()


def _marquardt(residuals, z0, **options):
    """Drive LevenbergMarquardt to its end on an analytic problem (J by finite differences of 1e-7)."""

    def evaluate(z):
        r = residuals(z)
        J = np.stack([(residuals(z + 1e-7 * e) - r) / 1e-7 for e in np.eye(len(z))], axis=1)
        return r, J, np.zeros((1, 2))

    run = LevenbergMarquardt(np.asarray(z0, float), *evaluate(np.asarray(z0, float)), **options)
    while run.reason is None:
        run.take(*evaluate(run.trial()))
    return run


def test_levenberg_marquardt_runs_to_convergence_and_says_which_test_stopped_it():
    """An exponential decay y = a·exp(−b·t) with noise: converged by the Gauss–Newton test at the
    least-squares optimum (scipy's), from a start 50 % off; a budget of 3 evaluations stops it
    with that reason; a residual that cannot be lowered stalls."""
    t = np.linspace(0.0, 3.0, 30)
    y = 2.0 * np.exp(-1.3 * t) + 0.01 * np.random.default_rng(0).normal(size=30)

    def residuals(z):
        return (np.exp(z[0]) * np.exp(-np.exp(z[1]) * t) - y) / 0.01

    options = {"fit_rtol": 1e-10, "fit_atol": 1e-6, "max_iterations": 50}
    run = _marquardt(residuals, np.log([3.0, 0.65]), **options)
    expected = scipy.optimize.least_squares(residuals, np.log([3.0, 0.65]), xtol=1e-14, ftol=1e-14).x
    assert run.reason == "gauss-newton" and run.reason in CONVERGED
    np.testing.assert_allclose(run.z, expected, atol=1e-5)
    assert np.all(np.diff(run.history) < 0) and run.evaluations < 20
    assert _marquardt(residuals, np.log([3.0, 0.65]), **{**options, "max_iterations": 3}).reason == "max_iterations"
    assert "not converged" in STOP_REASONS["max_iterations"] and "converged" in STOP_REASONS["gauss-newton"]
    flat = _marquardt(lambda z: np.array([1.0 + 1e-300 * z[0], 2.0]), [0.0], **options)
    assert flat.reason == "gauss-newton"  # nothing to gain: converged at once, not an endless loop


@pytest.mark.parametrize("dof", [5, 20, 100])
def test_student_quantile(dof):
    assert quantile(0.95, dof) == pytest.approx(scipy.stats.t.ppf(0.975, dof), rel=1.2e-3)
    assert quantile(0.95, None) == pytest.approx(1.959964, rel=1e-6)


def test_bad_options_are_refused_before_compiling():
    table = StickSlipTable.from_dict(V=[1.0, 2.0], F_mean=[200.0, 220.0], period=[0.05, 0.02])
    for kwargs, name in (
        ({"window": -1.0}, "window"), ({"transient": -0.1}, "transient"), ({"n_starts": 0}, "n_starts"),
        ({"max_iterations": 0}, "max_iterations"), ({"tau": -1.0}, "tau"), ({"free": ["c99"]}, "c99"),
        ({"statistics": ["F_slip"]}, "F_slip"), ({"free": ["c1", "c3", "c6", "c5"]}, "free"),
        ({"n_coarse": 0}, "n_coarse"),
        ({"coarse_spread": 0.0}, "coarse_spread"), ({"scale_covariance": "yes"}, "scale_covariance"),
    ):  # fmt: skip
        with pytest.raises(ValueError, match=name):
            fit_stick_slip(table, **kwargs)
    with pytest.raises(TypeError, match="StickSlipTable"):
        fit_stick_slip({"V": [1.0]})
    with pytest.raises(TypeError, match="progress must be"):
        fit_stick_slip(table, progress="yes")


def test_progress_is_silent_a_line_or_the_callers():
    """progress=False and None are silent, True prints a line per iteration, a callable is called
    (progress=False crashed after the first iteration: 'bool' object is not callable)."""
    import io
    from contextlib import redirect_stderr

    from peeljax.fit.table import progress_callback

    assert progress_callback(None) is None and progress_callback(False) is None
    def mine(iteration, chi2):
        pass

    assert progress_callback(mine) is mine
    err = io.StringIO()
    with redirect_stderr(err):
        progress_callback(True)(3, 12.5)
    assert err.getvalue() == "iteration 3: chi2 = 12.5\n"


SETTINGS = {"transient": 0.3, "window": 0.5}


@pytest.mark.slow
def test_hidden_truth_table_of_three_coefficients_is_recovered():
    """The window method (``method="window"``) on its smallest problem (benchmarks/fit_acceptance.py
    --table runs it at 8 V): φ with c1 × 1.12, c3 × 1.06, c6 × 1.10, a table at 6 V (1 % noise and its σ, made at
    the fit's tolerances, [0.5, 1.5] s), fitted from the paper's φ from the best of 4 coarse
    points: every coefficient within 2 % of the truth and within 3 standard errors,
    Levenberg–Marquardt converged (its stop reason names the test), χ²/dof reported, no residual
    beyond 5 σ, φ within 2.5 % over the v visited. (At 4 V it ends at c1 + 2.3 %, 3.2 SE: measured.)"""
    import fit_acceptance  # benchmarks/

    V = (0.8, 1.0, 1.5, 2.2, 2.6, 3.0)
    out = fit_acceptance.run_table(V=V, n_coarse=4, n_starts=1, max_iterations=15, method="window")
    result, truth = out["result"], out["truth"]
    u = result.uncertainty
    assert result.converged and result.stop_reason.startswith("converged"), result.stop_reason
    for name, value, se in zip(u.names, u.values, u.standard_errors):
        true = float(getattr(truth, name))
        assert abs(value / true - 1) < 0.02 and abs(value - true) < 3 * se, (name, value, true, se)
    assert result.final_loss < result.initial_loss / 20
    assert result.dof == 6 * 5 - 3 and result.chi2_dof == pytest.approx(result.final_loss / 27)
    assert f"chi2/dof = {result.chi2_dof:.3g}" in result.summary() and not result.outliers
    # φ within 2.5 % over the v visited. The fit stops on the rough floor of χ² (window statistics
    # jump where a slip crosses a window's edge), at a point its derivatives' last digits choose:
    # 0.35 % with tangential folds differentiated from a reference 1e-8 deep, 2.0 % (c3 +1.5 %,
    # 1.7 SE) with the more accurate 1e-3·rtol (measured); statistics without that floor are still to come.
    assert phi_relative_error(result.adhesion, truth, V, result.v_range) < 0.025
    record = result.to_dict()
    assert record["chi2_dof"] == pytest.approx(result.chi2_dof) and len(record["optima"]) == 1


@pytest.mark.slow
def test_a_table_across_the_whole_stick_slip_range_is_recovered():
    """``benchmarks/fit_acceptance.py --wide grazing``: 8 V in 0.5–4 m/s, three coefficients 6–8 %
    off, 1 % noise, the defaults. The orbits at 3.5–4 m/s pass close to a grazing (their
    derivatives singular, named in the rows and left out of the steps; before, the fit stopped
    at its start, every coefficient 6–8 % off). Every coefficient within 2 % and 4 standard
    errors, χ²/dof below 2, no statistic missing. The table where besides the tape stops after
    every slip at 0.5 m/s (``--wide stops``) is fitted without noise below, and its noisy fit
    is the benchmark's (docs/fitting.md); its test here was cut for CI's time.

    4, not 3: these fits end on χ²'s rough floor (docs/fitting.md), where the point they stop
    at follows the last bits of the machine's arithmetic. The same code and draw passed at 3
    on one 2-core AMD EPYC and read c6 −0.16 %, 3.7 standard errors on another (2026-12-06);
    the intervals' coverage over 60 draws is ``benchmarks/results/fit_coverage_wide.md``'s."""
    import fit_acceptance  # benchmarks/

    out = fit_acceptance.run_table(V=fit_acceptance.WIDE_V, multipliers=fit_acceptance.WIDE_TRUTH)
    result, truth = out["result"], out["truth"]
    u = result.uncertainty
    for name, value, se in zip(u.names, u.values, u.standard_errors):
        true = float(getattr(truth, name))
        assert abs(value / true - 1) < 0.02 and abs(value - true) < 4 * se, (name, value, true, se)
    assert result.converged and result.chi2_dof < 2.0 and not result.missing, result.summary()


@pytest.mark.slow
def test_the_whole_range_table_without_noise_is_fitted_to_its_truth():
    """The whole-range table of ``benchmarks/fit_coverage.py --problem wide`` without noise (σ 1 %
    of each value), at ``fit_acceptance.WIDE_STOPS``: the tape stops after every slip at 0.5 m/s,
    where the row's attractor is a 5-slip orbit found by shooting and followed through a period
    doubling (``tests/test_fit_attractors.py``). χ² is 0 at the truth. Before the step beyond a branch's edge the fit stopped
    at χ² 1.25, c1 0.87 standard errors short of the truth. Since, measured: χ² 0.14 and
    c1 0.30 SE short (2026-11-28), and χ² 6.93, c1 1.00 SE short (2026-12-04, twice: the end
    point differs between processes in the last digits, and the row at 3.5 m/s then lands on a
    coexisting 34-slip attractor and the one at 4 m/s on its window statistics). Since the rows'
    second try at Newton's floor (the row at 4 m/s keeps its orbit, 2026-12-07): χ² 9.6e-8, every
    coefficient within 0.001 SE of the truth, converged by the Gauss–Newton test; with the row at
    0.5 m/s on its 5-slip orbit (2026-12-07, before a window row): χ² 1.8e-9, within 2e-5 SE;
    since rows whose runs show no repeat are shot from their last slip: χ² 1.2e-7, within
    3e-4 SE. Asserted with room for another machine's last digits: within 0.2 SE, χ²/dof below
    0.05."""
    import fit_coverage  # benchmarks/

    truth, names, V = fit_coverage.truth_of("wide")
    stats, _ = fit_coverage.exact_statistics(truth, V, names)
    columns = {s: np.asarray(stats[s]) for s in STATISTICS}
    columns.update({f"{s}_std": 0.01 * np.abs(stats[s]) for s in STATISTICS})
    result = fit_stick_slip(StickSlipTable.from_dict(V=np.asarray(V), **columns), free=names, intervals="linear")
    u = result.uncertainty
    for name, value, se in zip(u.names, u.values, u.standard_errors):
        assert abs(value - float(getattr(truth, name))) < 0.2 * se, (name, value, se, result.summary())
    assert result.converged and result.chi2_dof < 0.05 and not result.missing, result.summary()


def test_an_interrupted_levenberg_marquardt_keeps_its_best_point(monkeypatch):
    """Ctrl-C inside the table fit's Levenberg-Marquardt (window rows, and rows on their
    attractors): a FitInterrupted (a KeyboardInterrupt) whose best point is the lowest chi2 so far."""
    from types import SimpleNamespace

    from peeljax import AdhesionLaw
    from peeljax.fit import FitInterrupted
    from peeljax.fit import table as table_module

    # r(z) = z - 1 on one coefficient: each step moves toward z = 1
    def evaluated(z):
        return np.array([z[0] - 1.0, 0.0]), np.array([[1.0], [0.0]]), np.array([0.1, 5.0])

    calls = []

    def batch(fit, zs, n):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return [evaluated(z) for z in zs]

    monkeypatch.setattr(table_module, "_evaluate_batch", batch)
    fit = SimpleNamespace(names=("c1",), start=AdhesionLaw())
    options = dict(fit_rtol=1e-12, fit_atol=1e-30, max_iterations=10)
    with pytest.raises(FitInterrupted) as stop:
        table_module._solve(fit, np.array([[0.0]]), [evaluated(np.array([0.0]))], **options)
    best = stop.value.best
    assert isinstance(stop.value, KeyboardInterrupt) and best.stop_reason == "interrupted after 1 iterations"
    assert best.final_loss < best.initial_loss == 1.0 and best.free == ("c1",)
    assert float(best.adhesion.c1) == pytest.approx(400.0 * np.exp(1.0), rel=1e-2)  # one step to z = log(c/c0) ~ 1

    # the attractor rows' loop: the same, through fit_rows
    class Rows:
        n = 0

        def start(self):
            return SimpleNamespace(z=np.zeros(1), r=np.array([-1.0, 0.0]), J=np.array([[1.0], [0.0]]),
                                   v_range=np.array([0.1, 5.0]), changes=())  # fmt: skip

        def evaluate(self, z, state):
            Rows.n += 1
            if Rows.n == 2:
                raise KeyboardInterrupt
            r, J, v = evaluated(z)
            return SimpleNamespace(z=z, r=r, J=J, v_range=v, changes=())

    with pytest.raises(FitInterrupted) as stop:
        table_module.fit_rows(Rows(), AdhesionLaw(), ("c1",), {**options, "progress": None}, scale=True,
                               intervals="linear", level=0.95)  # fmt: skip
    assert stop.value.best.final_loss < 1.0 and "interrupted" in stop.value.best.stop_reason


def test_rounds_that_never_settle_from_rest_keep_the_round_of_least_chi2():
    """Where rest reaches the other of two coexisting attractors at every optimum, the rounds
    alternate between them until ``ROUNDS`` is used up; the round of least χ² is kept (not the
    last), and the crossings say so. With records (an instrument bias that moves between
    rounds) the last is kept."""
    from types import SimpleNamespace

    from peeljax.fit import table as table_module

    floors = {"a": 1.0, "b": 3.0}  # r = (z − 1, floor): each branch's least χ² is floor²

    class Rows:
        has_instruments = False

        def __init__(self):
            self.rounds = 0

        def evaluate(self, z, state):
            r = np.array([z[0] - 1.0, floors[state.branch]])
            return SimpleNamespace(z=z, r=r, J=np.array([[1.0], [0.0]]), v_range=np.array([0.1, 5.0]), changes=(),
                                   branch=state.branch)  # fmt: skip

        def from_rest(self, state):
            self.rounds += 1
            return [0]  # rest reaches the other attractor at every optimum

        def forget(self, state, rows):
            return SimpleNamespace(branch="b" if state.branch == "a" else "a")

        def update_bias(self, state):
            return 1.0

    options = dict(fit_rtol=1e-12, fit_atol=1e-12, max_iterations=10, progress=None)
    for instruments, kept in ((False, "a"), (True, "b")):
        rows = Rows()
        rows.has_instruments = instruments
        start = rows.evaluate(np.zeros(1), SimpleNamespace(branch="a"))
        crossings = []
        run = table_module._rounds(rows, start, options, crossings, [0], [])
        assert rows.rounds == table_module.ROUNDS  # a, b, a, b: the last on b
        assert run.state.branch == kept and run.chi2 == pytest.approx(floors[kept] ** 2)
        said = [c["why"] for c in crossings if c["row"] is None]
        assert said == ([] if instruments else [said[0]]) and (instruments or "least chi2" in said[0]), crossings
