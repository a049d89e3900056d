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


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--t-final", "-1"], "t_final must be > 0"),
        (["--t-final", "0.01"], "t_final must be >= 0.05"),
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
