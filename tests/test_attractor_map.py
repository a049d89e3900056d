"""The attractor map: sweeps from given states, the state kept at each lane's last slip, labels
checked against the periodic orbit and the Lyapunov exponents' rule, files, and bad input."""

from __future__ import annotations

import dataclasses
import importlib
import types

import numpy as np
import pytest

import peeljax as pj
from peeljax.attractor_map import (
    ATTRACTOR_KINDS,
    CHAOTIC,
    IRREGULAR,
    PERIODIC,
    QUASI_PERIODIC,
    UNSTABLE,
    _Attractor,
    _change,
    _label_irregular,
    _labels,
    _merge,
    _run,
    _steady_states,
    attractor_label,
    attractor_map,
)
from peeljax.branches import phi_folds


@pytest.mark.slow
def test_a_sweep_from_given_states_is_the_run_from_them():
    model = pj.PeelingModel()
    y0 = np.asarray(model.consistent_state(1.1, 0.1, 5.0, 0.05))
    result = pj.sweep(V=[1.1, 1.1], tau=0, grid="pairs", start=np.stack([y0, model.initial_state(1.1)]), t_final=1.0,
                      progress=False)  # fmt: skip
    run = pj.simulate(V=1.1, tau=0, t_final=1.0, y0=y0)
    assert result.jumps["jump_count"][0] == run.stats["jumps"]
    paper = pj.sweep(V=1.1, tau=0, t_final=1.0, progress=False)
    assert result.jumps["jump_count"][1] == paper.jumps["jump_count"][0]
    np.testing.assert_allclose(result.v_mean[1], paper.v_mean[0], rtol=1e-12)


@pytest.mark.parametrize(
    ("start", "message"),
    [(np.zeros((3, 4)), r"shape \(4,\) or \(n, 4\) with n = 2"), (np.full(4, np.nan), "finite"), ("rest", "start")],
)
def test_bad_start_states_are_refused_before_compiling(start, message):
    with pytest.raises(ValueError, match=message):
        pj.sweep(V=[1.1, 2.0], tau=0, grid="pairs", start=start, progress=False)


def test_each_lane_keeps_the_state_at_its_last_slip_on_the_section():
    model = pj.PeelingModel()
    result = pj.sweep(V=[1.1, 2.0], tau=0, grid="pairs", t_final=1.0, progress=False)
    for V, y in zip((1.1, 2.0), result.cycles["cycle_slip_state"]):
        folds = phi_folds(model, V)
        np.testing.assert_allclose(y[3], float(folds.v_max), rtol=1e-9)  # v = v̂: just before the slip
        np.testing.assert_allclose(float(model.shear_force(y[:3])), float(folds.phi_max), rtol=1e-9)  # G = φ(v̂)


@pytest.mark.parametrize(
    ("lam", "se", "kind"),
    [
        ((0.8, -0.1), (0.05, 0.05), CHAOTIC),
        ((0.01, -0.02), (0.01, 0.01), QUASI_PERIODIC),
        ((0.0, -2.7), (0.01, 0.01), PERIODIC),  # a limit cycle: λ₂ < 0 makes λ₁ the flow's zero
        ((0.1, -2.7), (0.2, 0.2), PERIODIC),  # (λ₁ itself known to 0.2 only)
        ((0.1, -0.3), (0.2, 0.2), IRREGULAR),  # λ₂ not negative beyond 3 SE: nothing decided
        ((np.nan, np.nan), (np.nan, np.nan), IRREGULAR),
        ((0.8, -0.1), (np.nan, np.nan), IRREGULAR),  # no standard error: nothing decided
    ],
)
def test_the_exponents_rule(lam, se, kind):
    assert _label_irregular(np.asarray(lam), np.asarray(se), 0.05) == kind


def test_a_run_near_an_unstable_orbit_is_no_attractor():
    """A row with its own label (where runs linger), never a seed; a branch's seed that stays
    near its orbit, now unstable, names the boundary."""
    orbit = _Attractor(j=0, kind=PERIODIC, slips=1, period=3.9e-3, multiplier=0.98, lanes={}, state=np.zeros(4))
    near = dataclasses.replace(orbit, kind=UNSTABLE, period=3.871e-3, multiplier=1.0004)
    assert attractor_label(UNSTABLE, 1) == "near an unstable orbit (k=1)"
    attractors: dict = {}
    assert _merge(attractors, [near, dataclasses.replace(near), orbit], np.array([False, True, False])) == [near, orbit]
    assert (near.hits, near.random_hits) == (2, 1)  # one row for both runs; the random start's share
    assert _change(orbit, near) == "loses stability (|mu1| = 1.000400)"
    assert _change(orbit, dataclasses.replace(near, slips=2)) == "lost to near an unstable orbit (k=2)"


def test_padding_lanes_of_a_round_of_orbits_shoot_nothing(monkeypatch):
    """A round of 3 orbits is padded to a whole chunk: the padding lanes' runs end at once (one
    return map evaluated, none reached) where copies of the last lane would shoot its orbit 13
    more times; the lanes given come back, the padding dropped."""
    am = importlib.import_module("peeljax.attractor_map")
    batch = importlib.import_module("peeljax.orbits.batch")
    seen = {}

    def periodic_orbits(model, V, start, slips, period, rtol, max_iterations):
        seen.update(V=V, slips=slips, period=period)
        n = V.size
        fields = {"multipliers": np.zeros((n, 2)), "period": period, "state": np.zeros((n, 4)), "residual": np.ones(n)}
        return types.SimpleNamespace(status=np.arange(n), **fields)

    monkeypatch.setattr(batch, "periodic_orbits", periodic_orbits)
    out = am._padded_orbits(None, np.array([1.0, 1.1, 1.2]), np.zeros((3, 4)), [1, 2, 3], [0.2, 0.3, 0.4], 1e-8)
    assert out["status"].tolist() == [0, 1, 2] and out["period"].tolist() == [0.2, 0.3, 0.4]
    assert seen["V"].size == am._CHUNK and np.all(seen["period"][3:] == am._IDLE_PERIOD)
    last = {"V": float(seen["V"][-1]), "slips": int(seen["slips"][-1]), "start": (0.3, 16.0)}
    idle = pj.periodic_orbit(**last, period=am._IDLE_PERIOD)
    assert int(idle.iterations) == 1 and int(idle.status) == pj.OrbitStatus.EVENTS_CHANGED


def test_a_solve_held_at_newtons_floor_is_shot_again_at_the_tighter_tolerance(monkeypatch):
    """Of three solves that end NOT_CONVERGED, the two whose residual is below the floor's bound
    are shot again at ``_FLOOR_RTOL`` from their last iterate and period; the one that converges
    there is kept, the one that does not stays as it was; the wanderer (residual 1e-2) is not
    shot again."""
    am = importlib.import_module("peeljax.attractor_map")
    batch = importlib.import_module("peeljax.orbits.batch")
    calls = []

    def periodic_orbits(model, V, start, slips, period, rtol, max_iterations):
        calls.append({"V": np.asarray(V), "start": np.asarray(start), "period": np.asarray(period), "rtol": rtol})
        n = V.size
        tight = rtol <= am._FLOOR_RTOL
        status = np.where(tight & (V < 1.15), pj.OrbitStatus.CONVERGED, pj.OrbitStatus.NOT_CONVERGED)
        residual = np.where(tight, 1e-11, np.where(V < 1.25, 1e-9, 1e-2))
        state = np.column_stack([V + (0.0 if tight else 0.5), np.zeros((n, 3))])
        return types.SimpleNamespace(status=status, residual=residual, state=state,
                                     period=np.asarray(period) + 0.01, multipliers=np.full((n, 2), 0.5))  # fmt: skip

    monkeypatch.setattr(batch, "periodic_orbits", periodic_orbits)
    V = np.array([1.1, 1.2, 1.3])
    out = am._padded_orbits(None, V, np.zeros((3, 4)), [44, 50, 3], [2.0, 3.0, 0.4], 1e-8)
    assert [c["rtol"] for c in calls] == [1e-8, am._FLOOR_RTOL]
    again = calls[1]
    assert again["V"][:2].tolist() == [1.1, 1.2] and np.all(again["period"][2:] == am._IDLE_PERIOD)
    assert again["start"][:2, 0].tolist() == [1.6, 1.7] and again["period"][:2].tolist() == [2.01, 3.01]
    assert out["status"].tolist() == [pj.OrbitStatus.CONVERGED, pj.OrbitStatus.NOT_CONVERGED, pj.OrbitStatus.NOT_CONVERGED]
    assert out["residual"].tolist() == [1e-11, 1e-9, 1e-2] and out["period"][0] == pytest.approx(2.02)
    calls.clear()
    am._padded_orbits(None, V, np.zeros((3, 4)), [44, 50, 3], [2.0, 3.0, 0.4], am._FLOOR_RTOL)
    assert len(calls) == 1  # already at the floor's tolerance: nothing to shoot again


def test_a_round_of_orbits_is_chunked_in_order_of_slips_and_comes_back_in_the_callers_order(monkeypatch):
    """20 lanes of mixed k go to the batches sorted by (k, period guess), so that lanes of like
    cost share a chunk; each result comes back to its own lane."""
    am = importlib.import_module("peeljax.attractor_map")
    batch = importlib.import_module("peeljax.orbits.batch")
    chunks = []

    def periodic_orbits(model, V, start, slips, period, rtol, max_iterations):
        chunks.append(np.asarray(slips))
        n = V.size
        return types.SimpleNamespace(status=np.zeros(n, int), residual=np.zeros(n), state=np.column_stack([V] * 4),
                                     period=np.asarray(period), multipliers=np.zeros((n, 2)))  # fmt: skip

    monkeypatch.setattr(batch, "periodic_orbits", periodic_orbits)
    rng = np.random.default_rng(0)
    slips = rng.integers(1, 60, 20)
    V, period = rng.uniform(0.3, 5.4, 20), rng.uniform(0.1, 1.0, 20)
    out = am._padded_orbits(None, V, np.zeros((20, 4)), slips, period, 1e-8)
    assert np.all(np.diff(chunks[0]) >= 0) and chunks[0].max() <= np.sort(slips)[am._CHUNK - 1]
    assert np.array_equal(out["state"][:, 0], V) and np.array_equal(out["period"], period)


def test_runs_that_reach_one_orbit_from_several_starts_refine_it_once(monkeypatch):
    """Candidates of one V and k whose repeat periods agree to ``_TWIN_RTOL`` are twins: the
    orbit is refined from the first, and the others take its outcome; another V, another k or
    a period farther off is refined on its own."""
    am = importlib.import_module("peeljax.attractor_map")
    V = np.array([1.0, 1.0, 1.0, 2.0, 1.0, 1.0])
    slips = np.array([5, 5, 5, 5, 6, 5])
    period = np.array([0.2, 0.2 * (1 + 0.5 * am._TWIN_RTOL), 0.3, 0.2, 0.2, 0.2 * (1 + 3 * am._TWIN_RTOL)])
    assert am._first_twins(V, slips, period).tolist() == [0, 0, 2, 3, 4, 5]
    seen = {}

    def refine(model, V, state, slips, period, orbit_rtol):
        seen["V"], seen["slips"] = V, slips
        n = V.size
        return np.arange(n) % 2 == 0, np.zeros(n, bool), slips, period + 1e-3 * np.arange(n), np.full(n, 0.5)

    monkeypatch.setattr(am, "_candidates", lambda lanes: (np.full(6, am.PERIODIC), slips.copy(), period.copy()))
    monkeypatch.setattr(am, "_refine", refine)
    kind, k, T, mu1 = am._labels(None, V, {"slip_state": np.zeros((6, 4))}, {"orbit_rtol": 1e-8})
    assert seen["V"].tolist() == [1.0, 1.0, 2.0, 1.0, 1.0] and seen["slips"].tolist() == [5, 5, 5, 6, 5]
    assert kind.tolist() == [am.PERIODIC, am.PERIODIC, am.IRREGULAR, am.PERIODIC, am.IRREGULAR, am.PERIODIC]
    assert T[1] == T[0] == pytest.approx(0.2) and T[3] == pytest.approx(0.202) and T[5] == pytest.approx(0.20006 + 4e-3)


@pytest.mark.parametrize("boundary", [0.95317, 0.99995])
def test_a_branch_end_is_located_by_continuing_its_orbit(monkeypatch, boundary):
    """A model of Newton that finds the orbit below ``boundary`` only from an orbit at most 2e-3
    away (a start from farther fails, as a real Newton may): the continuation tries every far
    failure again from closer, brackets the end to 1e-4 and names it from one run beyond."""
    am = importlib.import_module("peeljax.attractor_map")

    def orbits(model, V, state, slips, period, orbit_rtol, max_iterations=20):
        ok = (V < boundary) & (np.abs(V - state[:, 0]) <= 2e-3)
        n = V.size
        return {"status": np.where(ok, 0, 1), "multipliers": np.tile([0.5, 0.1], (n, 1)),
                "period": np.asarray(period, float), "state": np.column_stack([V, np.zeros((n, 3))]),
                "approach": np.full(n, -1.0), "iterations": np.full(n, 3)}  # fmt: skip

    beyond = _Attractor(j=0, kind=IRREGULAR, slips=0, period=np.nan, multiplier=np.nan, lanes={}, state=np.zeros(4))
    monkeypatch.setattr(am, "_padded_orbits", orbits)
    monkeypatch.setattr(am, "_run", lambda model, V, *args: {})
    monkeypatch.setattr(am, "_classify_free", lambda model, Vs, *args: [dataclasses.replace(beyond) for _ in Vs])
    branch = _Attractor(j=0, kind=PERIODIC, slips=3, period=0.2, multiplier=0.5, lanes={}, state=np.array([0.9, 0, 0, 0]))
    end = [branch, 0.9, 1.0, branch.state, 0.5, None]
    rounds: list = []
    options = {"orbit_rtol": 1e-8, "branch_tol": 0.1}
    am._bisect_orbits(pj.PeelingModel(), [end], 1e-4, 1.0, 0.5, {}, options, lambda text: None, rounds)
    assert end[1] < boundary <= end[2] and end[2] - end[1] <= 1e-4, end[1:3]
    assert end[5].kind == IRREGULAR and rounds[-1] == 1  # one run beyond the bracket names it
    kept = [branch, 0.9, 0.95, branch.state, 0.5, None]  # the orbit goes on to the grid value
    am._bisect_orbits(pj.PeelingModel(), [kept], 1e-4, 1.0, 0.5, {}, options, lambda text: None, [])
    assert kept[5] == "kept" and kept[1] == kept[2] == 0.95


@pytest.mark.slow
def test_a_branch_that_loses_stability_ends_where_its_multiplier_crosses_1():
    """The k = 12 orbit at 1.34 m/s, continued down in V: the map's bracket has |μ₁| < 1 inside
    and ≥ 1 outside, by periodic_orbit from the orbit inside (runs there linger near the weakly
    unstable orbit and put the end later, at a grazing)."""
    amap = attractor_map(V=[1.28, 1.3408], random_starts=0, seed_rounds=0, lyapunov=False, progress=False)
    b = amap.boundaries
    ends = [i for i, change in enumerate(b["change"]) if change.startswith("loses stability")]
    assert ends, b
    i = ends[0]
    row = [r for r in range(amap.kind.size) if amap.branch[r] == b["branch"][i]][0]
    inside = pj.periodic_orbit(V=b["V_inside"][i], start=amap.state[row][:2], slips=int(amap.slips[row]))
    for V, stable in ((b["V_inside"][i], True), (b["V_outside"][i], False)):
        orbit = pj.periodic_orbit(V=V, start=np.asarray(inside.section), slips=int(amap.slips[row]))
        assert int(orbit.status) == 0
        assert (np.abs(np.asarray(orbit.multipliers)).max() < 1.0) == stable, (V, orbit.multipliers)
    assert abs(b["V_outside"][i] - b["V_inside"][i]) <= 1e-4


@pytest.mark.slow
def test_the_run_from_steady_peeling_at_3_m_s_is_near_an_unstable_orbit():
    """V = 3.0935: the run from steady peeling repeats one slip per 3.871 ms for its 4 s, and
    Newton finds that orbit with |μ₁| just above 1 (it spreads by e in ~9 s and leaves after
    20–40 s, measured): near an unstable orbit, not an attractor."""
    model, V = pj.PeelingModel(), np.array([3.0935])
    lanes = _run(model, V, _steady_states(model, V), 4.0, 2.0, {})
    kind, slips, period, multiplier = _labels(model, V, lanes, {"orbit_rtol": 1e-8})
    assert (kind[0], slips[0]) == (UNSTABLE, 1), (kind, slips)
    np.testing.assert_allclose(period[0], 3.871e-3, rtol=1e-3)
    assert 1.0 < multiplier[0] < 1.01


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"V": [1.1, 0.5]}, "increasing"),
        ({"V": [0.0, 1.0]}, "> 0"),
        ({"random_starts": -1}, "random_starts must be an integer >= 0"),
        ({"t_final": 2.0, "transient": 2.0}, r"transient must lie in \[0, t_final\)"),
        ({"boundary_tol": 0.0}, r"boundary_tol must be > 0 \(allowed range: \(0, inf\)\)"),
        ({"extend": 0.5}, "extend must be >= 1"),
        ({"chunk": 4}, "attractor_map sets chunk itself"),
    ],
)
def test_bad_input_is_refused_before_compiling(kwargs, message):
    with pytest.raises(ValueError, match=message):
        attractor_map(**kwargs, progress=False)


@pytest.mark.slow
def test_the_map_finds_the_paper_orbit_with_its_period_and_basins(tmp_path):
    amap = attractor_map(V=[1.05, 1.1], random_starts=3, t_final=3.0, boundary_tol=None, progress=False)
    assert set(amap.kind.tolist()) <= set(range(len(ATTRACTOR_KINDS)))
    orbit = pj.periodic_orbit(V=1.1)
    at = [i for i in amap.at(1.1) if amap.kind[i] == PERIODIC and amap.slips[i] == int(orbit.slips)]
    assert len(at) == 1, amap.summary()
    i = at[0]
    np.testing.assert_allclose(amap.period[i], float(orbit.period), rtol=1e-7)
    np.testing.assert_allclose(amap.multiplier[i], np.abs(np.asarray(orbit.multipliers)).max(), rtol=1e-5)
    for j in range(amap.grid_V.size):  # every random start ends on exactly one attractor
        here = amap.V_index == j
        np.testing.assert_allclose(amap.basin[here].sum(), 1.0)
    path = tmp_path / "map.npz"
    amap.save(path)
    back = pj.load(path)
    assert back.labels == amap.labels
    np.testing.assert_array_equal(back.period, amap.period)
    assert "periodic (k=" in back.summary()
    assert back.to_xarray()["label"].size == amap.kind.size
    again = back.orbit(i)  # the orbit again from the file, e.g. to continue it
    np.testing.assert_allclose(float(again.period), amap.period[i], rtol=1e-7)
    unknown = dataclasses.replace(back, fields=back.fields | {"slips": np.zeros_like(back.slips)})  # k=? everywhere
    with pytest.raises(ValueError, match=r"'periodic \(k=\?\)': only a periodic orbit with k known"):
        unknown.orbit(i)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["map", "--V", "1.1", "0.5"], "--V must be increasing"),
        (["map", "--random-starts", "-1"], "--random-starts must be an integer >= 0"),
        (["map", "--out", "map.csv"], "writes FILE.npz"),
    ],
)
def test_the_command_line_refuses_bad_input_before_compiling(argv, message):
    from conftest import run_cli

    code, _, err = run_cli(argv)
    assert code == 2 and message in err, err


@pytest.mark.slow
def test_the_command_line_writes_the_map_and_its_figure(tmp_path):
    from conftest import run_cli_writing

    done = run_cli_writing(tmp_path, ["map", "--V", "1.1", "--random-starts", "1", "--t-final", "3",
                                      "--boundary-tol", "0", "--no-progress"])  # fmt: skip
    assert done["code"] == 0, done["stderr"]
    assert done["png"].stat().st_size > 0
    back = pj.load(done["npz"])
    assert "periodic (k=8)" in back.labels
