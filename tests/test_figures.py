"""``peeljax figures``: every figure and the captions are written; bad input exits 2 before running."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import PNG_MAGIC, run_cli

from peeljax.figures import CAPTIONS, RUNS


@pytest.mark.slow
def test_figures_writes_every_png_and_captions(tmp_path):
    out = tmp_path / "figs"
    code, stdout, stderr = run_cli(["figures", "--out", str(out), "--t-final", "0.2", "--json"])
    assert code == 0, stderr
    facts = json.loads(stdout)
    for name in CAPTIONS:
        path = out / f"{name}.png"
        assert path.read_bytes()[:8] == PNG_MAGIC, name
    captions = (out / "captions.md").read_text(encoding="utf-8")
    assert all(name in captions for name in CAPTIONS)
    # one entry per (V, τ) run; the paper's least τ at V = 1.1 stops early at h = 1/82 s
    assert len(facts["runs"]) == sum(len(spec.taus) for spec in RUNS.values())
    early = facts["runs"]["V=1.1,tau=0.001"]
    assert not early["completed"] and 0.15 < early["t_stop"] < 0.19
    assert not facts["schur_reference"]["completed"]  # diffrax's step collapses near J_t = 0
    # every figure of the paper's uniform-mesh runs says so on the figure, not in captions.md alone
    mesh = {"fig2_v_V1.1", "fig3_alpha_V1.1", "fig4_F_vs_v_V1.1", "fig5_v_V2", "fig6_v_V4", "fig7_v_three_V",
            "bifurcation_V"}  # fmt: skip
    assert set(facts["uniform_mesh_figures"]) == mesh


def test_the_uniform_mesh_note_names_the_step_and_the_stop():
    from peeljax.figures import Figure, _mark_uniform_mesh

    fig = _mark_uniform_mesh(Figure(), 1 / 82)
    note = fig.get_suptitle()
    assert "h = 1/82 s" in note and "fold='stop'" in note and "artefact" in note and "first fold" in note
    both = _mark_uniform_mesh(Figure(), 1 / 82, 1 / 164, labels=("V = 1.1", "V = 2")).get_suptitle()
    assert "h = 1/82 s (V = 1.1), 1/164 s (V = 2)" in both


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--t-final", "-1"], "--t-final must be > 0"),
        (["--t-final", "0.01"], "--t-final must be >= 0.05"),
        (["--format", "xyz"], "unknown image format"),
    ],
)
def test_bad_input_exits_2_before_running(tmp_path, argv, message):
    code, stdout, stderr = run_cli(["figures", "--out", str(tmp_path / "f"), *argv])
    assert code == 2 and message in stderr and stdout == ""
    assert not (tmp_path / "f").exists()


def test_out_must_not_be_a_file(tmp_path):
    target = tmp_path / "file.txt"
    target.write_text("x")
    code, _, stderr = run_cli(["figures", "--out", str(target)])
    assert code == 2 and "not a folder" in stderr


# ---------------------------------------------------------------------------- sweep map
def _sweep_result(Vs, taus, *, events=None, completed=None, settings=None):
    """A synthetic outer-grid SweepResult (no simulation): runs with small τ stop early."""
    from peeljax.sweeps import SweepResult
    from peeljax.sweeps.api import PER_TRAJECTORY_KEYS

    V, tau = (a.ravel() for a in np.meshgrid(np.asarray(Vs, float), np.asarray(taus, float), indexing="ij"))
    done = tau > 2e-3 if completed is None else np.broadcast_to(np.asarray(completed, bool), V.shape)
    arrays = {key: np.zeros(V.size) for key in PER_TRAJECTORY_KEYS if key != "completed"}
    arrays.update(
        V=V, tau=tau, status=np.where(done, 0, 2).astype(np.int32), t_stop=np.where(done, 1.0, 0.4),
        v_std=np.where(done, 1e-4 * V / tau, np.nan),
        events=np.where(done & (tau < 5e-3), 2, 0) if events is None else np.broadcast_to(events, V.shape),
    )  # fmt: skip
    settings = {"dt": 0.01, "t_final": 1.0, "window": [0.5, 1.0]} | (settings or {})
    return SweepResult(
        params={}, completed=done, window_time=np.zeros(V.size), ts=None, ys=None, grid_shape=None, settings=settings,
        **arrays,
    )  # fmt: skip


def test_sweep_map_heading_names_the_tolerances_of_error_control(tmp_path):
    from peeljax.plots import plot_sweep_map

    settings = {"dt": None, "method": "alpha-adaptive", "rtol": 1e-5, "atol": 1e-8}
    result = _sweep_result([1.1, 2.0], np.geomspace(1e-3, 1e-1, 3), settings=settings)
    heading = plot_sweep_map(result, path=tmp_path / "map.png").get_suptitle()
    assert "error control rtol = 1e-05, atol = 1e-08" in heading and "dt =" not in heading


def _legend_texts(fig):
    return [text.get_text() for legend in fig.legends for text in legend.get_texts()]


@pytest.mark.parametrize("n_V", [2, 40, 200])
def test_sweep_map_draws_few_and_many_V_with_settings_and_stopped_legend(n_V, tmp_path):
    from matplotlib.collections import PolyCollection, QuadMesh

    from peeljax.plots import SWEEP_MAP_MAX_LINES, plot_sweep_map

    result = _sweep_result(np.linspace(1.0, 4.0, n_V), np.geomspace(1e-3, 1e-1, 12))
    fig = plot_sweep_map(result, path=tmp_path / "map.png")
    assert (tmp_path / "map.png").read_bytes()[:8] == PNG_MAGIC
    heading = fig.get_suptitle()
    assert "dt = 0.01 s" in heading and "t_final = 1 s" in heading and f"{n_V} V × 12 τ" in heading
    stopped = [text for text in _legend_texts(fig) if text.startswith("stopped before t_final")]
    assert len(stopped) == 1, _legend_texts(fig)
    titles = [ax.get_title() for ax in fig.axes]
    assert "stick-slip map" not in titles and "stick-slip events in the window" in titles
    (legend,) = fig.legends
    handle = legend.legend_handles[_legend_texts(fig).index(stopped[0])]
    if n_V <= SWEEP_MAP_MAX_LINES:
        # one series per V against τ on a log axis; stopped runs drawn with the legend's marker
        assert all(ax.get_xscale() == "log" for ax in fig.axes)
        assert sum(text.startswith("V = ") for text in _legend_texts(fig)) == n_V
        markers = {line.get_marker() for ax in fig.axes for line in ax.get_lines() if line.get_linestyle() == "None"}
        assert handle.get_marker() == "x" and "x" in markers
    else:
        # images over (τ, V); the stopped cells hatched like the legend's patch in every panel
        maps = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
        panels = [ax for ax in maps if any(isinstance(c, QuadMesh) for c in ax.collections)]
        assert len(panels) == 3
        for ax in panels:
            (hatched,) = [c for c in ax.collections if isinstance(c, PolyCollection) and c.get_hatch()]
            assert hatched.get_hatch() == handle.get_hatch()
            assert len(hatched.get_paths()) == int((~result.completed).sum())


@pytest.mark.parametrize("n_V", [2, 40])
def test_sweep_map_says_so_when_no_run_has_events(n_V):
    from peeljax.plots import plot_sweep_map

    fig = plot_sweep_map(_sweep_result(np.linspace(1.0, 4.0, n_V), np.geomspace(1e-3, 1e-1, 6), events=0))
    titles = [ax.get_title() for ax in fig.axes]
    assert "no stick-slip events in this sweep" in titles
    assert not any("stick-slip map" in title or title == "stick-slip events in the window" for title in titles)


def test_sweep_map_top_panel_shows_every_V_apart():
    """The runs of each V on a row of their own in the first panel (all completed runs of all V
    sat on one point, t = t_final, so one colour hid the others); a stopped run's t_stop is
    written by its ×."""
    from peeljax.plots import plot_sweep_map

    Vs = [1.1, 2.0, 4.0]
    result = _sweep_result(Vs, np.geomspace(1e-3, 1e-1, 5))
    fig = plot_sweep_map(result)
    top = fig.axes[0]
    rows = {}
    for line in top.get_lines():
        if line.get_marker() in ("o", "x"):
            rows.setdefault(line.get_color(), set()).update(np.round(np.asarray(line.get_ydata(), float), 9))
    assert len(rows) == len(Vs) and all(len(y) == 1 for y in rows.values())
    assert len(set.union(*rows.values())) == len(Vs)  # one row each
    written = [text.get_text() for text in top.texts]
    assert written.count("0.4 s") == int((~result.completed).sum())
    assert [t.get_text() for t in top.get_yticklabels()] == ["V = 1.1", "V = 2", "V = 4"]


def test_sweep_map_with_every_run_stopped_and_user_title():
    from peeljax.plots import plot_sweep_map

    result = _sweep_result([1.1, 2.0], np.geomspace(1e-3, 1e-1, 4), completed=False)
    fig = plot_sweep_map(result, title="my sweep")
    assert fig.get_suptitle().startswith("my sweep\n") and "0 completed, 8 stopped" in fig.get_suptitle()
    fig.canvas.draw()  # no log axis without data, no empty layout


# ---------------------------------------------------------------------------- paper figures
def test_phi_extrema_values_with_units_in_the_legend_not_on_the_curves():
    from peeljax.figures import plot_phi_extrema

    fig = plot_phi_extrema()
    (ax,) = fig.axes
    assert not ax.texts  # no labels over the curves
    texts = _legend_texts(fig)
    assert len(texts) == 3
    assert all("m/s" in text and " N at v = " in text and "▲ max" in text and "▼ min" in text for text in texts)
    assert "0.524 m/s" in texts[0] and "8.49 m/s" in texts[0]


@pytest.fixture(scope="module")
def early_stop():
    """The paper's least τ at V = 1.1 (α-method, h = 1/82 s): stops at t ≈ 0.171 s."""
    from peeljax import simulate

    return simulate(V=1.1, tau=1e-3, dt=1 / 82, t_final=0.3)


def test_schur_index_has_integer_ticks_and_a_zoom_of_the_end(early_stop):
    from peeljax.figures import plot_schur_index

    fig = plot_schur_index(early_stop, V=1.1, tau=1e-3)
    fig.canvas.draw()
    index_axes = [ax for ax in fig.axes if any(line.get_drawstyle() == "steps-mid" for line in ax.get_lines())]
    assert len(index_axes) == 2  # the whole run and the zoom
    for ax in index_axes:
        ticks = [t for t in ax.get_yticks() if ax.get_ylim()[0] <= t <= ax.get_ylim()[1]]
        assert ticks and all(float(t).is_integer() for t in ticks)
    zoom = index_axes[1].get_xlim()
    assert zoom[1] - zoom[0] <= 0.0105 and zoom[1] >= float(early_stop.t_stop)


def test_time_figure_legends_sit_below_the_axes(early_stop):
    from peeljax.figures import _plot_against_time

    fig = _plot_against_time({1e-3: early_stop, 1e-2: early_stop}, 3, "v [m/s]", "Fig. 5", 1.1)
    fig.canvas.draw()
    (ax,) = fig.axes
    (legend,) = fig.legends
    assert ax.get_legend() is None and len(legend.get_texts()) == 3
    assert legend.get_window_extent().y1 <= ax.get_window_extent().y0  # outside the data, below the axes


# ---------------------------------------------------------------------------- the stick-slip run figure
def _stuck_run():
    """By hand (no integration): v from the paper's 1e-10 up to v̂, a jump up at 0.1 s, down at
    0.12 s to 1e-54 m/s (a stuck tape), still stuck when max_jumps stops it at 0.3 s."""
    import jax.numpy as jnp

    from peeljax import PeelingModel
    from peeljax.solution import JumpRecord, Solution, StopReason

    ts = jnp.array([0.0, 0.05, 0.1, 0.11, 0.12, 0.2, 0.3])
    v = jnp.array([1.1e-10, 1e-3, 0.524, 12.0, 8.49, 1e-54, 1e-50])
    u = jnp.array([0.13, 0.2, 0.29, 0.25, 0.21, 0.24, 0.27])
    ys = jnp.stack([jnp.full(7, 0.05), jnp.zeros(7), u, v], axis=1)
    G = PeelingModel().shear_force(ys[jnp.array([2, 4]), :3].T)
    jumps = JumpRecord.empty(4).record(True, 0.1, True, 0.524, 15.0, G[0]).record(True, 0.12, False, 8.49, 1e-54, G[1])
    return Solution(ts=ts, ys=ys, valid=jnp.ones(7, bool), status=jnp.asarray(int(StopReason.MAX_JUMPS)),
                    t_stop=jnp.asarray(0.3), stats={}, diagnostics=None, jumps=jumps)  # fmt: skip


@pytest.mark.slow
def test_stick_slip_figure_keeps_notes_off_the_data_and_axes_near_it(tmp_path):
    """#30 item 5: the stop note in the legend above the panels (no box over G(t)), the v axis
    fitted to the data (no empty decades on top, not 60 decades down to 1e-54), and a run that
    stopped before its transient draws its loop from the first jump, not from v = 1e-10."""
    from peeljax import PeelingModel
    from peeljax.plots import plot_stick_slip

    fig = plot_stick_slip(_stuck_run(), PeelingModel(), 1.1, transient=1.0, path=tmp_path / "stuck.png")
    assert (tmp_path / "stuck.png").read_bytes()[:8] == PNG_MAGIC
    fig.canvas.draw()
    by_label = {ax.get_ylabel(): ax for ax in fig.axes}
    ax_v, ax_loop = by_label["peeling velocity v [m/s]"], by_label["shear force G [N]"]
    (ax_G,) = (ax for ax in fig.axes if ax.get_ylabel().startswith("shear force G = "))
    assert not ax_G.texts and ax_G.get_legend() is None  # nothing drawn over the sawtooth
    legend = ax_v.get_legend()
    assert legend.get_window_extent().y0 >= ax_v.get_window_extent().y1 - 1  # above the axes
    labels = [text.get_text() for text in legend.get_texts()]
    assert any(label.startswith("stopped at t = 0.3 s: reached max_jumps") for label in labels)
    assert any(label.startswith("G(t)") for label in labels)  # the G panel's entries too
    bottom, top = ax_v.get_ylim()
    assert 15.0 < top <= 3 * 15.0 and bottom >= 1e-12 * 15.0  # the data's decades, 1e-12 of the top at most
    assert any("v below" in t.get_text() and "1e-54" in t.get_text() for t in ax_v.texts)
    (loop,) = (line for line in ax_loop.get_lines() if line.get_label().startswith("the run"))
    xs = np.asarray(loop.get_xdata(), float)
    assert xs[0] == pytest.approx(0.524)  # from the first jump: the approach from 1e-10 is no part of it
    assert ax_loop.get_xlim()[0] >= 0.5e-12 * 15.0  # the stuck 1e-54 drawn at the clipped bottom
    assert "from the first jump" in ax_loop.get_title() and "stopped before the transient" in ax_loop.get_title()


def test_stick_slip_map_panel_b_keeps_k_and_the_status_apart(tmp_path):
    """#30 item 5: k per repeat on its own axis (no twin of the time axis), the lanes without
    a repeat and the stopped ones on a strip of named rows, not at heights of the time axis."""
    from test_stick_slip_map import _hand_made_map

    from peeljax.plots import plot_stick_slip_map

    fig = plot_stick_slip_map(_hand_made_map(), path=tmp_path / "map.png")
    fig.canvas.draw()
    ax_G, ax_T, ax_k, ax_S, ax_v = fig.axes[:5]
    assert len(fig.axes) == 5  # no twin axis
    assert ax_k.get_ylabel() == "k per repeat" and ax_k.get_ylim()[0] < 1 < 22 < ax_k.get_ylim()[1] <= 1.6 * 22
    assert [t.get_text() for t in ax_S.get_yticklabels()] == ["stopped", "no repeat", "too few"]
    rows = {round(float(y)) for line in ax_S.get_lines() for y in line.get_ydata()}
    assert rows <= {0, 1, 2} and 0 in rows and 1 in rows  # a stopped lane and lanes without a repeat
    lo, hi = ax_T.get_ylim()
    assert lo >= 2e-3 / 1.7 and hi <= 0.233 * 1.7  # the periods and intervals, no room kept for markers


@pytest.mark.slow
def test_trajectory_fit_plot_shows_every_fitted_quantity(tmp_path):
    """#30 item 8: the fit figure has a row per observed quantity (v, F, α), data and the fitted
    model's run, not v alone; a quantity one observation lacks says so."""
    from types import SimpleNamespace

    from peeljax import AdhesionLaw, PeelingModel, simulate
    from peeljax.fit import Observation
    from peeljax.plots import plot_fit

    model = PeelingModel()
    run = simulate(model, V=1.1, tau=0.01, dt=0.01, t_final=0.3)
    t, ys = np.asarray(run.ts), np.asarray(run.ys)
    F = np.asarray(model.tension(ys[:, 2], ys[:, 0]))
    observations = [Observation(V=1.1, t=t, v=ys[:, 3], F=F, alpha=ys[:, 0]), Observation(V=1.1, t=t, v=ys[:, 3], F=F)]
    law = AdhesionLaw()
    result = SimpleNamespace(settings={"dt": 0.01, "tau": 0.01, "t_final": 0.3}, adhesion=law, start=law,
                             v_range=(1e-3, 10.0), initial_loss=1.0, final_loss=0.1, steps=3)  # fmt: skip
    fig = plot_fit(result, observations, path=tmp_path / "fit.png")
    assert (tmp_path / "fit.png").read_bytes()[:8] == PNG_MAGIC
    ylabels = [ax.get_ylabel() for ax in fig.axes]
    for label in ("v [m/s]", "tension F [N]", "angle α [rad]"):
        assert ylabels.count(label) == 2, label  # one panel per observation
    assert ylabels.count("φ(v, V) [N]") == 1
    texts = [text.get_text() for ax in fig.axes for text in ax.texts]
    assert texts == ["no alpha observed at this V"]
    # the start model's run beside the fitted one, and the data drawn over both (not hidden by them)
    for ax in fig.axes:
        lines = {line.get_label(): line for line in ax.get_lines()}
        data = [line for label, line in lines.items() if label.startswith("data ")]
        if data:
            models = [line for label, line in lines.items() if "model" in label]
            assert {line.get_label().split()[0] for line in models} == {"start", "fitted"}
            assert data[0].get_zorder() > max(line.get_zorder() for line in models)


def test_the_old_module_peeljax_stick_slip_plots_warns_on_use_and_re_exports():
    import peeljax.plots as plots
    import peeljax.stick_slip_plots as old

    with pytest.warns(DeprecationWarning, match="peeljax.stick_slip_plots is deprecated: import plot_stick_slip_map from peeljax.plots"):
        assert old.plot_stick_slip_map is plots.plot_stick_slip_map


def test_the_old_module_peeljax_fit_plots_warns_on_use_and_re_exports():
    import peeljax.plots.fit as new

    with pytest.warns(DeprecationWarning, match="peeljax.fit.plots is deprecated: import plot_table_fit"):
        from peeljax.fit.plots import plot_table_fit
    assert plot_table_fit is new.plot_table_fit
    import peeljax.fit.plots as old

    for name in ("plot_records_fit", "fitted_values", "model_statistics"):
        with pytest.warns(DeprecationWarning, match=f"import {name} from peeljax.plots.fit"):
            assert getattr(old, name) is getattr(new, name)


# ---------------------------------------------------------------------------- the fold's end, stopped runs
def test_no_fold_shading_starts_where_phi_loses_its_fold(tmp_path):
    """The stick-slip map shades "no fold" from the V where φ's maximum and minimum merge, found
    by a root solve (V = 5.387 m/s for the paper's φ; the map's samples 4 and 6 m/s put it at 5),
    with the model given or read from the map's settings."""
    import dataclasses

    from matplotlib.patches import Rectangle
    from test_stick_slip_map import _hand_made_map

    from peeljax import PeelingModel
    from peeljax.analysis import _min_slope, fold_limit
    from peeljax.plots import plot_stick_slip_map

    V_cusp = fold_limit(None, 4.0, 6.0)
    assert V_cusp == pytest.approx(5.387, abs=1e-3)
    model = PeelingModel()
    assert float(_min_slope(model, V_cusp - 1e-3)) < 0 < float(_min_slope(model, V_cusp + 1e-3))
    with pytest.raises(ValueError, match="V_fold = 6"):
        fold_limit(None, 6.0, 4.0)

    def shading(fig):
        return [(p.get_x(), p.get_x() + p.get_width()) for p in fig.axes[0].patches if isinstance(p, Rectangle)]

    smap = _hand_made_map()
    ((start, _),) = shading(plot_stick_slip_map(smap, model=model))
    assert start == pytest.approx(V_cusp, abs=1e-9)
    paper = {name: float(getattr(model, name)) for name in ("R", "I", "k", "l")}
    paper |= {"geometry": "paper", "phi": model.adhesion.coefficients()}  # as a sweep records it
    recorded = dataclasses.replace(smap, settings={"sweep": {"model": paper}})
    fig = plot_stick_slip_map(recorded)
    ((start, _),) = shading(fig)
    assert start == pytest.approx(V_cusp, abs=1e-9)
    labels = [t.get_text() for legend in fig.axes[0].artists if hasattr(legend, "get_texts") for t in legend.get_texts()]
    assert any("5.387 m/s" in label for label in labels), labels
    ((start, _),) = shading(plot_stick_slip_map(smap))  # no model known: halfway between the samples
    assert start == pytest.approx(5.0)


def test_bifurcation_diagram_draws_a_stopped_run_on_the_axis_edge_not_at_v_0():
    from peeljax.analysis import BifurcationDiagram
    from peeljax.figures import plot_bifurcation_diagram

    diagram = BifurcationDiagram(
        V=np.array([1.0, 2.0, 3.0]), tau=1e-3, t_transient=1.5, v_max=[np.array([3.0]), np.array([4.0]), np.array([])],
        v_min=[np.array([0.5]), np.array([1.0]), np.array([])], v_final=np.array([1.0, 2.0, np.nan]),
        t_stop=np.array([3.0, 3.0, 0.25]), completed=np.array([True, True, False]),
    )  # fmt: skip
    fig = plot_bifurcation_diagram(diagram)
    (ax,) = fig.axes
    fig.canvas.draw()
    (cross,) = [line for line in ax.get_lines() if line.get_marker() == "x" and len(line.get_xdata())]
    assert cross.get_transform() != ax.transData  # on the axis edge: no value of v
    assert ax.get_ylim()[0] > 0.2  # v = 0 is no data here: the axis keeps to the extrema
    assert [t.get_text() for t in ax.texts] == ["0.25 s"]


# ---------------------------------------------------------------------------- the user's axes
def test_every_plotting_function_draws_into_the_users_axes():
    """``ax=``/``axes=``: drawn into a figure of the user's (which is returned), nothing else
    made; the wrong number of axes refused naming the parameter, before anything is drawn."""
    from matplotlib.figure import Figure

    from peeljax import PeelingModel
    from peeljax.analysis import BifurcationDiagram
    from peeljax.figures import plot_bifurcation_diagram, plot_phi_extrema
    from peeljax.plots import plot_run, plot_stick_slip, plot_sweep_map

    run = _stuck_run()
    diagram = BifurcationDiagram(V=np.array([1.0]), tau=1e-3, t_transient=1.5, v_max=[np.array([3.0])],
                                 v_min=[np.array([0.5])], v_final=np.array([1.0]), t_stop=np.array([3.0]),
                                 completed=np.array([True]))  # fmt: skip
    cases = [
        (lambda axes: plot_run(run, V=1.1, axes=axes), 3),
        (lambda axes: plot_stick_slip(run, PeelingModel(), 1.1, axes=axes), 3),
        (lambda axes: plot_sweep_map(_sweep_result([1.1, 2.0], [1e-3, 3e-3, 1e-2]), axes=axes), 3),
        (lambda axes: plot_phi_extrema(ax=axes), 1),
        (lambda axes: plot_bifurcation_diagram(diagram, ax=axes), 1),
    ]
    for draw, count in cases:
        mine = Figure()
        axes = mine.subplots(1, count + 1)
        assert draw(axes[:count] if count > 1 else axes[0]) is mine
        assert len(mine.axes) == count + 1 and all(ax.has_data() for ax in axes[:count]) and not axes[-1].has_data()
        assert mine.get_suptitle() == ""  # no title put on the user's figure unasked
        with pytest.raises(ValueError, match=rf"(ax|axes) must hold {count} Axes"):
            draw(axes[: count + 1] if count > 1 else axes)
    with pytest.raises(TypeError, match="axes must be matplotlib Axes"):
        plot_run(run, axes=["not", "axes", "here"])


def test_stick_slip_figure_keeps_the_state_after_each_jump_in_its_lines():
    """The rows hold v just after a jump: v(t), G(t) and the G–v loop go on from it (the line
    broke after it, so the slip branch was missing from the loop); a run whose rows lack the
    jumps (a file from before) gets the jump record's v after each jump inserted."""
    import dataclasses

    import jax.numpy as jnp

    from peeljax import PeelingModel
    from peeljax.plots import plot_stick_slip

    old = _stuck_run()
    ts, ys = np.asarray(old.ts), np.asarray(old.ys)
    # the same run with both sides of each jump in its rows (v after: 15 and 1e-54)
    at = [3, 6]
    ys_new = np.insert(ys, at, ys[[2, 4]], axis=0)
    ys_new[3, 3], ys_new[6, 3] = 15.0, 1e-54
    new = dataclasses.replace(old, ts=jnp.asarray(np.insert(ts, at, ts[[2, 4]])), ys=jnp.asarray(ys_new),
                              valid=jnp.ones(9, bool), after_jump=jnp.asarray(np.isin(np.arange(9), at)))  # fmt: skip
    for run in (old, new):
        fig = plot_stick_slip(run, PeelingModel(), 1.1)
        by_label = {ax.get_ylabel(): ax for ax in fig.axes}
        (v_line,) = (line for line in by_label["peeling velocity v [m/s]"].get_lines() if line.get_label() == "peeling velocity v(t)")
        v = np.asarray(v_line.get_ydata(), float)
        # a break (NaN) just before v = 15, and the line goes on from there
        i = int(np.flatnonzero(v == 15.0)[0])
        assert np.isnan(v[i - 1]) and v[i + 1] == pytest.approx(12.0)
        (loop,) = (line for line in by_label["shear force G [N]"].get_lines() if line.get_label().startswith("the run"))
        assert np.nanmax(np.asarray(loop.get_xdata(), float)) == 15.0


def test_table_fit_figure_colours_every_V_and_error_bars_that_stay_positive(monkeypatch):
    """table_fit.png: orange and blue mean the start and the fitted model in every panel (the φ
    panel's pull velocities take other colours), every V of the table has its φ curves, the φ
    legend sits beside the panel (not over the curves), and ±σ of a period larger than the
    period stops at zero. The model's statistics are stood in for (nothing is run)."""
    from types import SimpleNamespace

    from matplotlib.colors import to_hex

    import peeljax.plots.fit as fit_plots
    from peeljax import AdhesionLaw
    from peeljax.fit import StickSlipTable

    V = np.array([0.8, 1.2, 1.6, 2.0])
    period = np.array([0.023, 0.011, 0.005, 0.003])
    table = StickSlipTable.from_dict(V=V, F_mean=300 + 10 * V, F_mean_std=np.full(4, 3.0), period=period,
                                     period_std=np.array([0.002, 0.02, 0.001, 0.001]))  # fmt: skip
    stats = {name: np.ones(4) for name in ("F_mean", "F_slip", "F_stick", "period", "slip_duration")}
    monkeypatch.setattr(fit_plots, "model_statistics", lambda *args, **kwargs: (stats, np.ones((4, 2))))
    result = SimpleNamespace(adhesion=AdhesionLaw(), start=AdhesionLaw(c1=440.0), settings={}, residuals=None,
                             uncertainty=None, v_range=(1e-4, 20.0), stop_reason="", free=("c1",), initial_loss=2.0,
                             final_loss=1.0)  # fmt: skip
    fig = fit_plots.plot_table_fit(result, table)
    fig.canvas.draw()
    ax_mean, ax_period, _, ax_phi = fig.axes[:4]
    model_colors = {to_hex(line.get_color()) for ax in (ax_mean, ax_period) for line in ax.get_lines()
                    if "model" in line.get_label()}  # fmt: skip
    assert model_colors == {to_hex("C0"), to_hex("C1")}
    phi_colors = {to_hex(line.get_color()) for line in ax_phi.get_lines() if len(line.get_xdata()) > 10}
    assert len(phi_colors) == 4 and not phi_colors & model_colors  # one colour per V, none of the models'
    legend = ax_phi.get_legend()
    assert [t.get_text() for t in legend.get_texts()][:4] == [f"V = {v:g} m/s" for v in V]
    assert legend.get_window_extent().x0 >= ax_phi.get_window_extent().x1  # beside the panel
    (bars,) = [c for c in ax_period.collections if c.get_segments()]
    lows = [min(seg[:, 1]) for seg in bars.get_segments()]
    assert min(lows) == 0.0 and ax_period.get_ylim()[0] >= 0.0  # 0.011 ± 0.02 stops at 0
    assert any("cut at 0" in t.get_text() for t in ax_period.get_legend().get_texts())


def test_the_phi_panel_legend_is_true_to_its_lines_and_the_title_gives_the_fit():
    """One V: the legend's fitted, band and start entries have the curves' colour (not a grey key
    for a blue curve); the fit's title names each free coefficient with its 95 % interval."""
    from types import SimpleNamespace

    import jax.numpy as jnp
    import matplotlib.pyplot as plt
    from matplotlib.colors import to_rgba

    import peeljax as pj
    from peeljax._panels import draw_phi
    from peeljax.plots.fit import fitted_values

    fig, ax = plt.subplots()
    law = pj.AdhesionLaw()
    band = lambda V: (np.asarray(law(jnp.geomspace(1e-3, 10, 50), V)), np.full(50, 5.0))  # noqa: E731
    (color,) = draw_phi(ax, np.geomspace(1e-3, 10, 50), [1.1], law, pj.AdhesionLaw(c1=440.0), band=band)
    legend = ax.get_legend()
    texts = [t.get_text() for t in legend.get_texts()]
    assert texts == ["fitted (V = 1.1 m/s)", "its 95 % band", "start"]
    for handle in legend.legend_handles:
        assert to_rgba(handle.get_facecolor() if hasattr(handle, "get_facecolor") and not hasattr(handle, "get_xdata")
                       else handle.get_color())[:3] == pytest.approx(to_rgba(color)[:3])  # fmt: skip
    plt.close(fig)
    uncertainty = SimpleNamespace(intervals=lambda level: {"c1": (398.04, 406.61)})
    result = SimpleNamespace(adhesion=pj.AdhesionLaw(c1=402.3), free=("c1",), uncertainty=uncertainty)
    assert fitted_values(result) == "c1 = 402.3 [398.04, 406.61] (95 %)"


def test_a_records_fit_figure_shows_each_record_against_the_model(tmp_path):
    """The force-record fit's figure: each record's measured F(t) with the fitted and the start
    model's F(t) on its times, φ fitted against the start, the fitted value in the title."""
    from types import SimpleNamespace

    import peeljax as pj
    from peeljax.fit import Observation
    from peeljax.plots.fit import plot_records_fit

    ts = np.linspace(0.0, 0.3, 301)
    run = pj.simulate(V=1.1, tau=0.0, t_final=0.3, ts=ts)
    keep = ~np.asarray(run.after_jump)
    F = np.asarray(pj.PeelingModel().tension(run.ys[:, 2], run.ys[:, 0]))
    record = Observation(V=1.1, t=np.asarray(run.ts)[keep], v=None, F=F[keep])
    result = SimpleNamespace(start=pj.AdhesionLaw(c1=440.0), adhesion=pj.AdhesionLaw(), v_range=(1e-3, 10.0),
                             uncertainty=None, free=("c1",))  # fmt: skip
    fig = plot_records_fit(result, [record], path=tmp_path / "records.png")
    assert (tmp_path / "records.png").read_bytes()[:8] == PNG_MAGIC
    ax_F, ax_phi = fig.axes[:2]
    assert [t.get_text() for t in ax_F.get_legend().get_texts()] == ["measured F(t)", "start model", "fitted model"]
    measured, _, fitted = ax_F.get_lines()
    np.testing.assert_allclose(fitted.get_ydata(), measured.get_ydata(), rtol=1e-9)  # the fitted law is the truth
    assert fig._suptitle.get_text() == "force records fitted: c1 = 400"
