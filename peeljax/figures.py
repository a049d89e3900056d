"""The paper's Figs. 2–7 and two structure figures, regenerated with peeljax.

Every figure uses the paper's parameters (R = 0.1 m, I = 1e-2 kg·m², k/l = 1000 N/m, the adhesion
law of de2006dynamics) and initial data (v0 = 1e-10·V, ω0 = v0/R, α0 = (π/4)·1e-8, u0 from
(sac)), the α-method with ρ = 0 on [0, 3] s. Steps and τ lists are in :data:`RUNS`:

* V = 1.1 m/s: the paper's h = 1/82 s; τ = 1e-3 (the paper's least τ: it stops early here too,
  at t ≈ 0.171 s), 4.22e-3 (the least τ of the grid below that completes [0, 3] s; τ* = 4.8e-3,
  since 4.59e-3 stops), 1e-2, 1e-1;
* V = 2 and 4 m/s: h = 1/164 s (the paper says only that smaller steps work there; 1/164 halves
  the V = 1.1 step); τ lists from the least τ found to complete [0, 3] s on a log grid of 25 values
  in [1e-4, 0.1] at that step, rounded to 3 digits and rechecked (``docs/reproduction.md``):
  2.37e-3 at V = 2, 3.16e-4 at V = 4 (2.37e-4 rounded stops at 1.26 s; completion is not
  monotone in τ: 7.5e-4 stops at 0.97 s), and larger ones.

Figures (file name → content):

* ``fig2_v_V1.1`` v(t) at V = 1.1 for the τ list (eq. ``hv`` integrated by the α-method);
* ``fig3_alpha_V1.1`` α(t), same runs;
* ``fig4_F_vs_v_V1.1`` the tension F(u, α) (eq. ``defF``) against v, same runs;
* ``fig5_v_V2``, ``fig6_v_V4`` v(t) at V = 2 and 4;
* ``fig7_v_three_V`` v(t) at the three V, each at its least τ;
* ``phi_extrema`` φ(v, V) for the three V with its maximum and minimum (∂φ/∂v = 0) marked;
* ``bifurcation_V`` the late extrema of v against V (17 values in [1, 5] m/s) at τ = 2.37e-3 s,
  h = 1/164 s (:func:`peeljax.bifurcation_diagram`);
* ``schur_index_V1.1`` |J_t| (Lemma 1) and the local index ⌈log_τ|J_t|⌉ + 1 (Lemma 2) along the
  diffrax reference trajectory at V = 1.1, τ = 1e-3 (output every 1/16400 s), up to where its
  step collapses, with the stick (∂φ/∂v > 0) and slip (∂φ/∂v < 0) phases shaded, and a zoom of
  its last 10 ms (the slip phase and the index change are a sliver at the full scale).

Legends sit below the axes, outside the data.

What the figures show (:data:`MESH_NOTE`, also in ``captions.md``): the paper's uniform mesh,
where a run ends at a fold of φ (``fold="stop"``). Their sustained oscillations of v (Figs. 5–7,
the bifurcation diagram) are an artefact of that coarse mesh: resolved (a finer step, or error
control) the same runs end at the first fold. The model's stick-slip cycles come from runs
carried through the folds (``fold="jump"``, the default under error control; README, "Stick-slip
through the folds", notebook ``05_stick_slip.ipynb``).

:func:`make_figures` returns the figures and captions; :func:`write_figures` saves PNGs and a
``captions.md``. ``t_final`` shortens every run (for tests); it is rounded to a whole number of
steps so that the step stays exactly as documented (the early stops depend on the step: at
V = 1.1, τ = 1e-3 the run with h = 0.3/25 s completes where h = 1/82 s stops).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ._atomic import save_figure, write_text
from ._panels import panels
from .analysis import BifurcationDiagram, analyze, bifurcation_diagram, phi_extrema
from .model import PeelingModel
from .simulate import simulate, simulate_reference
from .solution import Solution

__all__ = [
    "BIFURCATION_RUN",
    "CAPTIONS",
    "MESH_NOTE",
    "RUNS",
    "FigureRuns",
    "make_figures",
    "plot_bifurcation_diagram",
    "plot_phi_extrema",
    "plot_schur_index",
    "write_figures",
]


@dataclass(frozen=True)
class FigureRuns:
    """The runs behind one pull velocity's figures: step [s] and τ values [s] (least first)."""

    V: float
    dt: float
    taus: tuple[float, ...]


RUNS = {
    1.1: FigureRuns(V=1.1, dt=1 / 82, taus=(1e-3, 4.22e-3, 1e-2, 1e-1)),
    2.0: FigureRuns(V=2.0, dt=1 / 164, taus=(2.37e-3, 1e-2, 1e-1)),
    4.0: FigureRuns(V=4.0, dt=1 / 164, taus=(3.16e-4, 1e-3, 1e-2, 1e-1)),
}
BIFURCATION_RUN = {"Vs": tuple(np.linspace(1.0, 5.0, 17)), "tau": 2.37e-3, "dt": 1 / 164}
SCHUR_RUN = {"V": 1.1, "tau": 1e-3, "dt": 1 / 16400, "t_final": 0.2}  # diffrax reference, fine output

MESH_NOTE = (
    "These figures reproduce the paper on its uniform mesh, where a run ends at a fold of φ (fold='stop', the "
    "paper's behaviour). Their sustained oscillations of v (Figs. 5–7, the bifurcation diagram) are an artefact of "
    "that coarse mesh, whose steps land beyond the fold where J_t → 0 and go on: resolved, the same runs end at the "
    "first fold (V = 2, τ = 2.37e-3: h = 1/164 oscillates for 3 s, h = 1/656 stops at 0.165 s, error control at "
    "0.122–0.124 s; docs/reproduction.md). The model's stick-slip cycles come from runs carried through the folds, "
    "v jumping at constant force: `peeljax simulate --V 1.1 --tau 0 --plot run.png` (210 jumps in 3 s, repeating "
    'every 0.218 s) and `peeljax sweep --stick-slip-map` (README, "Stick-slip through the folds"; notebook '
    "05_stick_slip.ipynb)."
)

CAPTIONS = {
    "fig2_v_V1.1": "Fig. 2: peeling velocity v(t) at V = 1.1 m/s, h = 1/82 s, for τ = 1e-3 (the paper's least τ; stops early), "
    "4.22e-3 (the least τ of a 25-point log grid in [1e-4, 0.1] that completes [0, 3] s: not τ* = 4.8e-3 of "
    "peeljax.least_tau, the least τ above which every tested τ completes, since completion is not monotone "
    "in τ: 4.59e-3 stops at 0.256 s), 1e-2 and 1e-1 s; as τ grows v is smoothed to the pull velocity V (dashed).",
    "fig3_alpha_V1.1": "Fig. 3: peel-front angle α(t) at V = 1.1 m/s, same runs as Fig. 2; α settles to its mean, "
    "slower than v.",
    "fig4_F_vs_v_V1.1": "Fig. 4: tension F(u, α) = (k/l)·u against v at V = 1.1 m/s, same runs; v moves far while "
    "F hardly changes near the jump; τ = 4.22e-3 and 1e-2 spiral towards v = V. τ = 0.1 s ends at F ≈ 398 N "
    "(diffrax: 401 N), not at 300–315 N like the others, nor at φ(V, V) = 281 N (dotted): its v lags and creeps up "
    "to V from below without overshoot (0.9·V only at t = 0.37 s, against 0.23 s for τ = 1e-2), and while v < V "
    "the tape keeps stretching, u̇ ≈ V − v, so F grows by (k/l)·∫(V − v)dt = 1000 N/m × 0.267 m = 267 N from "
    "131 N (τ = 1e-2: 0.184 m, its overshoot past V gives some back). Every state with α = 0, ω = V/R, v = V is "
    "an equilibrium of eq. hv whatever u, so F stays there: 118 N off the constraint (sac), which τ relaxes.",
    "fig5_v_V2": "Fig. 5: v(t) at V = 2 m/s, h = 1/164 s, for the τ list of peeljax.figures.RUNS[2.0]. The sustained "
    "oscillation at τ = 2.37e-3 is the coarse mesh's: resolved, this run ends at the first fold (t ≈ 0.12 s).",
    "fig6_v_V4": "Fig. 6: v(t) at V = 4 m/s, h = 1/164 s, for the τ list of peeljax.figures.RUNS[4.0]; as in Fig. 5, "
    "an oscillation that lasts is the uniform mesh's, not the model's stick-slip.",
    "fig7_v_three_V": "Fig. 7: v(t) at V = 1.1, 2 and 4 m/s, each at the least τ of its list (1e-3, 2.37e-3, "
    "3.16e-4 s) on the paper's uniform mesh; V = 1.1 stops early (t = 0.171 s), as in the paper; the lasting "
    "oscillations at V = 2 and 4 are the mesh's (see the note above).",
    "phi_extrema": "φ(v, V) of de2006dynamics for V = 1.1, 2, 4 m/s with its maximum (▲, end of the stick "
    "branch) and minimum (▼) marked, their v [m/s] and φ [N] in the legend; ∂φ/∂v < 0 between them (slip).",
    "bifurcation_V": "Bifurcation diagram: local maxima and minima of v over the second half of each run against V "
    "(17 values in [1, 5] m/s), τ = 2.37e-3 s, h = 1/164 s (sweep engine); × marks runs that stopped early. The "
    "late swing of v is the uniform mesh's (see the note above); the model's stick-slip against V is the map of "
    "runs through the folds (peeljax sweep --stick-slip-map).",
    "schur_index_V1.1": "v, |J_t| (Lemma 1) and the local index ⌈log_τ|J_t|⌉ + 1 (Lemma 2, an integer) along "
    "the diffrax Kvaerno5 trajectory at V = 1.1 m/s, τ = 1e-3 (output every 1/16400 s), up to where its step "
    "collapses (t = 0.1728 s); stick (∂φ/∂v > 0) and slip (∂φ/∂v < 0) phases shaded. Right: the last 10 ms, "
    "where the slip phase (from t = 0.1687 s, v past the maximum of φ) and the index 2 (from t = 0.1718 s, "
    "|J_t| < 1) are.",
}


def _figure(nrows: int = 1, figsize=(8.0, 4.5), sharex: bool = True):
    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, 1, sharex=sharex, squeeze=False)[:, 0]
    return fig, axes


def _format_step(dt: float) -> str:
    """1/82 → "1/82 s"; other steps as numbers."""
    n = round(1.0 / dt)
    return f"1/{n} s" if abs(1.0 / dt - n) < 1e-9 * n else f"{dt:g} s"


def mesh_note(steps: str) -> str:
    """The note every figure of the paper's uniform-mesh runs carries (``steps``: its h in
    words, e.g. "h = 1/82 s"): what the coarse mesh does to the runs, in lines that fit an
    8-inch figure."""
    import textwrap

    lines = (
        f"α-method on the paper's uniform mesh, {steps}, stopping at a fold of φ (fold='stop'):",
        "an oscillation that lasts is this coarse mesh's artefact; resolved (finer h or error control) the run ends "
        "at the first fold.",
        "The model's stick-slip: runs through the folds (peeljax simulate --tau 0).",
    )
    return "\n".join(textwrap.fill(line, 125) for line in lines)


def _mark_uniform_mesh(fig: Figure, *dts: float, labels: tuple[str, ...] = ()) -> Figure:
    """The mesh note (:func:`mesh_note`) on the figure, above its panels (see :data:`MESH_NOTE`)."""
    steps = [_format_step(dt) + (f" ({label})" if label else "") for dt, label in zip(dts, labels or ("",) * len(dts))]
    fig.suptitle(mesh_note("h = " + ", ".join(steps)), fontsize=7.5, color="#8c2d04")
    return fig


def _series(solution: Solution) -> tuple[np.ndarray, np.ndarray]:
    valid = np.asarray(solution.valid)
    return np.asarray(solution.ts), np.where(valid[:, None], np.asarray(solution.ys), np.nan)


def _label(tau: float, solution: Solution) -> str:
    text = f"τ = {tau:g} s"
    if not bool(solution.completed):
        text += f" (stopped at t = {float(solution.t_stop):.3f} s)"
    return text


def _legend_below(fig: Figure, ax, ncols: int = 3) -> None:
    """The axes' legend below it, outside the data (inside, it hid peaks or minima)."""
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=min(ncols, len(labels)), fontsize=8)


def _plot_against_time(runs: dict[float, Solution], column: int, ylabel: str, title: str, V: float | None):
    fig, (ax,) = _figure()
    for i, (tau, solution) in enumerate(runs.items()):
        ts, ys = _series(solution)
        ax.plot(ts, ys[:, column], color=f"C{i}", lw=1.1, label=_label(tau, solution))
        if not bool(solution.completed):
            ax.axvline(float(solution.t_stop), color=f"C{i}", ls=":", lw=1.0)
    if V is not None:
        ax.axhline(V, color="k", ls="--", lw=0.8, label=f"pull velocity V = {V:g} m/s")
    ax.set_xlabel("time t [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    _legend_below(fig, ax)
    return fig


def plot_phi_extrema(
    model: PeelingModel | None = None, Vs=(1.1, 2.0, 4.0), v_range=(1e-3, 12.0), *, ax=None, path=None
) -> Figure:
    """φ(v, V) on a log v axis for each V with its maximum (▲) and minimum (▼) marked (∂φ/∂v = 0);
    the values, with units, are in the legend below the axes (labels on the curves overlapped them;
    drawn into the user's ``ax``, in that axes). Returns the figure (``ax``'s when given);
    ``path``: saved there."""
    model = PeelingModel() if model is None else model
    drawn = panels(ax, 1, lambda fig: [fig.subplots()], figsize=(8.0, 5.2), name="ax")
    (ax,) = drawn.axes
    vs = np.geomspace(*v_range, 800)
    for i, V in enumerate(Vs):
        phi = np.asarray(model.phi(vs, V))
        label = f"V = {V:g} m/s"
        for v_ext, marker in zip(phi_extrema(model, V), ("^", "v")):
            if np.isfinite(v_ext):
                phi_ext = float(model.phi(v_ext, V))
                ax.plot([v_ext], [phi_ext], marker=marker, color=f"C{i}", ms=8, ls="none", zorder=3)
                label += f"\n{'▲ max' if marker == '^' else '▼ min'} φ = {phi_ext:.0f} N at v = {v_ext:.3g} m/s"
        ax.plot(vs, phi, color=f"C{i}", label=label)
    ax.set_xscale("log")
    ax.set_xlabel("peeling velocity v [m/s]")
    ax.set_ylabel("adhesion force φ(v, V) [N]")
    ax.set_title("The adhesion law and its extrema (▲ maximum: stick → slip; ▼ minimum)")
    ax.grid(True, alpha=0.3)
    drawn.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncols=3, fontsize=8)
    return drawn.finish(None, path, dpi=130)


def _shade_phases(ax, ts, stick, slip):
    """Shade contiguous stick (blue) and slip (orange) intervals."""
    for mask, color in ((stick, "tab:blue"), (slip, "tab:orange")):
        edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
        for start, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
            ax.axvspan(ts[start], ts[min(stop, len(ts) - 1)], color=color, alpha=0.12, lw=0)


def plot_schur_index(
    solution: Solution, model: PeelingModel | None = None, V: float = 1.1, tau: float = 1e-3, zoom: float = 0.01,
    *, axes=None, path=None,
) -> Figure:  # fmt: skip
    """v, |J_t| (log) and the local index along a trajectory, stick and slip phases shaded.

    Left: the whole run; right: its last ``zoom`` seconds [s] (default 10 ms), where the slip
    phase and the index change happen (a sliver at the full scale). ``axes``: six matplotlib
    Axes to draw into, row by row (v, its zoom, |J_t|, its zoom, the index, its zoom); None: a
    new figure. Returns the figure (the axes' when given); ``path``: saved there.
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.ticker import MaxNLocator

    model = PeelingModel() if model is None else model
    a = analyze(solution, model, V, tau)
    v_top, _ = phi_extrema(model, V)
    drawn = panels(axes, 6, lambda fig: fig.subplots(3, 2, sharex="col", width_ratios=(3, 2)).ravel(),
                   figsize=(11.0, 8.5), what="v, |J_t| and the index, each with its zoom, row by row")  # fmt: skip
    axes = np.asarray(drawn.axes, dtype=object).reshape(3, 2)
    ts = a.ts
    t_end = float(solution.t_stop) if not bool(solution.completed) else float(ts[a.valid][-1])
    t_zoom = max(float(ts[0]), t_end - zoom)
    index = np.where(a.valid, a.local_index, np.nan)
    for column, in_zoom in ((0, np.ones_like(a.valid)), (1, ts >= t_zoom - 1e-12)):
        ax_v, ax_j, ax_i = axes[:, column]
        for ax in axes[:, column]:
            _shade_phases(ax, ts, a.stick & in_zoom, a.slip & in_zoom)
            for t in a.bifurcation_times:
                ax.axvline(t, color="C3", ls=":", lw=1.2)
            if not bool(solution.completed):
                ax.axvline(float(solution.t_stop), color="k", ls=":", lw=1.0)
            ax.grid(True, alpha=0.3)
        ax_v.plot(ts[in_zoom], a.v[in_zoom], color="k", lw=1.1)
        if np.isfinite(v_top):
            ax_v.axhline(v_top, color="C1", ls="--", lw=0.8)
        ax_v.set_yscale("log" if column == 0 else "linear")  # v spans 10 decades, but not in the zoom
        ax_j.plot(ts[in_zoom], np.abs(a.schur[in_zoom]), color="C3", lw=1.1)
        ax_j.axhline(1.0, color="k", ls="--", lw=0.8)
        ax_j.set_yscale("log")
        ax_i.step(ts[in_zoom], index[in_zoom], where="mid", color="C2", lw=1.5)
        ax_i.yaxis.set_major_locator(MaxNLocator(integer=True, min_n_ticks=1))
        top = int(np.nanmax(index)) if np.isfinite(index).any() else 1
        ax_i.set_ylim(min(0.5, np.nanmin(index) - 0.5) if np.isfinite(index).any() else 0.5, top + 0.5)
        ax_i.set_xlabel("time t [s]")
    for ax in axes[:, 0]:
        ax.axvline(t_zoom, color="0.4", ls="--", lw=0.8)
    axes[2, 1].set_xlim(t_zoom, t_end + 0.02 * zoom)
    axes[0, 0].set_ylabel("peeling velocity v [m/s]")
    axes[1, 0].set_ylabel("|J_t| [N·s/m]")
    axes[2, 0].set_ylabel("local index ⌈log_τ|J_t|⌉ + 1")
    axes[0, 0].set_title("the whole run")
    axes[0, 1].set_title(f"zoom: the last {zoom * 1e3:g} ms before t = {t_end:.4g} s")
    handles = [
        Line2D([], [], color="k", lw=1.1),
        Line2D([], [], color="C1", ls="--", lw=0.8),
        Line2D([], [], color="C3", lw=1.1),
        Line2D([], [], color="k", ls="--", lw=0.8),
        Line2D([], [], color="C2", lw=1.5),
        Patch(color="tab:blue", alpha=0.3),
        Patch(color="tab:orange", alpha=0.3),
        Line2D([], [], color="0.4", ls="--", lw=0.8),
    ]
    labels = [
        "v",
        f"v = {v_top:.3g} m/s, the maximum of φ (stick → slip)",
        "|J_t|",
        "|J_t| = 1 (index 2 below)",
        "local index",
        "stick (∂φ/∂v > 0)",
        "slip (∂φ/∂v < 0)",
        "start of the zoom",
    ]
    if a.bifurcation_times.size:
        handles.append(Line2D([], [], color="C3", ls=":", lw=1.2))
        labels.append("bifurcation point (J_t = 0 or min |J_t| < threshold)")
    if not bool(solution.completed):
        handles.append(Line2D([], [], color="k", ls=":", lw=1.0))
        labels.append(f"run stops: {solution.method} at t = {float(solution.t_stop):.4g} s")
    drawn.legend(handles, labels, loc="outside lower center", ncols=4, fontsize=8)
    heading = f"Structure along the trajectory, V = {V:g} m/s, τ = {tau:g} s ({solution.method})"
    return drawn.finish(heading if drawn.own else None, path, dpi=130)


def plot_bifurcation_diagram(diagram: BifurcationDiagram, *, ax=None, path=None) -> Figure:
    """Late local maxima (▲) and minima (▼) of v against V. A run that stopped early is a ×
    on the V axis's edge with the time it stopped (no v there: it is not a value of v),
    its extrema from before the stop drawn open. Returns the figure (``ax``'s when given);
    ``path``: saved there."""
    drawn = panels(ax, 1, lambda fig: [fig.subplots()], figsize=(8.0, 4.5), name="ax")
    (ax,) = drawn.axes
    stopped = ~np.asarray(diagram.completed, bool)
    for V, v_max, v_min, early in zip(diagram.V, diagram.v_max, diagram.v_min, stopped):
        face = "none" if early else None
        ax.plot(np.full(v_max.shape, V), v_max, "^", color="C3", mfc=face, ms=4)
        ax.plot(np.full(v_min.shape, V), v_min, "v", color="C0", mfc=face, ms=4)
    ax.plot(diagram.V, diagram.V, "k--", lw=0.8, label="v = V")
    ax.plot([], [], "^", color="C3", label="local maxima of v")
    ax.plot([], [], "v", color="C0", label="local minima of v")
    if stopped.any():
        edge = ax.get_xaxis_transform()  # x in data, y in axes: on the lower edge, at no value of v
        ax.plot(diagram.V[stopped], np.zeros(stopped.sum()), "kx", ms=7, mew=1.5, transform=edge, clip_on=False,
                label=f"stopped before t_final = {diagram.t_transient * 2:g} s (at the time written; open: "
                "its extrema before the stop)")  # fmt: skip
        for V, t in zip(diagram.V[stopped], np.asarray(diagram.t_stop, float)[stopped]):
            ax.annotate(f"{t:.3g} s", (V, 0.0), xycoords=edge, xytext=(0, 5), textcoords="offset points",
                        ha="center", fontsize=6.5)  # fmt: skip
    ax.set_xlabel("pull velocity V [m/s]")
    ax.set_ylabel("late extrema of v [m/s]")
    ax.set_title(f"Bifurcation diagram, τ = {diagram.tau:g} s (t ≥ {diagram.t_transient:g} s)")
    ax.grid(True, alpha=0.3)
    # below the axes: inside, it hid the extrema at small V
    drawn.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncols=2, fontsize=8)
    return drawn.finish(None, path, dpi=130)


def _reporter(progress, log):
    """``progress`` as a function of one line (the library's convention, ``docs/plotting.md``):
    False → silent, True → the line on stderr, a callable → called with it; ``log`` is the
    old name of a callable."""
    if log is not None:
        import warnings

        warnings.warn("make_figures/write_figures: log= is deprecated and will be removed in peeljax 0.3.0; "
                      "give the callable as progress=", DeprecationWarning, stacklevel=3)  # fmt: skip
        progress = log
    if callable(progress):
        return progress
    if progress:
        import sys

        return lambda message: print(f"peeljax figures: {message}", file=sys.stderr, flush=True)
    return lambda message: None


def make_figures(
    t_final: float = 3.0, model: PeelingModel | None = None, log=None, *, progress=False
) -> tuple[dict[str, Figure], dict]:
    """Run every simulation and build every figure; returns (figures by name, timings and run facts).

    ``progress``: False (silent), True (a line on stderr after each group of runs) or a
    callable taking that line (``log``: its deprecated name)."""
    model = PeelingModel() if model is None else model
    say = _reporter(progress, log)
    facts: dict = {"runs": {}}
    start = time.perf_counter()
    runs: dict[float, dict[float, Solution]] = {}
    for V, spec in RUNS.items():
        runs[V] = {}
        for tau in spec.taus:
            # a whole number of steps, so that the step is exactly spec.dt (the stops depend on it)
            t_run = max(1, round(t_final / spec.dt)) * spec.dt
            solution = simulate(model, V, tau, spec.dt, t_run)
            runs[V][tau] = solution
            facts["runs"][f"V={V:g},tau={tau:g}"] = {
                "dt": spec.dt,
                "completed": bool(solution.completed),
                "t_stop": float(solution.t_stop),
            }
        say(f"ran V = {V:g} ({len(spec.taus)} values of tau)")
    figures = {}
    r11 = runs[1.1]
    h11 = RUNS[1.1].dt
    figures["fig2_v_V1.1"] = _plot_against_time(r11, 3, "peeling velocity v [m/s]", "Fig. 2: v(t), V = 1.1 m/s", 1.1)
    figures["fig3_alpha_V1.1"] = _plot_against_time(
        r11, 0, "peel-front angle α [rad]", "Fig. 3: α(t), V = 1.1 m/s", None
    )
    fig, (ax,) = _figure()
    for i, (tau, solution) in enumerate(r11.items()):
        _, ys = _series(solution)
        ax.plot(
            ys[:, 3], np.asarray(model.tension(ys[:, 2], ys[:, 0])), color=f"C{i}", lw=1.0, label=_label(tau, solution)
        )
    ax.axvline(1.1, color="k", ls="--", lw=0.8, label="v = V")
    # on the constraint (sac) with α = 0, v = V: F = φ(V, V); large τ relaxes (sac) and ends elsewhere
    phi_VV = float(model.phi(1.1, 1.1))
    ax.axhline(phi_VV, color="0.4", ls=":", lw=1.0, label=f"F = φ(V, V) = {phi_VV:.0f} N (constraint sac at v = V)")
    ax.set_xlabel("peeling velocity v [m/s]")
    ax.set_ylabel("tension F(u, α) [N]")
    ax.set_title("Fig. 4: F(u, α) against v, V = 1.1 m/s")
    ax.grid(True, alpha=0.3)
    _legend_below(fig, ax)
    figures["fig4_F_vs_v_V1.1"] = fig
    figures["fig5_v_V2"] = _plot_against_time(runs[2.0], 3, "peeling velocity v [m/s]", "Fig. 5: v(t), V = 2 m/s", 2.0)
    figures["fig6_v_V4"] = _plot_against_time(runs[4.0], 3, "peeling velocity v [m/s]", "Fig. 6: v(t), V = 4 m/s", 4.0)
    for name in ("fig2_v_V1.1", "fig3_alpha_V1.1", "fig4_F_vs_v_V1.1"):
        _mark_uniform_mesh(figures[name], h11)
    _mark_uniform_mesh(figures["fig5_v_V2"], RUNS[2.0].dt)
    _mark_uniform_mesh(figures["fig6_v_V4"], RUNS[4.0].dt)
    fig, (ax,) = _figure()
    for i, (V, spec) in enumerate(RUNS.items()):
        tau = spec.taus[0]
        ts, ys = _series(runs[V][tau])
        ax.plot(ts, ys[:, 3], color=f"C{i}", lw=1.0, label=f"V = {V:g} m/s, " + _label(tau, runs[V][tau]))
        ax.axhline(V, color=f"C{i}", ls="--", lw=0.6)
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("peeling velocity v [m/s]")
    ax.set_title("Fig. 7: v(t) at the three pull velocities (dashed: V)")
    ax.grid(True, alpha=0.3)
    _legend_below(fig, ax)
    figures["fig7_v_three_V"] = _mark_uniform_mesh(
        fig, *(spec.dt for spec in RUNS.values()), labels=tuple(f"V = {V:g}" for V in RUNS)
    )
    figures["phi_extrema"] = plot_phi_extrema(model)
    b_dt = BIFURCATION_RUN["dt"]
    diagram = bifurcation_diagram(
        BIFURCATION_RUN["Vs"],
        BIFURCATION_RUN["tau"],
        model=model,
        dt=b_dt,
        t_final=max(1, round(t_final / b_dt)) * b_dt,
    )
    facts["bifurcation"] = {
        "V": [float(V) for V in diagram.V],
        "completed": [bool(c) for c in diagram.completed],
        "spread": [
            float(a.max() - b.min()) if a.size and b.size else None for a, b in zip(diagram.v_max, diagram.v_min)
        ],
    }
    figures["bifurcation_V"] = _mark_uniform_mesh(plot_bifurcation_diagram(diagram), b_dt)
    say("ran the bifurcation diagram")
    ref_t = min(SCHUR_RUN["t_final"], t_final)
    reference = simulate_reference(
        model, SCHUR_RUN["V"], SCHUR_RUN["tau"], SCHUR_RUN["dt"], ref_t, rtol=1e-10, atol=1e-12
    )
    facts["schur_reference"] = {"completed": bool(reference.completed), "t_stop": float(reference.t_stop)}
    figures["schur_index_V1.1"] = plot_schur_index(reference, model, SCHUR_RUN["V"], SCHUR_RUN["tau"])
    facts["uniform_mesh_figures"] = [name for name, fig in figures.items() if "uniform mesh" in fig.get_suptitle()]
    facts["compute_seconds"] = time.perf_counter() - start
    return figures, facts


def write_figures(out: str | Path, t_final: float = 3.0, fmt: str = "png", log=None, *, progress=False) -> dict:
    """Build every figure and save ``<name>.<fmt>`` and ``captions.md`` in the folder ``out``
    (``progress`` as :func:`make_figures`).

    Returns the run facts (completion, stop times, timings) and the written paths.
    """
    start = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figures, facts = make_figures(t_final=t_final, progress=_reporter(progress, log))
    paths = []
    for name, fig in figures.items():
        path = out / f"{name}.{fmt}"
        save_figure(fig, path, dpi=130)
        paths.append(str(path))
    lines = ["# peeljax figures", "", f"Generated by `peeljax figures` (t_final = {t_final:g} s).", "", MESH_NOTE, ""]
    lines += [f"- `{name}.{fmt}`: {CAPTIONS[name]}" for name in figures]
    write_text(out / "captions.md", "\n".join(lines) + "\n")
    facts["files"] = paths
    facts["total_seconds"] = time.perf_counter() - start
    return facts
