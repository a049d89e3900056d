"""The stick-slip map over V (``peeljax.sweeps.stick_slip_map``), its figure and ``peeljax sweep --stick-slip-map``.

One small map of the DAE (τ = 0, V = 0.25, 1.1, 2, 6 m/s, both starts, [0, 3] s, statistics
after 1.5 s) serves the slow tests; the refusals of bad input are checked before anything
compiles, and the figure's fast test draws a map made by hand.
"""

from __future__ import annotations

import inspect
import io
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import PNG_MAGIC, assert_refused, forbid, run_cli

from peeljax import PeelingModel, StopReason, phi_folds
from peeljax.cli import build_parser
from peeljax.cli import sweep as sweep_cli
from peeljax.cli import sweep_map as sweep_map_cli
from peeljax.cli import tau_star as tau_star_cli
from peeljax.plots import plot_stick_slip_map
from peeljax.sweeps import StickSlipMap, stick_slip_map, sweep
from peeljax.sweeps.stick_slip_map import FOLD_FIELDS, LANE_FIELDS

V_MAP = [0.25, 1.1, 2.0, 6.0]


def _same(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind in "fc":
        return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=True))
    return a.shape == b.shape and bool(np.array_equal(a, b))


@pytest.fixture(scope="module")
def smap():
    return stick_slip_map(V=V_MAP, t_final=3.0, progress=False)


# ---------------------------------------------------------------------------- the map of the DAE
@pytest.mark.slow
def test_map_shape_and_settings(smap):
    assert smap.starts == ("paper", "steady") and smap.tau == 0.0
    assert smap.t_final == 3.0 and smap.transient == 1.5
    np.testing.assert_allclose(smap.V, V_MAP)
    for name in LANE_FIELDS:
        assert np.shape(getattr(smap, name)) == (2, 4), name
    for name in FOLD_FIELDS:
        assert np.shape(getattr(smap, name)) == (4,), name
    assert smap.jump_G.shape[:2] == (2, 4) and smap.jump_G.shape == smap.jump_up.shape
    assert smap.settings["sweep"]["dae"] is True and smap.settings["sweep"]["grid"] == "pairs"


@pytest.mark.slow
def test_stick_slip_from_the_papers_start(smap):
    paper = smap.row("paper")
    # V = 1.1 and 2 stick-slip; V = 0.25 peels steadily (v = V on the rising stick branch)
    assert smap.stick_slip[paper].tolist() == [False, True, True, False]
    assert smap.jumps_total[paper, 0] == 0
    assert np.all(smap.completed[paper])
    # the repeats of the scipy prototype: 8 events in T = 0.2182711 s at V = 1.1, 22 in 0.2331759 s at V = 2
    assert smap.events[paper, 1] == 8 and smap.period[paper, 1] == pytest.approx(0.2182711, rel=1e-3)
    assert smap.events[paper, 2] == 22 and smap.period[paper, 2] == pytest.approx(0.2331759, rel=1e-3)
    # a cycle: stick → slip and slip → stick alternate, half of the jumps each
    assert np.all(np.abs(2 * smap.slips[paper, 1:3] - smap.jumps[paper, 1:3]) <= 1)
    assert 0 < smap.stick_fraction[paper, 1] < 1
    assert smap.stick_slip_ranges("paper") == [(1.1, 2.0)]


@pytest.mark.slow
def test_no_fold_no_jumps(smap):
    # φ(·, 6 m/s) has no fold: no jump from either start, v steady at V
    assert smap.has_folds.tolist() == [True, True, True, False]
    assert all(math.isnan(getattr(smap, name)[3]) for name in FOLD_FIELDS)
    assert np.all(smap.jumps_total[:, 3] == 0) and not smap.stick_slip[:, 3].any()
    np.testing.assert_allclose(smap.v_mean[:, 3], 6.0, rtol=0.1)
    assert smap.no_fold_ranges() == [(6.0, 6.0)]


@pytest.mark.slow
def test_dae_jumps_at_the_fold_forces(smap):
    """τ = 0: the tape slips at G = φ(v̂, V) and re-sticks at G = φ(v̌, V)."""
    model = PeelingModel()
    folds = jax.vmap(lambda V: phi_folds(model, V))(jnp.asarray(V_MAP))
    for name in FOLD_FIELDS:
        np.testing.assert_allclose(getattr(smap, name), np.asarray(getattr(folds, name)), rtol=1e-12)
    # φ at the folds, and φ's slope vanishing there
    ok = smap.has_folds
    np.testing.assert_allclose(smap.phi_max[ok], np.asarray(model.phi(jnp.asarray(smap.v_max[ok]), jnp.asarray(V_MAP)[ok])),
                               rtol=1e-12)  # fmt: skip
    checked = 0
    for start in smap.starts:
        for i in range(len(V_MAP)):
            G, up = smap.jump_forces(start, i)
            assert G.size == min(smap.jumps[smap.row(start), i], 64)  # the jumps each lane kept
            if G.size == 0:
                continue
            np.testing.assert_allclose(G[up], smap.phi_max[i], rtol=1e-6)
            np.testing.assert_allclose(G[~up], smap.phi_min[i], rtol=1e-6)
            checked += G.size
    assert checked > 100
    s = smap.row("paper")
    np.testing.assert_allclose(smap.G_slip_max[s, 1:3], smap.phi_max[1:3], rtol=1e-6)
    np.testing.assert_allclose(smap.G_stick_min[s, 1:3], smap.phi_min[1:3], rtol=1e-6)
    # the v amplitude: the stick branch ends at v̂, the slip branch starts at v̌
    np.testing.assert_allclose(smap.v_stick_max[s, 1:3], smap.v_max[1:3], rtol=1e-6)
    np.testing.assert_allclose(smap.v_slip_min[s, 1:3], smap.v_min[1:3], rtol=1e-6)


@pytest.mark.slow
def test_a_lane_is_its_sweep(smap):
    """Each lane is the sweep's lane with the same settings, summarized after the transient."""
    # the map's batch shape: its compilation is reused
    result = sweep(V=V_MAP, tau=0, t_final=3.0, grid="pairs", start="steady", progress=False, window=(0.5, 1.0))
    s = smap.row("steady")
    np.testing.assert_array_equal(smap.jumps_total[s], result.jumps["jump_count"])
    np.testing.assert_array_equal(smap.status[s], result.status)
    stats = result.cycle_statistics(1, transient=1.5)
    assert smap.jumps[s, 1] == stats.jumps and smap.slips[s, 1] == stats.slips
    assert smap.slip_interval[s, 1] == pytest.approx(stats.slip_interval.mean, rel=1e-12)


def _alone(V: float, start: str, transient: float, t_final: float, rtol: float = 1e-3) -> dict:
    """The map's fields of one lane from the run alone (``simulate``, its whole record) by the
    map's definitions: :func:`peeljax.cycle_statistics` after the transient, the repeat of at
    most 32 events, else searched on the later half and quarter of the stick → slip times (each
    at most the last 65)."""
    from peeljax import cycle_statistics, simulate
    from peeljax.cycles import repeat_pattern
    from peeljax.model import PAPER_ALPHA0

    model = PeelingModel()
    y0 = None if start == "paper" else model.consistent_state(V, PAPER_ALPHA0, V / model.R, V)
    sol = simulate(model, V=V, tau=0.0, t_final=t_final, y0=y0, ts=np.array([0.0, t_final]), adjoint="forward",
                   max_jumps=8192, max_steps=1_000_000)  # fmt: skip
    stats = cycle_statistics(sol, float(sol.t_stop), transient=transient, rtol=rtol)
    t, up = (np.asarray(a)[: int(sol.jumps.count)] for a in (sol.jumps.t, sol.jumps.up))
    up_times = t[(t >= transient) & up]
    repeat = stats.repeat if stats.repeat is not None and stats.repeat.events <= 32 else None
    if repeat is None and up_times.size >= 5:
        for fraction in (2, 4):
            repeat = repeat_pattern(up_times[up_times.size - min(up_times.size // fraction, 65) :], rtol=rtol)
            if repeat is not None and repeat.events <= 32:
                break
            repeat = None
    return {
        "status": int(sol.status), "jumps_total": int(sol.jumps.count), "jumps": stats.jumps, "slips": stats.slips,
        "events": 0 if repeat is None else repeat.events, "repeats": 0 if repeat is None else repeat.repeats,
        "period": math.nan if repeat is None else repeat.period, "slip_interval": stats.slip_interval.mean,
        "stick_duration": stats.stick_duration.mean, "slip_duration": stats.slip_duration.mean,
        "force_drop": stats.force_drop.mean, "G_slip_min": stats.G_slip.min, "G_slip_max": stats.G_slip.max,
        "G_stick_min": stats.G_stick.min, "G_stick_max": stats.G_stick.max, "stick_fraction": stats.stick_fraction,
        "v_stick_min": stats.v_stick[0], "v_stick_max": stats.v_stick[1], "v_slip_min": stats.v_slip[0],
        "v_slip_max": stats.v_slip[1],
    }  # fmt: skip


@pytest.mark.slow
def test_the_maps_statistics_are_those_of_its_lanes_run_alone(smap):
    """Every lane of the map (statistics accumulated in the loop, the last 64 jumps kept) against
    the same run alone with its whole record: counts and repeats exactly, the rest to 1e-6 (the
    lane and the run alone are compiled apart: their cycles drift apart by rounding)."""
    compared = 0
    for s, start in enumerate(smap.starts):
        for i, V in enumerate(V_MAP):
            want = _alone(V, start, smap.transient, smap.t_final)
            for name, value in want.items():
                got = getattr(smap, name)[s, i]
                if isinstance(value, int):
                    assert got == value, (start, V, name)
                else:
                    np.testing.assert_allclose(got, value, rtol=1e-6, err_msg=f"{start} {V} {name}")
            compared += want["jumps"]
    assert compared > 500  # jumps in the windows (826 measured)
    assert smap.events[smap.row("paper"), 2] == 22 and smap.repeats[smap.row("paper"), 2] >= 2


@pytest.mark.slow
def test_arrays_round_trip_without_pickles(smap, tmp_path):
    arrays = smap.as_arrays()
    assert all(np.asarray(value).dtype != object for value in arrays.values())
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    buffer.seek(0)
    with np.load(buffer, allow_pickle=False) as data:
        loaded = {key: data[key] for key in data.files}
    assert set(loaded) == set(arrays)
    for key, value in arrays.items():
        assert _same(loaded[key], value), key
    back = StickSlipMap.from_arrays(loaded)
    assert back.starts == smap.starts and back.settings == json.loads(json.dumps(back.settings))
    for key, value in back.as_arrays().items():
        if key != "settings_json":
            assert _same(value, arrays[key]), key
    path = tmp_path / "map.npz"
    smap.save(path)
    with np.load(path, allow_pickle=False) as data:
        assert _same(data["stick_slip"], smap.stick_slip)


@pytest.mark.slow
def test_summary_and_figure(smap, tmp_path):
    text = str(smap)
    assert "stick-slip for V in" in text and "no fold at V = 6 m/s" in text
    assert "paper" in text and "steady" in text
    path = tmp_path / "map.png"
    fig = plot_stick_slip_map(smap, title="test map", path=path)
    assert path.read_bytes()[:8] == PNG_MAGIC
    assert len(fig.axes) == 5  # three panels, and (b)'s k axis and status strip


@pytest.mark.slow
def test_homogenized_ode_map():
    """τ > 0: a small τ still stick-slips (jumps at impasse points and smooth crossings of v̂);
    a large one smooths v to V."""
    small = stick_slip_map(V=[1.1], tau=1e-4, t_final=1.0, starts=("paper",), progress=False)
    assert small.tau == 1e-4 and small.settings["sweep"]["dae"] is False
    assert small.stick_slip.tolist() == [[True]] and small.crossings[0, 0] > 0
    large = stick_slip_map(V=[1.1], tau=1e-2, t_final=1.0, starts=("paper",), progress=False)
    assert large.stick_slip.tolist() == [[False]] and large.jumps_total[0, 0] == 0
    assert 1.0 < large.v_lo[0, 0] <= large.v_hi[0, 0] < 1.2


# ---------------------------------------------------------------------------- a map made by hand
def _hand_made_map() -> StickSlipMap:
    """Five V, two starts: steady peeling, regular and irregular stick-slip, a stopped run, no fold."""
    V = np.array([0.3, 1.0, 2.0, 4.0, 6.0])
    lanes = {name: np.full((2, 5), np.nan) for name in LANE_FIELDS}
    for name in ("status", "jumps_total", "jumps", "slips", "crossings", "events", "repeats"):
        lanes[name] = np.zeros((2, 5), np.int64)
    lanes["t_stop"][:] = 3.0
    lanes["window_start"][:] = 1.5
    lanes["status"][1, 3] = int(StopReason.MAX_STEPS)
    lanes["t_stop"][1, 3], lanes["window_start"][1, 3] = 1.0, 0.5
    jumps = np.array([[0, 100, 300, 600, 0], [0, 110, 0, 400, 0]])
    lanes["jumps"][:] = jumps
    lanes["jumps_total"][:] = 2 * jumps
    lanes["slips"][:] = jumps // 2
    lanes["events"][0, 1:3], lanes["period"][0, 1:3], lanes["repeats"][0, 1:3] = (8, 22), (0.218, 0.233), (6, 4)
    lanes["events"][1, 3], lanes["period"][1, 3], lanes["repeats"][1, 3] = 1, 2e-3, 100
    phi_max = np.array([276.0, 285.0, 294.0, 305.0, np.nan])
    phi_min = np.array([150.0, 200.0, 240.0, 290.0, np.nan])
    v_max = np.array([0.37, 0.5, 0.7, 1.2, np.nan])
    v_min = np.array([9.5, 8.6, 7.7, 6.0, np.nan])
    stick_slip = jumps > 0
    for s in range(2):
        lanes["slip_interval"][s] = np.where(stick_slip[s], 1.5 / np.maximum(jumps[s] / 2, 1), np.nan)
        lanes["v_stick_min"][s] = np.where(stick_slip[s], [0.0, 1e-3, 2e-2, 0.3, 1.0], np.nan)
        lanes["v_stick_max"][s] = np.where(stick_slip[s], v_max, np.nan)
        lanes["v_slip_min"][s] = np.where(stick_slip[s], v_min, np.nan)
        lanes["v_slip_max"][s] = np.where(stick_slip[s], [17.0, 15.0, 13.5, 9.2, 1.0], np.nan)
        lanes["v_mean"][s] = np.where(stick_slip[s], np.nan, V)
        lanes["v_lo"][s] = np.where(stick_slip[s], np.nan, V * 0.99)
        lanes["v_hi"][s] = np.where(stick_slip[s], np.nan, V * 1.01)
    width = int(jumps.max())
    up = np.zeros((2, 5, width), bool)
    up[..., ::2] = True
    G = np.where(up, phi_max[None, :, None], phi_min[None, :, None])
    G[np.arange(width)[None, None, :] >= jumps[:, :, None]] = np.nan
    up &= np.isfinite(G)
    return StickSlipMap(
        V=V, starts=("paper", "steady"), tau=0.0, t_final=3.0, transient=1.5, **lanes, jump_G=G, jump_up=up,
        phi_max=phi_max, phi_min=phi_min, v_max=v_max, v_min=v_min, settings={"sweep": {"rtol": 1e-6, "atol": 1e-9}},
    )  # fmt: skip


def test_hand_made_map_summary_and_figure(tmp_path):
    smap = _hand_made_map()
    assert smap.stick_slip_ranges("paper") == [(1.0, 4.0)]
    assert smap.stick_slip_ranges("steady") == [(1.0, 1.0), (4.0, 4.0)]
    assert smap.irregular.tolist() == [[False, False, False, True, False], [False, True, False, False, False]]
    assert smap.early.tolist() == [[False] * 5, [False, False, False, True, False]]
    text = str(smap)
    assert "[1, 4]" in text and "no fold at V = 6 m/s" in text and "max_steps" in text
    assert "disagree (coexisting stick-slip and steady peeling) at V = 2 m/s" in text
    path = tmp_path / "hand.png"
    plot_stick_slip_map(smap, path=path)
    assert path.read_bytes()[:8] == PNG_MAGIC
    one = StickSlipMap.from_arrays({**smap.as_arrays()})
    plot_stick_slip_map(one, path=tmp_path / "again.png")


# ---------------------------------------------------------------------------- refusals, before compiling
@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"V": [0.0, 1.0]}, ("V must be finite and > 0",)),
        ({"V": [[1.0, 2.0]]}, ("V must be a number or 1-d",)),
        ({"V": []}, ("V must hold at least one value",)),
        ({"tau": [0.0, 0.1]}, ("tau must be one number",)),
        ({"tau": -1.0}, ("tau must be finite and >= 0",)),
        ({"t_final": 0.0}, ("t_final must be finite and > 0",)),
        ({"transient": 3.0}, ("transient must lie in [0, t_final)",)),
        ({"transient": -0.1}, ("transient must be finite and >= 0",)),
        ({"starts": ()}, ("starts must name at least one",)),
        ({"starts": ("paper", "moving")}, ("starts must be among",)),
        ({"starts": ("paper", "paper")}, ("starts must not repeat",)),
        ({"fold": "stop"}, ("fold='stop'",)),
        ({"fold": "follow"}, ("fold='follow' applies to tau > 0",)),
        ({"repeat_rtol": 0.0}, ("repeat_rtol must be finite and > 0",)),
        ({"dt": 0.01}, ("dt asks for a uniform mesh",)),
        ({"out": "x.npz"}, ("out:",)),
        ({"params": {"k": [1.0]}}, ("params:",)),
        ({"grid": "outer"}, ("stick_slip_map sets grid itself",)),
        ({"rtol": 2.0}, ("rtol",)),
        ({"max_jumps": 0}, ("max_jumps must be a positive integer",)),
        ({"window": (0.2, 1.0)}, ("window starts at 0.6 s, not at transient = 1.5 s",)),
    ],
)
def test_map_refuses_bad_input_before_compiling(kwargs, words, no_compilation):
    with pytest.raises(ValueError) as error:
        stick_slip_map(**{"V": [1.1], "progress": False, **kwargs})
    for word in words:
        assert word in str(error.value), str(error.value)


@pytest.fixture
def cli_not_running(no_compilation, monkeypatch):
    forbid(monkeypatch, sweep_cli, "_run_sweep", reason="must not run")
    forbid(monkeypatch, sweep_map_cli, "_run_map", reason="must not run")
    forbid(monkeypatch, tau_star_cli, "_run_tau_star", reason="must not run")


MAP = ["sweep", "--V", "1.1", "--stick-slip-map"]


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["sweep", "--tau", "0", "--dt", "0.01"], ("--tau 0", "--dt")),
        (["sweep", "--tau", "0", "--n-tau", "4"], ("--n-tau",)),
        (["sweep", "--tau", "0", "1e-2"], ("--tau", "0 alone")),
        (["sweep", "--fold", "bounce"], ("--fold must be one of jump, stop, follow",)),
        (["sweep", "--fold", "jump", "--dt", "0.01"], ("--fold jump", "--dt")),
        (["sweep", "--tau", "0", "--fold", "follow"], ("--fold follow", "--tau 0")),
        (["sweep", "--max-jumps", "0"], ("--max-jumps",)),
        (["sweep", "--max-jumps", "20000000"], ("--max-jumps",)),
        (["sweep", "--max-jumps", "5", "--dt", "0.01"], ("--max-jumps", "--dt")),
        (["sweep", "--max-steps", "0"], ("--max-steps",)),
        (["sweep", "--start", "moving"], ("--start must be one of paper, steady",)),
        (["sweep", "--tau", "0", "--plot", "map.png"], ("--plot", "--stick-slip-map")),
        ([*MAP, "--tau", "1e-3", "1e-2"], ("one --tau",)),
        ([*MAP, "--n-tau", "3"], ("--n-tau",)),
        ([*MAP, "--dt", "0.01"], ("--dt",)),
        ([*MAP, "--save-dt", "0.1"], ("--save-dt",)),
        ([*MAP, "--window", "0.5", "1"], ("--window", "--transient")),
        ([*MAP, "--fold", "stop"], ("--fold stop",)),
        ([*MAP, "--fold", "follow"], ("--fold follow",)),
        ([*MAP, "--transient", "3"], ("--transient must lie in [0, --t-final)",)),
        ([*MAP, "--transient=-1"], ("--transient must lie in [0, --t-final)",)),
        ([*MAP, "--start", "x"], ("--start",)),
        ([*MAP, "--V", "0"], ("--V must be > 0 (allowed range: (0, inf))",)),
        ([*MAP, "--rtol", "0"], ("--rtol",)),
        ([*MAP, "--max-jumps", "0"], ("--max-jumps",)),
        ([*MAP, "--plot", "map.xyz"], ("--plot", "unknown image format")),
        ([*MAP, "--out", "/nonexistent/folder/map.npz"], ("--out", "does not exist")),
    ],
)
def test_cli_refuses_bad_input_before_compiling(argv, words, cli_not_running):
    code, out, err = run_cli(argv)
    assert_refused(code, err, *words, stdout=out)


def test_cli_options_reach_the_api():
    args = build_parser().parse_args(["sweep", "--tau", "0", "--fold", "jump", "--max-jumps", "100", "--start",
                                      "steady", "--max-steps", "5000"])  # fmt: skip
    kwargs = sweep_cli.validate_sweep(args)
    assert kwargs["tau"] == [0.0] and kwargs["fold"] == "jump" and kwargs["max_jumps"] == 100
    assert kwargs["start"] == "steady" and kwargs["max_steps"] == 5000
    assert set(kwargs) <= set(inspect.signature(sweep).parameters)
    args = build_parser().parse_args(["sweep", "--V", "1", "2", "--stick-slip-map", "--t-final", "2"])
    kwargs = sweep_map_cli.validate_map(args)
    assert kwargs["tau"] == 0.0 and kwargs["starts"] == ("paper", "steady") and kwargs["transient"] == 1.0
    accepted = set(inspect.signature(stick_slip_map).parameters) | set(inspect.signature(sweep).parameters)
    assert set(kwargs) <= accepted
    args = build_parser().parse_args(["sweep", "--stick-slip-map", "--start", "paper", "--tau", "0.01",
                                      "--transient", "0.5"])  # fmt: skip
    kwargs = sweep_map_cli.validate_map(args)
    assert kwargs["starts"] == ("paper",) and kwargs["tau"] == 0.01 and kwargs["transient"] == 0.5


# ---------------------------------------------------------------------------- the command line, running
@pytest.mark.slow
def test_cli_stick_slip_map_writes_map_and_figure(tmp_path):
    npz, png = tmp_path / "map.npz", tmp_path / "map.png"
    code, out, err = run_cli([*MAP[:2], "1.1", "6", "--stick-slip-map", "--t-final", "1", "--start", "paper",
                              "--no-progress", "--out", str(npz), "--plot", str(png), "--json"])  # fmt: skip
    assert code == 0, err
    record = json.loads(out)
    assert record["starts"] == ["paper"] and record["tau"] == 0.0 and record["transient"] == 0.5
    assert record["stick_slip_ranges"] == {"paper": [[1.1, 1.1]]} and record["no_fold_ranges"] == [[6.0, 6.0]]
    assert record["lanes"]["stick_slip"] == [[True, False]]
    assert png.read_bytes()[:8] == PNG_MAGIC
    with np.load(npz, allow_pickle=False) as data:
        back = StickSlipMap.from_arrays(data)
    assert back.stick_slip.tolist() == [[True, False]] and back.starts == ("paper",)


@pytest.mark.slow
def test_cli_dae_sweep_writes_the_jump_records(tmp_path):
    npz = tmp_path / "sweep.npz"
    code, out, err = run_cli(["sweep", "--V", "1.1", "6", "--tau", "0", "--t-final", "0.5", "--no-progress",
                              "--out", str(npz), "--json"])  # fmt: skip
    assert code == 0, err
    record = json.loads(out)
    assert record["fold"] == "jump" and record["start"] == "paper" and record["tau"] == [0.0]
    counts = record["jumps"]["jump_count"]
    assert counts[0] > 0 and counts[1] == 0
    assert len(record["jumps"]["jump_t"][0]) == counts[0] and record["jumps"]["jump_G"][1] == []
    assert record["jumps"]["jump_up"][0][0] is True
    with np.load(npz, allow_pickle=False) as data:
        assert data["jump_count"].tolist() == counts
        np.testing.assert_allclose(data["jump_t"][0, : counts[0]], record["jumps"]["jump_t"][0])
