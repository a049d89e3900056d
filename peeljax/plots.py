"""Plots of runs in the style of the paper's Figs. 2–3: v(t), α(t) and the tension F(t).

matplotlib only. The figures are plain :class:`matplotlib.figure.Figure` objects with an Agg
canvas attached, so saving needs no GUI and importing this module never switches the pyplot
backend (notebooks keep theirs; a returned figure still displays inline there).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .model import PeelingModel
from .solution import Solution, StopReason

__all__ = ["plot_fit", "plot_run", "plot_runs", "plot_sweep_map", "short_reason"]

_SHORT_REASONS = {
    StopReason.COMPLETED: "completed",
    StopReason.NEWTON_FAILED: "Newton's method did not converge",
    StopReason.IMPASSE: "impasse point (J_t changed sign)",
    StopReason.NONFINITE: "non-finite state",
    StopReason.STALLED: "step size collapsed (stalled)",
    StopReason.MAX_STEPS: "reached max_steps",
    StopReason.SOLVER_FAILED: "diffrax solver failed",
}
_METHOD_LABELS = {"alpha": "α-method", "alpha-adaptive": "α-method, error control", "diffrax": "diffrax reference"}
_PANELS = (
    ("v", "peeling velocity v [m/s]"),
    ("alpha", "peel-front angle α [rad]"),
    ("F", "tension F(u, α) [N]"),
)


def short_reason(solution: Solution, limit: int = 48) -> str:
    """A few words for why a single run stopped (for annotations)."""
    code = int(np.asarray(solution.status))
    if code in _SHORT_REASONS:
        return _SHORT_REASONS[code]
    # An unknown code: the first clause of the message, cut to ``limit`` characters.
    text = re.split(r"[:;,(]", solution.reason, maxsplit=1)[0].strip()
    return text if len(text) <= limit else text[: limit - 1].rstrip() + "…"


def _host_series(solution: Solution, model: PeelingModel) -> dict[str, np.ndarray]:
    """t, v, α and F on the host; NaN after a stop (matplotlib leaves a gap there)."""
    if np.ndim(solution.status) != 0:
        raise ValueError("plot a single trajectory: index the batch of a vmapped Solution first")
    valid = np.asarray(solution.valid)
    ys = np.asarray(solution.ys, dtype=float)
    tension = np.asarray(model.tension(ys[:, 2], ys[:, 0]), dtype=float)
    return {
        "t": np.asarray(solution.ts, dtype=float),
        "v": ys[:, 3],
        "alpha": ys[:, 0],
        "F": np.where(valid, tension, np.nan),
    }


def plot_runs(
    solutions: Sequence[Solution],
    labels: Sequence[str] | None,
    model: PeelingModel | None = None,
    *,
    V: float | None = None,
    title: str | None = None,
    path: str | Path | None = None,
) -> Figure:
    """Overlay runs in three stacked panels sharing the time axis: v(t), α(t), F(t).

    Args:
        solutions: single-trajectory :class:`Solution` objects (their grids may differ).
        labels: one legend label per solution (default: each solution's ``method``).
        model: the model the runs used, for F = ``model.tension(u, α)`` (default: the paper's).
        V: pull velocity [m/s]; drawn as a dashed horizontal line in the v panel when given.
        title: figure title.
        path: when given, the figure is saved there (format from the suffix, PNG if none).

    Returns:
        The figure. A run that stopped gets a dotted vertical line at ``t_stop`` in every
        panel and an annotation with the shortened reason in the v panel.
    """
    solutions = list(solutions)
    if not solutions:
        raise ValueError("plot_runs: no solutions given")
    labels = [_METHOD_LABELS.get(s.method, s.method) for s in solutions] if labels is None else list(labels)
    if len(labels) != len(solutions):
        raise ValueError(f"plot_runs: {len(solutions)} solutions but {len(labels)} labels")
    model = PeelingModel() if model is None else model

    fig = Figure(figsize=(8.0, 8.5), layout="constrained")
    FigureCanvasAgg(fig)  # attaches itself: savefig works with no pyplot backend
    axes = fig.subplots(len(_PANELS), 1, sharex=True)
    colors = [f"C{i % 10}" for i in range(len(solutions))]
    n_stopped = 0
    t_range = [np.inf, -np.inf]
    for solution, label, color in zip(solutions, labels, colors):
        series = _host_series(solution, model)
        t_range = [min(t_range[0], series["t"][0]), max(t_range[1], series["t"][-1])]
        for ax, (key, _) in zip(axes, _PANELS):
            ax.plot(series["t"], series[key], color=color, lw=1.2, label=label)
        if int(np.asarray(solution.status)) != 0:
            t_stop = float(solution.t_stop)
            for ax in axes:
                ax.axvline(t_stop, color=color, ls=":", lw=1.2)
            # The note goes on the side of the line with more room; several notes stack downwards.
            ts = series["t"]
            right = t_stop < 0.5 * (ts[0] + ts[-1])
            axes[0].annotate(
                f"stopped at t = {t_stop:.4g} s\n{short_reason(solution)}",
                xy=(t_stop, 1.0),
                xycoords=("data", "axes fraction"),
                xytext=(4 if right else -4, -4 - 26 * n_stopped),
                textcoords="offset points",
                ha="left" if right else "right",
                va="top",
                fontsize=8,
                color=color,
                bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": color, "alpha": 0.85},
            )
            n_stopped += 1
    if V is not None:
        axes[0].axhline(float(V), color="k", ls="--", lw=0.9, label=f"pull velocity V = {float(V):g} m/s")
    for ax, (_, ylabel) in zip(axes, _PANELS):
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
    # The whole requested interval, so that a run which stopped early visibly ends short of it.
    axes[-1].set_xlim(*t_range)
    axes[-1].set_xlabel("time t [s]")
    axes[0].legend(loc="best", fontsize=8)
    if title:
        fig.suptitle(title)
    if path is not None:
        fig.savefig(path, dpi=150)
    return fig


def plot_run(
    solution: Solution,
    model: PeelingModel | None = None,
    *,
    V: float | None = None,
    label: str | None = None,
    title: str | None = None,
    path: str | Path | None = None,
) -> Figure:
    """One run in three stacked panels: v(t) with the pull velocity V, α(t), F(t).

    The single-run case of :func:`plot_runs` (same arguments; ``label`` defaults to the
    solution's method).
    """
    return plot_runs([solution], None if label is None else [label], model, V=V, title=title, path=path)


def plot_sweep_map(result, *, title: str | None = None, path: str | Path | None = None) -> Figure:
    """The stick-slip map of a :class:`peeljax.SweepResult` over (τ, V) (cf. the paper's Figs. 2, 5–7).

    Left: completion (filled: completed [0, t_final]; cross: stopped, coloured by t_stop).
    Right: the spread of v over the window, v_std/V (log colour scale): large where the
    trajectory sticks and slips, ~0 where τ has smoothed v to V. τ on a log axis.
    """
    tau, V = np.asarray(result.tau, float), np.asarray(result.V, float)
    completed = np.asarray(result.completed, bool)
    t_final = float(result.settings.get("t_final", np.nanmax(result.t_stop)))
    fig = Figure(figsize=(11, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    left, right = fig.subplots(1, 2, sharey=True)
    size = 60 if V.size <= 200 else 20
    left.scatter(tau[completed], V[completed], s=size, marker="s", color="tab:green", label="completed")
    stopped = left.scatter(
        tau[~completed], V[~completed], s=size, marker="X", c=np.asarray(result.t_stop)[~completed],
        cmap="autumn", vmin=0.0, vmax=t_final, label="stopped",
    )  # fmt: skip
    if (~completed).any():
        fig.colorbar(stopped, ax=left, label="t_stop [s] of stopped runs")
    left.set_title("completion of [0, t_final]")
    left.legend(loc="best", fontsize=8)
    spread = np.asarray(result.v_std, float) / V
    ok = completed & np.isfinite(spread)
    floor = max(np.nanmin(spread[ok]) if ok.any() else 1e-12, 1e-12)
    from matplotlib.colors import LogNorm

    image = right.scatter(
        tau[ok], V[ok], s=size, marker="s", c=np.maximum(spread[ok], floor),
        norm=LogNorm(vmin=floor, vmax=max(floor * 10, np.nanmax(spread[ok]) if ok.any() else 1.0)), cmap="viridis",
    )  # fmt: skip
    right.scatter(tau[~completed], V[~completed], s=size, marker="x", color="0.6")
    fig.colorbar(image, ax=right, label="spread of v: std(v)/V over the window")
    right.set_title("stick-slip map")
    for ax in (left, right):
        ax.set_xscale("log")
        ax.set_xlabel("homogenization scale τ [s]")
        ax.grid(True, alpha=0.3)
    left.set_ylabel("pull velocity V [m/s]")
    if title:
        fig.suptitle(title)
    if path is not None:
        fig.savefig(path, dpi=150)
    return fig


def plot_fit(result, observations, *, model: PeelingModel | None = None, title: str | None = None, path: str | Path | None = None) -> Figure:
    """A fit (:func:`peeljax.fit_adhesion`): observed v(t) (and F(t)) against the fitted
    model's run at each V, and the fitted φ(v, V) against the start over the visited v range."""
    import jax.numpy as jnp

    from .simulate import simulate

    model = PeelingModel() if model is None else model
    settings = result.settings
    n = len(observations)
    fig = Figure(figsize=(4.2 * (n + 1), 3.4), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, n + 1, squeeze=False)[0]
    for ax, obs in zip(axes, observations):
        fitted = PeelingModel(R=model.R, I=model.I, k=model.k, l=model.l, adhesion=result.adhesion, geometry=model.geometry)
        run = simulate(fitted, V=obs.V, tau=settings["tau"], dt=settings["dt"], t_final=settings["t_final"])
        t, v = obs.series("v")
        ax.plot(t, v, ".", ms=2, color="0.5", label="data v")
        ax.plot(np.asarray(run.ts), np.asarray(run.v), "-", color="C0", label="fitted model v")
        ax.set_xlabel("t [s]")
        ax.set_ylabel("v [m/s]")
        ax.set_title(f"V = {obs.V:g} m/s")
        ax.legend(fontsize=7)
    ax = axes[-1]
    lo, hi = result.v_range
    lo = max(lo, 1e-12)
    v = np.geomspace(lo, max(hi, lo * 10), 300)
    for i, obs in enumerate(observations):
        ax.plot(v, np.asarray(result.adhesion(jnp.asarray(v), obs.V)), "-", color=f"C{i}", label=f"fitted, V = {obs.V:g}")
        ax.plot(v, np.asarray(result.start(jnp.asarray(v), obs.V)), "--", color=f"C{i}", alpha=0.6, label=f"start, V = {obs.V:g}")
    ax.set_xscale("log")
    ax.set_xlabel("v [m/s] (visited range)")
    ax.set_ylabel("φ(v, V) [N]")
    ax.set_title("adhesion law: fitted vs start")
    ax.legend(fontsize=7)
    fig.suptitle(title or f"fit: loss {result.initial_loss:.3g} → {result.final_loss:.3g} in {result.steps} iterations")
    if path is not None:
        fig.savefig(path, dpi=150)
    return fig
