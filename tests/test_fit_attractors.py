"""The table fit on the attractor's own statistics: profile-likelihood intervals across jumps, the
instrument's view of a record, records of every kind, steady rows — the parts that need no
compiled orbit (fast), and one small fit through the orbits (slow)."""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from peeljax import PeelingModel
from peeljax.fit import StickSlipTable, fit_records, fit_stick_slip
from peeljax.measurements.instrument import Instrument, recorded_statistics
from peeljax.measurements.statistics import record_cycles
from peeljax.measurements.statistics import STATISTICS, noise_level
from peeljax.fit.profile import profile
from peeljax.fit.records_fit import MIN_SLIPS, how_fitted, settled
from peeljax.fit.levenberg_marquardt import LevenbergMarquardt
from peeljax.fit.table_rows import Point
from peeljax.measurements.observations import Observation
from peeljax.fit.uncertainty import quantile

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

# ---------------------------------------------------------------------------- profile likelihood


class _Rows:
    """A fake table: residuals r(z) of a linear model on branches (``branch(z)`` → (k, r, J))."""

    def __init__(self, branch):
        self.branch, self.evaluations = branch, 0

    def evaluate(self, z, base=None):
        self.evaluations += 1
        z = np.asarray(z, float)
        k, r, J = self.branch(z)
        return Point(z=z, r=np.asarray(r, float), J=np.asarray(J, float), v_range=np.zeros((1, 2)), values=np.zeros((1, 5)),
                     available=np.ones((1, 5), bool), attractors=[None], orbits={}, branch=(k,))  # fmt: skip


def _profile(rows, z_hat, j, se):
    best = rows.evaluate(z_hat)
    return profile(rows, best, j, se_log=se, threshold=quantile(0.95, None) ** 2, level=0.95, c_hat=1.0,
                   fit_rtol=1e-10, fit_atol=1e-10)  # fmt: skip


def test_profile_of_a_quadratic_chi2_is_the_linearized_interval():
    """Linear residuals in two coefficients, correlated: the profile's set is one interval,
    θ̂_j ± q·SE_j (the inner fit of the other coefficient included), to the grid's interpolation."""
    rng = np.random.default_rng(0)
    A = rng.normal(size=(12, 2)) + np.array([3.0, 2.8])  # strongly correlated columns
    y = rng.normal(size=12)
    rows = _Rows(lambda z: (0, A @ z - y, A))
    z_hat = np.linalg.lstsq(A, y, rcond=None)[0]
    se = np.sqrt(np.diag(np.linalg.inv(A.T @ A)))
    q = quantile(0.95, None)
    for j in range(2):
        p = _profile(rows, z_hat, j, se[j])
        assert len(p.intervals) == 1 and not p.jumps
        lo, hi = (math.log(x) for x in p.intervals[0])  # c = c_hat·exp(δ), c_hat = 1
        assert lo == pytest.approx(-q * se[j], rel=0.03) and hi == pytest.approx(q * se[j], rel=0.03)


def test_profile_across_a_bifurcation_is_a_union_with_the_jump_located():
    """One coefficient, χ² quadratic about 0 until a bifurcation at z = 1.5 SE, where the
    statistics jump onto a branch whose χ² is quadratic about 3.5 SE with a floor of 2: the 95 %
    set is [−1.96, 1.5] ∪ [3.5 − √1.84, 3.5 + √1.84] SE, a union; the end at the jump is
    bisected to it, the others interpolated on their branch."""
    se, q2 = 0.01, quantile(0.95, None) ** 2

    def branch(z):
        x = float(z[0]) / se
        if x <= 1.5:
            return 0, [x, 0.0], [[1 / se], [0.0]]
        return 1, [x - 3.5, math.sqrt(2.0)], [[1 / se], [0.0]]

    p = _profile(_Rows(branch), np.zeros(1), 0, se)
    ends = [(math.log(lo) / se, math.log(hi) / se) for lo, hi in p.intervals]
    assert len(ends) == 2
    (a, b), (c, d) = ends
    h = math.sqrt(q2) / 3  # the grid step in SE
    assert a == pytest.approx(-math.sqrt(q2), abs=0.06)
    assert b == pytest.approx(1.5, abs=h / 2**3)  # bisected thrice
    assert c == pytest.approx(3.5 - math.sqrt(q2 - 2), abs=0.06)
    assert d == pytest.approx(3.5 + math.sqrt(q2 - 2), abs=0.06)
    assert len(p.jumps) == 1 and math.log(p.jumps[0][0]) / se < 1.5 < math.log(p.jumps[0][1]) / se


def test_a_profiles_inner_fit_stops_once_chi2_is_known_to_its_share_of_the_threshold(monkeypatch):
    """A curved valley (residuals quadratic in the coefficients, correlated): the others' fit
    at each grid point stops once its Gauss–Newton step would lower χ²_p by at most INNER_ATOL
    of the threshold. The ends of the set are those of the fit run to 1e-10 within 1e-3
    linearized half-widths, with fewer evaluations."""
    import peeljax.fit.profile as profile_module

    se = 0.01

    def branch(z):
        a, b = np.asarray(z, float) / se
        r = [a + 0.6 * b + 0.15 * b * b, b - 0.1 * a * a + 0.2, 0.3 * a * b - 0.1, 0.5 * a - 0.4 * b]
        J = [[1.0, 0.6 + 0.3 * b], [-0.2 * a, 1.0], [0.3 * b, 0.3 * a], [0.5, -0.4]]
        return 0, r, np.asarray(J) / se

    start = _Rows(branch).evaluate(np.zeros(2))
    best = LevenbergMarquardt(start.z, start.r, start.J, start.v_range, fit_rtol=1e-14, fit_atol=1e-14,
                              max_iterations=50, state=start)  # fmt: skip
    while best.reason is None:
        point = _Rows(branch).evaluate(best.trial())
        best.take(point.r, point.J, point.v_range, state=point)
    ends, evaluations, share = {}, {}, profile_module.INNER_ATOL
    for inner in (share, 0.0):
        monkeypatch.setattr(profile_module, "INNER_ATOL", inner)
        p = _profile(_Rows(branch), best.z, 0, se)
        assert len(p.intervals) == 1
        ends[inner] = np.log(p.intervals[0]) - best.z[0]
        evaluations[inner] = p.evaluations
    half_width = quantile(0.95, None) * se  # the linearized half-width, to the curvature's order
    assert np.max(np.abs(ends[share] - ends[0.0])) <= 1e-3 * half_width
    assert evaluations[share] < evaluations[0.0]


def test_auto_profiles_only_the_coefficients_whose_interval_holds_a_bifurcation():
    """Two uncorrelated coefficients, a bifurcation at z₁ = 1 SE (inside c1's linearized
    interval) and none along c2's: ``intervals="auto"`` profiles c1 alone and keeps c2's
    linearized interval; ``"profile"`` profiles both."""
    from peeljax.fit.table import _profiles_if_needed
    from peeljax.fit.uncertainty import uncertainty_from_jacobian

    se = 0.01
    A = np.diag([1 / se, 1 / se])

    class Rows(_Rows):  # a point on another branch than the one it steps from names the change
        def evaluate(self, z, base=None):
            point = super().evaluate(z, base)
            if base is not None and base.branch != point.branch:
                point.changes = [{"row": 0, "V": 1.0, "from": base.branch[0], "to": point.branch[0], "why": "test"}]
            return point

    rows = Rows(lambda z: (int(z[0] > se), A @ z, A))
    start = rows.evaluate(np.zeros(2))
    best = LevenbergMarquardt(start.z, start.r, start.J, start.v_range, fit_rtol=1e-10, fit_atol=1e-10, max_iterations=10,
                      state=start)  # fmt: skip
    uncertainty = uncertainty_from_jacobian(best.J, best.r, np.ones(2), ("c1", "c2"), scaled=False)
    options = {"fit_rtol": 1e-10, "fit_atol": 1e-10}
    auto = _profiles_if_needed(rows, best, uncertainty, "auto", 0.95, options)
    assert sorted(auto) == ["c1"] and auto["c1"].jumps
    assert sorted(_profiles_if_needed(rows, best, uncertainty, "profile", 0.95, options)) == ["c1", "c2"]
    # a row judged by χ² alone (or by window statistics) at the optimum: χ² is rough, "auto"
    # keeps the linearized intervals, "profile" still computes them
    for rough in ({"singular": {0: 1e4}}, {"windowed": (0,)}):
        best.state = dataclasses.replace(start, **rough)
        assert _profiles_if_needed(rows, best, uncertainty, "auto", 0.95, options) == {}
        assert sorted(_profiles_if_needed(rows, best, uncertainty, "profile", 0.95, options)) == ["c1", "c2"]


# ---------------------------------------------------------------------------- records


def _sawtooth(T=0.02, rise=0.016, F0=200.0, F1=220.0, duration=3.0, dt=1e-4, noise=0.0, seed=0):
    """A piecewise-linear sawtooth: F rises from F0 to F1 over ``rise``, falls back over T − rise."""
    t = np.arange(0.0, duration, dt)
    phase = np.mod(t, T)
    F = np.where(phase < rise, F0 + (F1 - F0) * phase / rise, F1 - (F1 - F0) * (phase - rise) / (T - rise))
    return t, F + noise * np.random.default_rng(seed).standard_normal(t.size)


def test_the_instrument_sees_a_sawtooth_as_the_phase_averaged_samples_predict():
    """A sawtooth sampled every Δt with a random phase: its maxima lie below the corner by
    (Δt/2)·ab/(a + b) on average (a, b the rise and fall rates; the sample before or after the
    corner, whichever is higher), its minima above by the same; its 'slip duration' from a
    maximum to the next minimum is longer than the fall by (Δt/2)·((c − d) − (a − b))/(a + b)
    with c = b, d = a here (the sample after the minimum is usually the one kept)."""
    T, rise, F0, F1, dt = 0.0201234, 0.016, 200.0, 220.0, 1e-3  # T/Δt not whole: the phase drifts cycle to cycle
    a, b = (F1 - F0) / rise, (F1 - F0) / (T - rise)
    t, F = _sawtooth(T, rise, F0, F1, duration=T, dt=1e-6)  # one period, densely
    seen = recorded_statistics(t, F, T, Instrument(dt=dt, noise=0.0, duration=4.0), replicates=4)
    shift = 0.5 * dt * a * b / (a + b)
    assert seen["F_slip"] == pytest.approx(F1 - shift, abs=0.02 * shift)
    assert seen["F_stick"] == pytest.approx(F0 + shift, abs=0.02 * shift)
    assert seen["period"] == pytest.approx(T, rel=1e-4)
    offset = 0.5 * dt * ((b - a) / (a + b) - (a - b) / (a + b))
    assert seen["slip_duration"] == pytest.approx((T - rise) + offset, abs=0.02 * dt)


def _beating_sawtooth(T=0.02, rise=0.016, cycles=5, n=20001):
    """One period (``cycles`` sawtooth cycles) of a sawtooth whose peak beats cycle to cycle, as
    a long orbit's slips do: the mean of a short record depends on where in it the record falls."""
    t = np.linspace(0.0, cycles * T, n)
    k, phase = np.floor(t / T), np.mod(t, T)
    F1 = 220.0 + 6.0 * np.sin(2 * np.pi * k / cycles)
    F = np.where(phase < rise, 200.0 + (F1 - 200.0) * phase / rise, F1 - (F1 - 200.0) * (phase - rise) / (T - rise))
    return t, F, cycles * T


def test_a_records_covariance_is_the_scatter_of_records_at_other_phases():
    """Records of a beating sawtooth at random phases scatter as the instrument's draws predict
    (the covariance a records fit whitens its rows by), not as their own cycle-to-cycle
    standard errors say."""
    from peeljax.measurements.instrument import _recorded_draws, record_covariance
    from peeljax.measurements.stick_slip_table import StickSlipTable

    t_p, F_p, P = _beating_sawtooth()
    inst = Instrument(dt=5e-4, noise=0.3, duration=0.37)
    draws, _ = _recorded_draws(t_p, F_p, P, inst, seed=1, replicates=200)
    cov = record_covariance(draws)
    R, p = 200, 5
    assert np.allclose(cov, np.cov(draws, rowvar=False) * (R - 1) / (R - p - 2) * (1 + 1 / R)
                       + np.diag((1e-6 * draws.mean(axis=0)) ** 2) * (1 + 1 / R))  # fmt: skip
    predicted = np.sqrt(np.diag(cov) / ((R - 1) / (R - p - 2) * (1 + 1 / R)))
    rng = np.random.default_rng(7)
    records, errors = [], []
    for _ in range(200):  # records of the same length, elsewhere in the period, with other noise
        t = rng.uniform(0.0, P) + inst.dt * np.arange(int(inst.duration / inst.dt) + 1)
        F = np.interp(np.mod(t, P), t_p, F_p) + inst.noise * rng.standard_normal(t.size)
        records.append(list(inst.statistics(t - t[0], F).get(s, np.nan) for s in STATISTICS))
        table = StickSlipTable.from_force_records([Observation(V=1.0, t=t - t[0], v=None, F=F)], std="error")
        errors.append(table.std["F_mean"][0])
    measured = np.nanstd(np.asarray(records), axis=0, ddof=1)
    assert np.allclose(predicted, measured, rtol=0.2)
    # the record's own standard error of F_mean (its cycles taken as independent) misses it
    assert not 0.5 < np.median(errors) / measured[0] < 2.0


def test_a_records_rows_are_whitened_by_their_covariance():
    """χ² of a whitened row is dᵀC⁻¹d over its measured statistics; one without a covariance
    for a statistic keeps that statistic's σ; a row off its orbit is left as it is."""
    from types import SimpleNamespace

    from peeljax.fit.table_rows import TableRows

    d = np.array([[1.0, -2.0, 0.5, 3e-4, 1e-5], [1.0, 1.0, 1.0, 1.0, 1.0]])
    data = np.zeros((2, 5))
    jac = np.arange(20.0).reshape(2, 5, 2)
    a = np.random.default_rng(0).standard_normal((5, 5))
    cov = a @ a.T + np.eye(5)
    cov[4, :], cov[:, 4] = np.nan, np.nan  # slip durations not produced by enough draws
    sigma = np.full((2, 5), 2.0)
    measured = np.array([[True, True, True, False, True], [True] * 5])
    rows = SimpleNamespace(covariance={0: cov, 1: cov}, measured=measured, data=data)
    r, J = d / sigma, jac / sigma[..., None]
    TableRows._whiten(rows, r, J, d, jac, np.ones((2, 5), bool), sigma, orbits={0: None})
    m = [0, 1, 2, 4]
    c = np.zeros((4, 4))
    c[:3, :3] = cov[np.ix_([0, 1, 2], [0, 1, 2])]
    c[3, 3] = 4.0
    assert float(r[0, m] @ r[0, m]) == pytest.approx(float(d[0, m] @ np.linalg.solve(c, d[0, m])))
    assert np.allclose(J[0, m].T @ J[0, m], jac[0, m].T @ np.linalg.solve(c, jac[0, m]))
    assert np.array_equal(r[1], d[1] / 2.0)  # off its orbit: as it was


def test_noise_level_reads_white_noise_off_a_smooth_signal():
    t = np.linspace(0.0, 1.0, 20001)
    x = 250.0 + 30.0 * np.sin(2 * np.pi * 3 * t) + 1.25 * np.random.default_rng(1).standard_normal(t.size)
    assert noise_level(x) == pytest.approx(1.25, rel=0.03)
    inst = Instrument.of_record(t, x)
    assert inst.dt == pytest.approx(5e-5) and inst.noise == pytest.approx(1.25, rel=0.2)  # (record_statistics' own estimate)


def test_each_record_is_fitted_by_statistics_or_points_as_it_is():
    t, F = _sawtooth()
    settle = 245.0 - 20.0 * np.exp(-t / 0.1)
    records = [
        Observation(V=1.1, t=t, v=None, F=F),  # stick-slips: 150 slips
        Observation(V=1.1, t=t, v=None, F=settle),  # settles: no slip
        Observation(V=1.1, t=t, v=np.full(t.size, 1.1), F=settle),  # holds v
    ]
    kinds = [k for k, _ in how_fitted(records)]
    assert kinds == ["statistics", "points", "points"]
    assert [k for k, _ in how_fitted(records[:2], "points")] == ["points", "points"]
    with pytest.raises(ValueError, match="no stick-slip statistics"):
        how_fitted(records[1:2], "statistics")
    with pytest.raises(ValueError, match="holds v or alpha"):
        how_fitted(records[2:], "statistics")
    with pytest.raises(ValueError, match="by must be one of"):
        how_fitted(records, "both")
    few = Observation(V=1.1, t=t[: int(0.2 / 1e-4)], v=None, F=F[: int(0.2 / 1e-4)])  # 5 slips in its second half
    assert how_fitted([few])[0][0] == "points" and MIN_SLIPS > 5


def test_records_table_carries_the_standard_error_of_each_mean():
    t, F = _sawtooth(noise=0.5)
    obs = [Observation(V=1.1, t=t, v=None, F=F)]
    cycle = StickSlipTable.from_force_records(obs, transient=1.0)
    error = StickSlipTable.from_force_records(obs, transient=1.0, std="error")
    cycles = record_cycles(t, F, transient=1.0)["cycles"]
    for s in ("F_mean", "F_slip", "F_stick", "period", "slip_duration"):
        assert error.std[s][0] == pytest.approx(cycle.std[s][0] / math.sqrt(cycles[s].size), rel=1e-12)
        assert error.values[s][0] == cycle.values[s][0]
    with pytest.raises(ValueError, match="std must be"):
        StickSlipTable.from_force_records(obs, std="mean")


def test_bad_options_are_refused_before_anything_compiles():
    table = StickSlipTable.from_dict(V=[1.0, 2.0], F_mean=[240.0, 260.0], F_slip=[255.0, 270.0])
    for kwargs, words in (
        ({"method": "orbits"}, "method must be one of"),
        ({"method": "orbit", "tau": 0.01}, "tau must be 0 with method='orbit'"),
        ({"intervals": "exact"}, "intervals must be one of"),
        ({"level": 95}, "level must be a number in"),
        ({"orbit_rtol": -1.0}, "orbit_rtol"),
    ):  # fmt: skip
        with pytest.raises(ValueError, match=words):
            fit_stick_slip(table, free=("c1",), **kwargs)
    t, F = _sawtooth()
    with pytest.raises(ValueError, match="tau must be > 0"):
        fit_records([Observation(V=1.1, t=t, v=None, F=F)], tau=0.0)
    with pytest.raises(ValueError, match="no records"):
        fit_records([])
    for kwargs, words in (({"max_iterations": 0}, "max_iterations"), ({"intervals": "all"}, "intervals"),
                          ({"level": 1.5}, "level"), ({"by": "rows"}, "by must be one of")):  # fmt: skip
        with pytest.raises(ValueError, match=words):
            fit_records([Observation(V=1.1, t=t, v=None, F=F)], **kwargs)


# ---------------------------------------------------------------------------- through the orbits (slow)

TRUE_C1 = 400.0 * 1.002  # close to the paper's: no bifurcation between the start and the truth
ROWS_V = (1.0, 3.0, 6.0)  # two stick-slip rows and one steady (phi has no fold at 6 m/s)


@pytest.fixture(scope="module")
def truth_rows():
    """The statistics at the truth, each row on its attractor, through the one-coefficient orbit
    program that the fits below share."""
    from peeljax import AdhesionLaw
    from peeljax.fit.table import attractor_statistics

    point, rows, why = attractor_statistics(AdhesionLaw(c1=TRUE_C1), ROWS_V, names=("c1",))
    return point, rows, why


def _table(point, noise, rng):
    from peeljax.measurements.stick_slip_table import STATISTICS

    columns = {}
    for j, name in enumerate(STATISTICS):
        exact = np.where(point.available[:, j], point.values[:, j], np.nan)
        columns[name] = exact * (1 + noise * rng.normal(size=exact.shape))
        columns[f"{name}_std"] = np.where(np.isfinite(exact), 0.01 * np.abs(exact), np.nan)
    return StickSlipTable.from_dict(V=np.asarray(ROWS_V), **columns)


@pytest.mark.slow
def test_rows_are_on_their_attractors_with_derivatives_of_the_orbit(truth_rows):
    """Two stick-slip rows on periodic orbits (stable, k their least number of slips), a steady
    row F = φ(V, V); the Jacobian of the orbit statistics (implicit function theorem) against
    central differences of orbits followed to θ ± h."""
    point, rows, why = truth_rows
    assert rows.kinds == ["orbit", "orbit", "steady"], why
    for i in (0, 1):
        orbit = point.orbits[i]
        assert int(orbit["status"]) == 0 and np.max(orbit["multipliers"]) < 1.0
        assert point.attractors[i].minimal
    assert point.values[2, 0] == pytest.approx(float(rows.law(np.zeros(1))(6.0, 6.0)), rel=1e-12)
    assert point.available[2].tolist() == [True, False, False, False, False]
    h = 1e-5
    plus, minus = rows.evaluate(np.array([h]), point), rows.evaluate(np.array([-h]), point)
    assert not plus.changes and not minus.changes
    fd = (plus.values - minus.values) / (2 * h)
    ad = np.stack([point.orbits[i]["jacobian"][:, 0] for i in (0, 1)])
    np.testing.assert_allclose(ad, fd[:2], rtol=2e-4)


@pytest.mark.slow
def test_table_fit_on_orbits_recovers_the_truth_and_covers_it(truth_rows):
    """Noise-free: the fit lands on the truth (1e-5) with every row on its attractor. Ten draws of
    1 % noise: the 95 % interval covers the truth in at least 8 (P(≤ 7 | 95 %) = 1.2 %)."""
    point, _, _ = truth_rows
    rng = np.random.default_rng(0)
    exact = fit_stick_slip(_table(point, 0.0, rng), free=("c1",))
    assert exact.converged and exact.uncertainty.values[0] == pytest.approx(TRUE_C1, rel=1e-5)
    assert [r["kind"] for r in exact.rows] == ["orbit", "orbit", "steady"]
    assert all(r["stable"] for r in exact.rows[:2]) and "slips per period" in exact.summary()
    covered = sum(fit_stick_slip(_table(point, 0.01, rng), free=("c1",)).covers({"c1": TRUE_C1})["c1"]
                  for _ in range(10))  # fmt: skip
    assert covered >= 8


# ---------------------------------------------------------------------------- the command line


@pytest.fixture
def no_record_fit(monkeypatch):
    from conftest import forbid

    import peeljax.cli.fit  # noqa: F401 - imported first: it reads fit_stick_slip's defaults

    forbid(monkeypatch, "peeljax.fit", "fit_records", "fit_stick_slip", reason="compiled before the input was checked")


def test_record_and_table_options_are_refused_before_anything_compiles(tmp_path, no_record_fit):
    from conftest import assert_refused, run_cli

    t, F = _sawtooth(duration=1.0, dt=1e-3)
    saw = tmp_path / "saw_V1.1.csv"
    saw.write_text("t,F\n" + "\n".join(f"{a:.9g},{b:.9g}" for a, b in zip(t, F)) + "\n")
    smooth = tmp_path / "settle_V1.1.csv"
    smooth.write_text("t,F\n" + "\n".join(f"{a:.9g},{245 - 20 * math.exp(-a / 0.1):.9g}" for a in t) + "\n")
    table = tmp_path / "table.csv"
    table.write_text("V,F_mean,period\n1.1,244,0.022\n1.5,251,0.015\n")
    for argv, words in (
        (["--data", str(saw), "--by", "both"], ["--by", "auto, statistics, points"]),
        (["--data", str(smooth), "--by", "statistics"], ["--by statistics", "no stick-slip statistics"]),
        (["--data", str(saw), "--method", "orbit"], ["--method", "force records"]),
        (["--data", str(saw), "--tau", "0"], ["--tau"]),
        (["--data", str(saw), "--intervals", "wide"], ["--intervals", "auto, profile, linear"]),
        (["--table", str(table), "--by", "points"], ["--by", "--table"]),
        (["--table", str(table), "--tau", "0.01", "--method", "orbit"], ["--method orbit", "--tau 0"]),
        (["--table", str(table), "--method", "orbits"], ["--method", "orbit, window"]),
    ):  # fmt: skip
        code, out, err = run_cli(["fit", *argv, "--out", str(tmp_path / "o.json")])
        assert_refused(code, err, *words, stdout=out)


@pytest.mark.slow
def test_a_transient_record_fits_point_by_point_with_an_interval_that_covers_its_truth():
    """A 1 s record at V = 1.1, τ = 0.01 (from rest, settling to steady peeling; 1 kHz) made with
    c1 = 420: ``fit_records`` fits it point by point (no slip); noise-free it returns 420 to
    1e-6; with 0.5 % noise, 5 draws' 95 % intervals cover 420 in at least 4 (measured 39 of 40:
    benchmarks/fit_records.py --points 40)."""
    import fit_records as bench  # benchmarks/

    t, F = bench.record(1.1, 1e3, 0.0, seed=0, t_final=1.0, tau=0.01)
    exact = fit_records([Observation(V=1.1, t=t, v=None, F=F * (1 + 1e-9 * np.sin(t)))], free=("c1",), tau=0.01)
    assert exact.settings["records"][0]["by"] == "points" and exact.converged
    assert exact.uncertainty.values[0] == pytest.approx(420.0, rel=1e-6)
    rng = np.random.default_rng(2)
    covered = 0
    for _ in range(5):
        noisy = Observation(V=1.1, t=t, v=None, F=F * (1 + 0.005 * rng.standard_normal(F.size)))
        covered += fit_records([noisy], free=("c1",), tau=0.01).covers({"c1": 420.0})["c1"]
    assert covered >= 4


def test_a_record_of_too_few_slips_to_tell_is_judged_by_the_models_own_run():
    """At 2 kHz and 0.5 % noise the record at V = 2.4 shows 11 of its slips over [2, 4] s: too
    few for the halves test, and before, the whole fit fell back on runs from rest over the window
    (c1 −8.7 %, −12.9 SE). The model's noise-free run from rest over the same span sees every
    slip and has settled; a 1 s record at V = 1.1 over [0.5, 1] s has not, nor has its model."""
    import fit_records as bench  # benchmarks/

    model = PeelingModel()
    t, F = bench.record(2.4, 2e3, 0.005, seed=240)
    record = Observation(V=2.4, t=t, v=None, F=F)
    alone, why = settled(record, 2.0)
    assert not alone and "too few to tell" in why
    judged, why = settled(record, 2.0, model)
    assert judged and "the model's run from rest over the same window has settled" in why
    t, F = bench.record(1.1, 2e3, 0.005, seed=110, t_final=1.0)
    short, why = settled(Observation(V=1.1, t=t, v=None, F=F), 0.5, model)
    assert not short and "nor is the model's run" in why
    # another noise draw shows 9 slips, fewer than MIN_SLIPS: it was fitted point by point
    # (c1 −15 %); the model's run from rest shows that it stick-slips
    t, F = bench.record(2.4, 2e3, 0.005, seed=5240)
    few = Observation(V=2.4, t=t, v=None, F=F)
    (alone, _), = how_fitted([few], transient=2.0)
    (judged, why), = how_fitted([few], transient=2.0, model=model)
    assert alone == "points" and judged == "statistics" and "its noise hides the small ones" in why


@pytest.mark.slow
def test_records_at_2khz_fit_as_their_instrument_saw_them():
    """The three 4 s records at V = 1.1, 1.6, 2.4 (c1 = 420, 0.5 % noise) sampled at 2 kHz, fitted
    for c1 from 400 (``benchmarks/fit_records.py --fit 2``): every record by its attractor's
    statistics as the instrument saw them, the truth within 2 standard errors and 1 %."""
    import fit_records as bench  # benchmarks/

    observations = []
    for V in bench.V:
        t, F = bench.record(V, 2e3, 0.005, seed=int(100 * V))
        observations.append(Observation(V=V, t=t, v=None, F=F))
    result = fit_records(observations, free=("c1",))
    assert all("; settled (" in r["why"] for r in result.settings["records"])
    # at 1.6 and 2.4 m/s the noise hides some slips (68 % and 35 % found): F_mean alone
    assert ["slips_found" in r for r in result.rows] == [False, True, True]
    assert "F_mean only" in result.summary()
    assert result.settings["method"] == "orbit" and result.converged
    (value,), (se,) = result.uncertainty.values, result.uncertainty.standard_errors
    assert abs(value - 420.0) <= 2 * se and abs(value / 420.0 - 1) <= 0.01
    assert result.covers({"c1": 420.0})["c1"]


def test_rows_with_a_singular_derivative_are_named_and_left_out_of_the_step():
    """An orbit row whose statistics move 50x faster than the coefficients (near a grazing) is
    named with its elasticity; a row of ordinary slopes, and statistics the row lacks, are not."""
    from peeljax.fit.table_rows import MAX_ELASTICITY, singular_rows

    values = np.array([[200.0, 250.0, 180.0, 0.02, 0.002], [200.0, 250.0, 180.0, 0.02, 0.002]])
    jac = np.zeros((2, 5, 2))
    jac[0, :, 0] = 5.0 * values[0]  # elasticity 5: an ordinary orbit
    jac[1, 3, 1] = 2 * MAX_ELASTICITY * values[1, 3]  # its period 100x as steep
    available = np.ones((2, 5), bool)
    assert singular_rows(values, jac, available, [0, 1]) == {1: pytest.approx(2 * MAX_ELASTICITY)}
    available[1, 3] = False  # a statistic the row does not produce has no slope to judge
    assert singular_rows(values, jac, available, [0, 1]) == {}


@pytest.mark.slow
def test_a_row_held_at_newtons_floor_is_shot_again_at_the_tighter_tolerance():
    """The whole-range table's row at 4 m/s (``benchmarks/fit_coverage.py --problem wide``) with
    c1 moved by −0.025 %: its orbit rides a grazing, and Newton at the fits' tolerance (runs at
    1e-8) stalls at |P^k(z) − z| ≈ 1e-8, above its 1e-10. Before, the row lost its orbit there
    and took its window statistics (``benchmarks/results/fit_roughness_wide_c1.md``: every other
    step of c1). ``shoot_rows`` shoots it again from the last iterate with the runs at
    ``FLOOR_RTOL``: converged, stable, and the statistics those of the stalled iterate."""
    import fit_coverage  # benchmarks/

    import peeljax as pj
    from peeljax.fit.attractors import Attractor, OrbitRows, _shoot_rows, shoot_rows
    from peeljax.orbits import orbit_shooting
    from peeljax.orbits.shooting import FLOOR_RESIDUAL, OrbitStatus

    truth = fit_coverage.truth_of("wide")[0]
    orbit = pj.periodic_orbit(PeelingModel(adhesion=truth), V=4.0)
    assert int(orbit.status) == 0 and int(orbit.slips) == 34
    program = OrbitRows(orbit_shooting(), PeelingModel(), truth, ("c1",))
    start = [Attractor(np.asarray(orbit.section), 34, float(orbit.period))]
    z = np.array([-0.00025])
    stalled = _shoot_rows(program, z, [4.0], start)
    assert int(stalled["status"][0]) == OrbitStatus.NOT_CONVERGED, stalled["residual"]
    assert 1e-10 < stalled["residual"][0] < FLOOR_RESIDUAL
    again = shoot_rows(program, z, [4.0], start)
    assert int(again["status"][0]) == OrbitStatus.CONVERGED and again["residual"][0] <= 1e-10
    assert np.max(again["multipliers"][0]) < 1.0 and np.all(np.isfinite(again["jacobian"][0]))
    np.testing.assert_allclose(again["statistics"][0], stalled["statistics"][0], rtol=1e-7)


def test_where_the_tape_stops_the_rows_attractor_is_an_orbit_that_settles_slowly():
    """φ with c1 × 1.07, c3 × 0.93, c6 × 1.07 at 0.5 m/s (the tape stops after every slip; the
    table of ``benchmarks/fit_coverage.py --problem wide``): the 3 and 8 s runs of
    ``find_attractor`` show a near repeat of 2 slips, whose orbit is unstable. The attractor is
    nevertheless periodic: a 10-slip orbit with |μ₁| = 0.952 (the 5-slip orbit run twice),
    whose slip intervals a 30 s run shows repeating to 1e-3 (they still drift by ~1e-5 s a
    period); ``row_kinds`` finds it by shooting k = 1 … 12 from the run's last slip, and the
    row is an orbit row of 5 slips (before, a window row: docs/fitting.md;
    ``test_a_fits_row_follows_its_orbit_through_a_period_doubling``)."""
    import fit_coverage  # benchmarks/

    import peeljax as pj
    from peeljax.fit.attractors import find_attractor

    model = PeelingModel(adhesion=fit_coverage.truth_of("wide")[0])
    first = find_attractor(model, 0.5)
    near = pj.periodic_orbit(model, V=0.5, start=first.section, slips=first.slips, period=first.period)
    assert first.slips == 2 and int(near.status) == 0 and np.max(np.abs(near.multipliers)) > 1.0
    run = pj.simulate(model, V=0.5, tau=0, t_final=30.0)
    assert pj.cycle_statistics(run, 30.0, transient=15.0).repeat.events == 10
    orbit = pj.periodic_orbit(model, V=0.5, start=run, slips=10)
    mu = np.abs(np.asarray(orbit.multipliers))
    assert int(orbit.status) == 0 and 0.94 < mu.max() < 0.96, (orbit.status, mu)
    assert abs(float(orbit.period) - 1.2122578) < 1e-6  # the run's repeat: 1.21237 s, still settling


@pytest.mark.slow
def test_a_row_whose_runs_show_no_repeat_is_on_the_stable_orbit_shot_from_their_last_slip():
    """A φ where a whole-range fit ended (``benchmarks/fit_coverage.py --problem wide``, draw 2's
    optimum: c1, c3, c6 = 424.28, 121.43, 441.86) at 0.5 m/s: the 3 and 8 s runs from rest show
    no repeat ("irregular"; still settling), yet a 120 s run reaches a periodic orbit. The row
    is shot for k = 1 … 12 from the runs' last slip and is an orbit row on the stable 5-slip
    orbit (|μ₁| 0.933), the orbit the 120 s run reaches. Before, it was a window row, its
    statistics those of a window still settling (in 28 of 60 fits of that benchmark)."""
    import fit_coverage  # benchmarks/

    import peeljax as pj
    from peeljax.fit.attractors import NoRepeat, find_attractor
    from peeljax.fit.table import attractor_statistics

    truth = fit_coverage.truth_of("wide")[0]
    law = eqx.tree_at(lambda law: (law.c1, law.c3, law.c6), truth, (424.2834924656183, 121.4284888069769, 441.85909626655763))
    model = PeelingModel(adhesion=law)
    found = find_attractor(model, 0.5)
    assert isinstance(found, NoRepeat) and "irregular" in str(found) and found.last is not None, found
    assert 0.11 < found.last.period < 0.13  # the mean slip interval
    point, rows, why = attractor_statistics(law, [0.5], names=("c1",), follow_lost=True)
    assert rows.kinds == ["orbit"] and point.attractors[0].slips == 5 and "no repeat" in why[0], why
    assert 0.92 < np.max(point.orbits[0]["multipliers"]) < 0.94
    run = pj.simulate(model, V=0.5, tau=0, t_final=120.0)
    reached = pj.periodic_orbit(model, V=0.5, start=run, slips=10)
    assert int(reached.status) == 0
    per_slip = np.array([float(reached.statistics[name]) for name in ("F_mean", "F_slip", "F_stick", "period")])
    np.testing.assert_allclose(per_slip, point.orbits[0]["statistics"][:4], rtol=1e-6)



@pytest.fixture(scope="module")
def doubling():
    """The whole-range table's truth at 0.5 m/s (the tape stops after every slip): its 5-slip
    attractor, a multiplier −0.976, crosses −1 at log c1 ≈ −0.0004 (a period doubling)."""
    import fit_coverage  # benchmarks/

    import peeljax as pj

    truth = fit_coverage.truth_of("wide")[0]
    run = pj.simulate(PeelingModel(adhesion=truth), V=0.5, tau=0, t_final=30.0)
    orbit = pj.periodic_orbit(PeelingModel(adhesion=truth), V=0.5, start=run, slips=5)
    past = PeelingModel(adhesion=eqx.tree_at(lambda law: law.c1, truth, truth.c1 * np.exp(-0.001)))
    return truth, orbit, past


@pytest.mark.slow
def test_past_a_period_doubling_deflated_newton_reaches_the_doubled_orbit(doubling):
    """0.1 % of c1 past the doubling the 5-slip orbit has a multiplier below −1, and the orbit of
    10 slips born there is the attractor (stable; an 80 s run settles on it). Newton for 10 slips
    from beside the 5-slip orbit returns to it (it is a fixed point of P¹⁰ too); with the
    5-slip orbit deflated away it reaches the doubled orbit, whose statistics per slip are
    within 0.2 % of the 5-slip orbit's (continuous through the doubling)."""
    from peeljax.orbits.api import orbit_of, orbit_shooting
    from peeljax.orbits.section import SlipSection

    _, orbit, past = doubling
    shooting = orbit_shooting(max_iterations=40)  # (near the doubling I − M is near-singular: 16–20 iterations)
    shoot = eqx.filter_jit(orbit_of)
    V, t5 = jnp.asarray(0.5), jnp.asarray(3 * float(orbit.period))
    five = shoot(shooting, past, V, orbit.section, jnp.asarray(5, jnp.int32), t5)
    values, vectors = np.linalg.eig(np.asarray(five.monodromy))
    m = int(np.argmax(np.abs(values)))
    assert int(five.status) == 0 and abs(values[m].imag) < 1e-12 and values[m].real < -1.0, values
    scale = np.asarray(SlipSection.at(past, 0.5).scale)
    e = np.real(vectors[:, m]) / np.max(np.abs(np.real(vectors[:, m]) / scale))
    start, ten, t10 = np.asarray(five.section) + 1e-3 * e, jnp.asarray(10, jnp.int32), 2 * t5
    plain = shoot(shooting, past, V, jnp.asarray(start), ten, t10)
    assert np.max(np.abs(np.asarray(plain.section) - np.asarray(five.section)) / scale) < 1e-6
    deflated = shoot(shooting, past, V, jnp.asarray(start), ten, t10, five.section)
    apart = np.max(np.abs(np.asarray(deflated.section) - np.asarray(five.section)) / scale)
    assert int(deflated.status) == 0 and np.max(np.abs(deflated.multipliers)) < 1.0 and apart > 0.05, apart
    for name in ("F_mean", "F_slip", "F_stick", "period"):
        assert abs(float(deflated.statistics[name]) / float(five.statistics[name]) - 1) < 2e-3, name
    # no point to avoid (NaN) is no deflation: the same bits as without
    nan = shoot(shooting, past, V, jnp.asarray(start), ten, t10, jnp.full(2, jnp.nan))
    np.testing.assert_array_equal(np.asarray(nan.section), np.asarray(plain.section))


@pytest.mark.slow
def test_a_fits_row_follows_its_orbit_through_a_period_doubling(doubling):
    """The table's row at 0.5 m/s followed from the truth to 0.1 % of c1 past the doubling: it
    stays an orbit row (the 10-slip orbit born there; before, the orbit was lost and the row
    took its window statistics), the crossing is named, and its statistics are within 0.2 % of
    the (now unstable) 5-slip orbit's there (0.12 % for the period): continuous through the
    doubling, the difference growing with the distance to it. Back at the truth and past the
    doubling again, the row is on its orbit, the same as the first time."""
    from peeljax.fit.table import attractor_statistics

    truth, _, _ = doubling
    point, rows, why = attractor_statistics(truth, [0.5], names=("c1",), follow_lost=True)
    assert rows.kinds == ["orbit"] and point.attractors[0].slips == 5, why
    past = rows.evaluate(np.array([-0.001]), point)
    assert 0 in past.orbits and not past.windowed and past.attractors[0].slips == 10, past.changes
    assert [c["to"] for c in past.changes] == [10] and "period doubling" in past.changes[0]["why"]
    five = rows._shoot(past.z, [0], [point.attractors[0]])[0]
    assert int(five["status"]) == 0 and int(five["slips"]) == 5 and np.max(five["multipliers"]) > 1.0
    np.testing.assert_allclose(past.values[0], five["statistics"], rtol=2e-3)
    back = rows.evaluate(np.array([0.0]), past)  # the doubled orbit becomes the 5-slip one run twice
    again = rows.evaluate(np.array([-0.001]), back)
    for point in (back, again):
        assert 0 in point.orbits and not point.windowed, point.changes
    np.testing.assert_allclose(again.values[0], past.values[0], rtol=1e-6)
