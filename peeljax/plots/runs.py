"""Plots of runs in the style of the paper's Figs. 2–3: v(t), α(t) and the tension F(t); and
of a run carried through the folds of φ (:func:`plot_stick_slip`): v(t) and G(t) with the
jumps, and the G–v loop over φ(v, V).

matplotlib only. The figures are plain :class:`matplotlib.figure.Figure` objects with an Agg
canvas attached, so saving needs no GUI and importing this module never switches the pyplot
backend (notebooks keep theirs; a returned figure still displays inline there).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from .._panels import panels, draw_phi
from ..model import PeelingModel
from ..solution import Solution, StopReason

__all__ = ["plot_fit", "plot_run", "plot_runs", "plot_stick_slip", "plot_sweep_map", "short_reason"]

_SHORT_REASONS = {
    StopReason.COMPLETED: "completed",
    StopReason.NEWTON_FAILED: "Newton's method did not converge",
    StopReason.IMPASSE: "impasse point (J_t changed sign)",
    StopReason.NONFINITE: "non-finite state",
    StopReason.STALLED: "step size collapsed (stalled)",
    StopReason.MAX_STEPS: "reached max_steps",
    StopReason.SOLVER_FAILED: "diffrax solver failed",
    StopReason.MAX_JUMPS: "reached max_jumps",
    StopReason.FOLD: "reached a fold of φ (fold='stop')",
}
_METHOD_LABELS = {
    "alpha": "α-method", "alpha-adaptive": "α-method, error control", "diffrax": "diffrax reference",
    "switching-tsit5-alpha": "Tsit5 ↔ α-method, error control",
}  # fmt: skip
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
    axes=None,
) -> Figure:
    """Overlay runs in three stacked panels sharing the time axis: v(t), α(t), F(t).

    Args:
        solutions: single-trajectory :class:`Solution` objects (their grids may differ).
        labels: one legend label per solution (default: each solution's ``method``).
        model: the model the runs used, for F = ``model.tension(u, α)`` (default: the paper's).
        V: pull velocity [m/s]; drawn as a dashed horizontal line in the v panel when given.
        title: figure title.
        path: when given, the figure is saved there (format from the suffix, PNG if none).
        axes: three matplotlib Axes to draw v, α and F into (a figure of the user's); None:
            a new figure.

    Returns:
        The figure (the axes' figure when they are given). A run that stopped gets a dotted
        vertical line at ``t_stop`` in every panel and an annotation with the shortened
        reason in the v panel. Each jump (a run through the folds) is a vertical segment at
        its time: the rows hold both sides of it.
    """
    solutions = list(solutions)
    if not solutions:
        raise ValueError("plot_runs: no solutions given")
    labels = [_METHOD_LABELS.get(s.method, s.method) for s in solutions] if labels is None else list(labels)
    if len(labels) != len(solutions):
        raise ValueError(f"plot_runs: {len(solutions)} solutions but {len(labels)} labels")
    model = PeelingModel() if model is None else model

    drawn = panels(
        axes, len(_PANELS), lambda fig: fig.subplots(len(_PANELS), 1, sharex=True), figsize=(8.0, 8.5),
        what="v, α and F",
    )  # fmt: skip
    axes = drawn.axes
    colors = [f"C{i % 10}" for i in range(len(solutions))]
    n_stopped = 0
    t_range = [np.inf, -np.inf]
    for solution, label, color in zip(solutions, labels, colors):
        series = _host_series(solution, model)
        # nanmin/nanmax: error control's accepted steps are padded with NaN rows
        t_range = [min(t_range[0], np.nanmin(series["t"])), max(t_range[1], np.nanmax(series["t"]))]
        for ax, (key, _) in zip(axes, _PANELS):
            ax.plot(series["t"], series[key], color=color, lw=1.2, label=label)
        if int(np.asarray(solution.status)) != 0:
            t_stop = float(solution.t_stop)
            for ax in axes:
                ax.axvline(t_stop, color=color, ls=":", lw=1.2)
            # The note goes on the side of the line with more room; several notes stack downwards.
            ts = series["t"]
            right = t_stop < 0.5 * (np.nanmin(ts) + np.nanmax(ts))
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
    return drawn.finish(title, path)


def plot_run(
    solution: Solution,
    model: PeelingModel | None = None,
    *,
    V: float | None = None,
    label: str | None = None,
    title: str | None = None,
    path: str | Path | None = None,
    axes=None,
) -> Figure:
    """One run in three stacked panels: v(t) with the pull velocity V, α(t), F(t).

    The single-run case of :func:`plot_runs` (same arguments, ``axes`` included; ``label``
    defaults to the solution's method).
    """
    return plot_runs([solution], None if label is None else [label], model, V=V, title=title, path=path, axes=axes)


# ---------------------------------------------------------------------------- stick-slip with jumps
_UP_COLOR, _DOWN_COLOR = "C3", "C0"  # stick → slip, slip → stick
_V_DECADES = 1e-12  # the log axes of v reach down to this fraction of the largest v, no further
_UP_LABEL, _DOWN_LABEL = "stick → slip jump (v up)", "slip → stick jump (v down)"


def _broken_at(t: np.ndarray, after: np.ndarray, *series: np.ndarray) -> list[np.ndarray]:
    """``t`` and ``series`` with a NaN row before each row just after a jump (``after``), so
    that a line is not drawn across a jump (the jumps are drawn on their own) and goes on from
    the state after it."""
    at = np.flatnonzero(after)
    return [np.insert(np.asarray(a, dtype=float), at, np.nan) for a in (t, *series)]


def _with_jump_rows(t, v, G, after, jump_t, v_after, G_jump):
    """t, v, G and the mask of the rows just after a jump, with both sides of every jump: a
    run's own rows where it kept them (``after`` not None), else (a file written before
    they were kept) the jump record's v after each jump inserted after the row at its time."""
    if after is not None:
        return t, v, G, np.asarray(after, bool)
    at = np.searchsorted(t, jump_t, side="right")
    mask = np.zeros(t.size + at.size, bool)
    mask[at + np.arange(at.size)] = True
    return np.insert(t, at, jump_t), np.insert(v, at, v_after), np.insert(G, at, G_jump), mask


def _positive_floor(*arrays: np.ndarray) -> float:
    """A value below every positive v, where v = 0 (a fully stuck tape) is drawn on a log axis."""
    values = np.concatenate([np.ravel(a) for a in arrays])
    positive = values[np.isfinite(values) & (values > 0)]
    return float(positive.min()) / 3.0 if positive.size else 1e-12


def plot_stick_slip(
    solution: Solution,
    model: PeelingModel | None,
    V: float,
    *,
    title: str | None = None,
    path: str | Path | None = None,
    transient: float | None = None,
    axes=None,
) -> Figure:
    """A run carried through the folds of φ (``fold="jump"``): v(t), G(t) and the G–v loop.

    Three panels:

    1. v(t) on a log axis; each recorded jump is a vertical segment from v before to v after
       it at its time (red: stick → slip at φ's maximum v̂; blue: slip → stick at its minimum
       v̌), so v is seen to jump between the two stable branches of G(x) = φ(v, V).
    2. G(t) = (1 + l·sinα/L)·F(u, α), the left side of the constraint (a sawtooth between the
       fold forces φ(v̌, V) and φ(v̂, V)); G is continuous across a jump (x is unchanged).
    3. The G–v loop: G against v (log axis) over the curve φ(v, V) (dashed), with the folds
       (v̂, φ(v̂, V)) and (v̌, φ(v̌, V)) marked and the jumps as horizontal segments at constant G.
       With ``transient``, only t ≥ transient (the settled loop); without one, or for a run
       that stopped before it, from the first jump on (the approach from rest is no part of
       the loop; the title says which).

    The v axes reach down to the lowest v of the cycles, never below 1e-12 of the largest v
    (lower v is drawn at the bottom, with a note); legends sit outside the data.

    Args:
        solution: a single run with a jump record (:attr:`Solution.jumps`).
        model: the model it used (default: the paper's), for G and φ.
        V: its pull velocity [m/s].
        title: figure title.
        path: when given, the figure is saved there (format from the suffix, PNG if none).
        transient: [s] the loop panel shows t ≥ transient only; shaded in the time panels.
        axes: three matplotlib Axes for v(t), G(t) and the loop (a figure of the user's; the
            legend of the time panels then goes into the v panel); None: a new figure.

    Returns:
        The figure. v = 0 (a fully stuck tape) is drawn at the bottom of the log axes. A run
        that stopped gets a dotted vertical line at ``t_stop``, its shortened reason in the
        legend above the panels.
    """
    if np.ndim(solution.status) != 0:
        raise ValueError("plot a single trajectory: index the batch of a vmapped Solution first")
    if solution.jumps is None:
        raise ValueError("plot_stick_slip: this run has no jump record (run it with fold='jump')")
    from ..branches import phi_folds

    model = PeelingModel() if model is None else model
    V = float(V)
    valid = np.asarray(solution.valid, dtype=bool)
    t = np.asarray(solution.ts, dtype=float)[valid]
    ys = np.asarray(solution.ys, dtype=float)[valid]
    v = ys[:, 3]
    G = np.asarray(model.shear_force(ys[:, :3].T), dtype=float)
    jumps = solution.jumps.as_numpy()
    jt, up, vb, va, jG = (jumps[key] for key in ("jump_t", "jump_up", "jump_v_before", "jump_v_after", "jump_G"))
    after = None if solution.after_jump is None else np.asarray(solution.after_jump, dtype=bool)[valid]
    t, v, G, after = _with_jump_rows(t, v, G, after, jt, va, jG)
    folds = phi_folds(model, V)
    v_hat, phi_hat, v_check, phi_check = (float(x) for x in (folds.v_max, folds.phi_max, folds.v_min, folds.phi_min))
    has_folds = bool(np.isfinite(v_hat) and np.isfinite(v_check))
    # The loop: after the transient; without one, or where the run stopped before it, from the
    # first jump on (the approach from the paper's v0 = 1e-10·V is no part of the loop).
    early = transient is not None and not np.any(t >= transient)
    loop_start = transient if transient is not None and not early else (float(jt[0]) if jt.size else None)
    # The log axis of v: down to the lowest v once stick-slip has begun, so that the approach
    # from the paper's v0 = 1e-10·V does not squash the cycles (a note says where v starts),
    # and never below 1e-12 of the top (a tape stuck at v → 1e-54 would take 60 decades).
    top = float(np.nanmax(np.concatenate([v[np.isfinite(v)], vb, va, [V]])))
    low_all = _positive_floor(v, vb, va)
    low_cycles = _positive_floor(v[t >= jt[0]], vb, va) if jt.size else low_all
    cropped = low_all < low_cycles / 30.0
    v_bottom = max(low_cycles / 3.0 if cropped else low_all, top * _V_DECADES)
    floor = v_bottom * 1.5  # where v = 0 (fully stuck), or v below the axis, is drawn
    clip = top * _V_DECADES
    below = v[np.isfinite(v) & (v > 0) & (v < clip)]
    stuck = bool(np.any(v[np.isfinite(v)] <= 0) or np.any(va <= 0))
    # v below the clip (v = 0 too) at the floor; NaN (the breaks at the jumps) kept
    shown = lambda values: np.where(np.isnan(values) | (np.asarray(values) >= clip), values, floor)  # noqa: E731

    def mosaic(fig):
        axes = fig.subplot_mosaic([["v", "loop"], ["G", "loop"]], width_ratios=(1.3, 1.0))
        axes["G"].sharex(axes["v"])
        return [axes["v"], axes["G"], axes["loop"]]

    drawn = panels(axes, 3, mosaic, figsize=(13.0, 7.6), what="v(t), G(t) and the G–v loop")
    ax_v, ax_G, ax_loop = drawn.axes
    tb, vb_line, Gb_line = _broken_at(t, after, v, G)

    # 1. v(t) with the jumps
    ax_v.plot(tb, shown(vb_line), color="0.2", lw=1.0, label="peeling velocity v(t)")
    for mask, color, label in ((up, _UP_COLOR, _UP_LABEL), (~up, _DOWN_COLOR, _DOWN_LABEL)):
        if mask.any():
            ax_v.vlines(jt[mask], shown(vb[mask]), shown(va[mask]), colors=color, lw=1.3, label=label)
    ax_v.axhline(V, color="k", ls="--", lw=0.9, label=f"pull velocity V = {V:g} m/s")
    if has_folds:
        for value in (v_hat, v_check):
            ax_v.axhline(value, color="0.55", ls=":", lw=0.9)
        ax_v.plot([], [], color="0.55", ls=":", lw=0.9, label=f"folds v̂ = {v_hat:.3g}, v̌ = {v_check:.3g} m/s")
    ax_v.set_yscale("log")
    ax_v.set_ylabel("peeling velocity v [m/s]")
    ax_v.set_ylim(bottom=v_bottom)
    notes = []
    if below.size:
        notes.append(f"v below {clip:.2g} m/s (down to {below.min():.2g}) drawn at the bottom")
    elif cropped:
        first = v[np.isfinite(v) & (v > 0)]
        notes.append(f"axis cut: v starts at {first[0]:.2g} m/s" if first.size else "axis cut")
    if stuck:
        notes.append("v = 0 (fully stuck) drawn at the bottom")
    if notes:
        ax_v.text(0.01, 0.02, "; ".join(notes), transform=ax_v.transAxes, fontsize=7, color="0.3", va="bottom",
                  bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none", "alpha": 0.8})  # fmt: skip

    # 2. G(t): the sawtooth between the fold forces
    ax_G.plot(tb, Gb_line, color="0.2", lw=1.0, label="G(t)")
    if has_folds:
        ax_G.axhline(phi_hat, color=_UP_COLOR, ls=":", lw=0.9, label=f"φ(v̂, V) = {phi_hat:.4g} N: slips")
        ax_G.axhline(phi_check, color=_DOWN_COLOR, ls=":", lw=0.9, label=f"φ(v̌, V) = {phi_check:.4g} N: re-sticks")
    ax_G.plot(jt[up], jG[up], "^", color=_UP_COLOR, ms=4, ls="none")
    ax_G.plot(jt[~up], jG[~up], "v", color=_DOWN_COLOR, ms=4, ls="none")
    ax_G.set_ylabel("shear force G = (1 + l·sinα/L)·F [N]")
    ax_G.set_xlabel("time t [s]")

    t_end = max(float(t[-1]), float(solution.t_stop)) if t.size else float(solution.t_stop)
    ax_v.set_xlim(float(t[0]) if t.size else 0.0, t_end)
    for ax in (ax_v, ax_G):
        if transient is not None and transient > 0:
            ax.axvspan(float(t[0]), transient, color="0.9", zorder=0,
                       label="transient (left out of the loop)" if ax is ax_v else None)  # fmt: skip
        ax.grid(True, alpha=0.3)
    ax_v.tick_params(labelbottom=False)
    if int(np.asarray(solution.status)) != 0:
        # the line in both panels, the words in the legend above them (a box would cover G(t))
        t_stop = float(solution.t_stop)
        for ax in (ax_v, ax_G):
            ax.axvline(t_stop, color="k", ls=":", lw=1.2,
                       label=f"stopped at t = {t_stop:.4g} s: {short_reason(solution)}" if ax is ax_v else None)  # fmt: skip
    # the data and a little room; the legends outside the axes, above them
    ax_v.set_ylim(top=top * 2.0)
    handles, labels = [], []
    for ax in (ax_v, ax_G):  # one legend for both panels: none of it over G's sawtooth
        h, lab = ax.get_legend_handles_labels()
        handles += h
        labels += lab
    ax_v.legend(handles, labels, loc="lower left", bbox_to_anchor=(0.0, 1.01), ncols=3, fontsize=7, framealpha=0.9,
                borderaxespad=0)  # fmt: skip

    # 3. the G–v loop over φ(v, V)
    start = -np.inf if loop_start is None else loop_start
    rows, kept = t >= start, jt >= start
    _, vl, Gl = _broken_at(t[rows], after[rows], v[rows], G[rows])
    up_k, vb_k, va_k, G_k = up[kept], vb[kept], va[kept], jG[kept]
    span = np.concatenate([vl[np.isfinite(vl)], vb_k, va_k] + ([[v_hat, v_check]] if has_folds else []))
    hi = float(np.nanmax(span)) if span.size else 10.0
    lo = max(_positive_floor(span) * 3.0, hi * _V_DECADES)
    grid = np.geomspace(lo / 2.0, hi * 1.5, 400)
    import jax.numpy as jnp

    ax_loop.plot(grid, np.asarray(model.phi(jnp.asarray(grid), V), dtype=float), color="k", ls="--", lw=1.0,
                 label=f"φ(v, V = {V:g} m/s)", zorder=3)  # fmt: skip
    if loop_start is None:
        window = "the run"
    elif loop_start == transient:
        window = f"t ≥ {transient:.3g} s"
    else:
        window = f"from the first jump, t ≥ {loop_start:.3g} s" + (
            f"; stopped before the transient {transient:.3g} s" if early else "")
    ax_loop.plot(shown(vl), Gl, color="C2", lw=3.0, alpha=0.55, label="the run: G against v (the window in the title)")
    for mask, color, label in ((up_k, _UP_COLOR, _UP_LABEL), (~up_k, _DOWN_COLOR, _DOWN_LABEL)):
        if mask.any():
            ax_loop.hlines(G_k[mask], shown(vb_k[mask]), shown(va_k[mask]), colors=color, lw=1.4, label=label,
                           zorder=4)  # fmt: skip
    if has_folds:
        ax_loop.plot([v_hat, v_check], [phi_hat, phi_check], "o", ms=7, mfc="white", mec="k", mew=1.4, zorder=5)
        ax_loop.annotate(
            f"fold v̂ = {v_hat:.4g} m/s\nφ(v̂, V) = {phi_hat:.4g} N", xy=(v_hat, phi_hat), xytext=(0, 14),
            textcoords="offset points", ha="center", va="bottom", fontsize=8,
            bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": _UP_COLOR, "alpha": 0.9},
        )  # fmt: skip
        ax_loop.annotate(
            f"fold v̌ = {v_check:.4g} m/s\nφ(v̌, V) = {phi_check:.4g} N", xy=(v_check, phi_check), xytext=(0, -14),
            textcoords="offset points", ha="center", va="top", fontsize=8,
            bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": _DOWN_COLOR, "alpha": 0.9},
        )  # fmt: skip
    forces = np.concatenate([Gl[np.isfinite(Gl)], G_k] + ([[phi_hat, phi_check]] if has_folds else []))
    if forces.size:  # the loop's forces, with room for the fold labels (φ climbs steeply beyond)
        g_lo, g_hi = float(forces.min()), float(forces.max())
        pad = max(g_hi - g_lo, 1e-3 * max(abs(g_hi), 1.0))
        ax_loop.set_ylim(g_lo - 0.3 * pad, g_hi + 0.45 * pad)
    ax_loop.set_xlim(lo / 2.0, hi * 1.5)
    ax_loop.set_xscale("log")
    ax_loop.set_xlabel("peeling velocity v [m/s]")
    ax_loop.set_ylabel("shear force G [N]")
    ax_loop.set_title(f"G–v loop over φ(v, V)\n({window})", fontsize=10)
    ax_loop.grid(True, alpha=0.3)
    ax_loop.legend(loc="upper left", fontsize=7, framealpha=0.9)
    return drawn.finish(title, path, fontsize=10)


# Up to this many pull velocities the sweep map draws one series per V against τ; more V
# values (on a full V × τ grid) are drawn as images over (τ, V).
SWEEP_MAP_MAX_LINES = 8
_STOPPED_LABEL = "stopped before t_final"


def _format_step(dt: float) -> str:
    """``0.01`` → "0.01 s"; 1/82 → "1/82 s" (the steps are often given as fractions)."""
    n = 1.0 / dt
    if abs(n - round(n)) < 1e-9 * n and round(n) > 1 and f"{dt:g}" != f"{dt:.12g}":
        return f"1/{round(n)} s"
    return f"{dt:g} s"


def _sweep_heading(result, title: str | None, t_final: float, window: tuple[float, float], n_V: int, n_tau: int,
                   grid: bool) -> str:  # fmt: skip
    """The figure title: the user's title (if any) over a line with the sweep's settings."""
    settings = result.settings or {}
    completed = np.asarray(result.completed, bool)
    runs = f"{completed.size} run{'' if completed.size == 1 else 's'}"
    parts = [f"{runs} ({n_V} V × {n_tau} τ)" if grid else f"{runs} ({n_V} V, {n_tau} τ values)"]
    if settings.get("dt") is not None:
        parts.append(f"dt = {_format_step(float(settings['dt']))}")
    elif settings.get("rtol") is not None:
        parts.append(f"error control rtol = {settings['rtol']:g}, atol = {settings['atol']:g}")
    parts.append(f"t_final = {t_final:g} s")
    parts.append(f"window t ∈ [{window[0] * t_final:g}, {window[1] * t_final:g}] s")
    parts.append(f"{int(completed.sum())} completed, {int((~completed).sum())} stopped")
    params = [name for name in getattr(result, "params", {}) or {}]
    if params:
        parts.append("also swept: " + ", ".join(params) + " (overplotted)")
    line = ", ".join(parts)
    return f"{title}\n{line}" if title else f"peeljax sweep: {line}"


def _events_title(events: np.ndarray, completed: np.ndarray) -> tuple[str, bool]:
    """The events panel's title, and whether any completed run had an event."""
    if not completed.any():
        return "stick-slip events: no run completed", False
    if (events[completed] > 0).any():
        return "stick-slip events in the window", True
    return "no stick-slip events in this sweep", False


def _no_events_note(ax, any_completed: bool) -> None:
    text = (
        "no completed run crossed v_slip (the v of the maximum of φ)\nupwards in the window"
        if any_completed
        else "every run stopped before t_final:\nno events over the whole window to count"
    )
    ax.text(
        0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", fontsize=9,
        bbox={"boxstyle": "round,pad=0.4", "fc": "white", "ec": "0.6", "alpha": 0.9},
    )  # fmt: skip


def _sweep_lines(drawn, tau, V, completed, t_stop, spread, events, t_final: float) -> None:
    """Few V: three panels against τ (log), one series per V; ● completed, × stopped. The top
    panel has a row per V (the runs of every V apart, each in its colour), a stopped run's
    t_stop written by its ×."""
    events_title, any_events = _events_title(events, completed)
    axes = drawn.axes
    Vs = np.unique(V)
    lo = np.nanmin(spread[completed & (spread > 0)]) if (completed & (spread > 0)).any() else None
    for i, V_i in enumerate(Vs):
        color = f"C{i % 10}"
        row = np.flatnonzero(V == V_i)
        row = row[np.argsort(tau[row], kind="stable")]
        done, stop = row[completed[row]], row[~completed[row]]
        axes[0].plot(tau[row], np.full(row.size, i), "-", color=color, lw=1.0, alpha=0.4)
        axes[0].plot(tau[done], np.full(done.size, i), "o", color=color, ms=6)
        axes[0].plot(tau[stop], np.full(stop.size, i), "x", color=color, ms=8, mew=2)
        for k in stop:  # how far it got
            axes[0].annotate(f"{t_stop[k]:.3g} s", (tau[k], i), xytext=(0, 6), textcoords="offset points",
                             ha="center", va="bottom", fontsize=6.5, color=color)  # fmt: skip
        axes[1].plot(tau[done], np.maximum(spread[done], lo) if lo else spread[done], "o-", color=color, ms=5, lw=1.2)
        if any_events:
            axes[2].plot(tau[done], events[done], "o-", color=color, ms=5, lw=1.2)
        # stopped runs have no statistics over the whole window: a × on the panels' lower edge
        # (only when there are some: an empty unclipped line breaks the constrained layout)
        for ax in (axes[1:] if any_events else axes[1:2]) if stop.size else ():
            ax.plot(tau[stop], np.zeros(stop.size), "x", color=color, ms=8, mew=2,
                    transform=ax.get_xaxis_transform(), clip_on=False)  # fmt: skip
    axes[0].set_yticks(np.arange(Vs.size), [f"V = {V_i:g}" for V_i in Vs], fontsize=8)
    axes[0].set_ylim(-0.6, Vs.size - 0.4)
    axes[0].set_ylabel("pull velocity [m/s]")
    axes[0].set_title(f"how far each run got: ● completed to t_final = {t_final:g} s, × stopped at the time written")
    if lo is None:  # nothing to draw on a log scale
        axes[1].text(0.5, 0.5, "no completed run with a spread of v > 0", transform=axes[1].transAxes, ha="center")
        axes[1].set_yticks([])
    else:
        hi = np.nanmax(spread[completed])
        if hi <= lo * 1.01:  # one value: a decade around it (a log axis cannot autoscale to a point)
            axes[1].set_ylim(lo / 3.0, lo * 3.0)
        axes[1].set_yscale("log")
    axes[1].set_ylabel("std(v)/V")
    axes[1].set_title("spread of v over the window (≈ 0: v smoothed to V)")
    axes[2].set_title(events_title)
    if any_events:
        from matplotlib.ticker import MaxNLocator

        axes[2].yaxis.set_major_locator(MaxNLocator(integer=True))
        axes[2].set_ylim(-0.5, max(1, int(events[completed].max())) + 0.5)
        axes[2].set_ylabel("events")
    else:
        _no_events_note(axes[2], completed.any())
        axes[2].set_yticks([])
    axes[-1].set_xscale("log")
    axes[-1].set_xlabel("homogenization scale τ [s]")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=f"C{i % 10}", marker="o", lw=1.2) for i in range(Vs.size)]
    labels = [f"V = {V_i:g} m/s" for V_i in Vs]
    handles += [
        Line2D([], [], color="k", marker="o", ls="none"),
        Line2D([], [], color="k", marker="x", ms=8, mew=2, ls="none"),
    ]
    stopped_label = _STOPPED_LABEL + ("\n(lower panels: × on the axis, no value)" if (~completed).any() else " (none)")
    labels += ["completed [0, t_final]", stopped_label]
    drawn.legend(handles, labels, ax=axes[1], loc="outside lower center", ncols=min(len(labels), 6), fontsize=8)


def _edges(centres: np.ndarray, log: bool) -> np.ndarray:
    """Cell edges around sorted centres (geometric midpoints on a log axis)."""
    c = np.log(centres) if log else centres.astype(float)
    if c.size == 1:
        half = 0.5 * np.log(10.0) if log else 0.5  # one decade (log) or 1 m/s around a single value
        e = np.array([c[0] - half, c[0] + half])
    else:
        mid = 0.5 * (c[1:] + c[:-1])
        e = np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]])
    return np.exp(e) if log else e


def _sweep_images(drawn, tau, V, completed, t_stop, spread, events, t_final: float, grid: bool) -> None:
    """Many V: three maps over (τ, V). On a full V × τ grid, images with the stopped cells
    hatched in every panel; otherwise (pairs, other parameters) squares at the runs, × stopped."""
    from matplotlib.collections import PolyCollection
    from matplotlib.colors import BoundaryNorm, LogNorm
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    stopped = ~completed
    fig, axes = drawn.figure, drawn.axes
    events_title, any_events = _events_title(events, completed)
    if grid:
        taus, Vs = np.unique(tau), np.unique(V)
        col, row = np.searchsorted(taus, tau), np.searchsorted(Vs, V)
        xe, ye = _edges(taus, log=True), _edges(Vs, log=False)

        def draw(ax, values, **kwargs):
            image = np.full((Vs.size, taus.size), np.nan)
            image[row, col] = values
            return ax.pcolormesh(xe, ye, np.ma.masked_invalid(image), **kwargs)

        cells = [[(xe[c], ye[r]), (xe[c + 1], ye[r]), (xe[c + 1], ye[r + 1]), (xe[c], ye[r + 1])]
                 for r, c in zip(row[stopped], col[stopped])]  # fmt: skip
        stopped_handle = Patch(facecolor="0.88", edgecolor="0.15", hatch="xxx", lw=0.0)
        stopped_label = _STOPPED_LABEL + (" (hatched)" if stopped.any() else " (none)")
    else:
        size = float(np.clip(4e4 / max(tau.size, 1), 4.0, 60.0))

        def draw(ax, values, **kwargs):
            keep = np.isfinite(values)
            return ax.scatter(tau[keep], V[keep], c=values[keep], s=size, marker="s", **kwargs)

        stopped_handle = Line2D([], [], color="k", marker="x", ls="none")
        stopped_label = _STOPPED_LABEL + ("" if stopped.any() else " (none)")
    # how far each run got
    mesh = draw(axes[0], t_stop, cmap="autumn", vmin=0.0, vmax=t_final)
    fig.colorbar(mesh, ax=axes[0], label="t_stop [s] (= t_final: completed)", location="bottom", shrink=0.9)
    axes[0].set_title("how far each run got")
    # spread of v (completed runs)
    ok = completed & np.isfinite(spread)
    positive = spread[ok & (spread > 0)]
    floor = max(float(positive.min()) if positive.size else 1e-12, 1e-12)
    top = max(floor * 10, float(positive.max()) if positive.size else 1.0)
    values = np.where(ok, np.maximum(spread, floor), np.nan)
    mesh = draw(axes[1], values, cmap="viridis", norm=LogNorm(vmin=floor, vmax=top))
    label = "std(v)/V over the window (≈ 0: v smoothed to V)"
    fig.colorbar(mesh, ax=axes[1], label=label, location="bottom", shrink=0.9)
    axes[1].set_title("spread of v")
    # events (completed runs)
    if any_events:
        n_max = int(events[completed].max())
        norm = BoundaryNorm(np.arange(-0.5, n_max + 1.5), 256)
        mesh = draw(axes[2], np.where(completed, events, np.nan), cmap="viridis", norm=norm)
        ticks = np.unique(np.linspace(0, n_max, min(n_max + 1, 8)).round().astype(int))
        fig.colorbar(mesh, ax=axes[2], label="upward crossings of v_slip (the v of the maximum of φ)", location="bottom",
                     shrink=0.9, ticks=ticks)  # fmt: skip
    else:
        draw(axes[2], np.where(completed, 0.0, np.nan), cmap="Greys", vmin=0.0, vmax=1.0)
        _no_events_note(axes[2], completed.any())
    axes[2].set_title(events_title)
    for ax in axes:
        if grid:
            ax.set_facecolor("0.88")  # the stopped cells of the value panels: no value
            ax.add_collection(PolyCollection(cells, facecolor="none", edgecolor="0.15", hatch="xxx", linewidth=0.0))
            ax.set_xlim(xe[0], xe[-1])
            ax.set_ylim(ye[0], ye[-1])
        elif stopped.any():
            ax.scatter(tau[stopped], V[stopped], marker="x", color="k", s=size, linewidths=1.0)
        ax.set_xscale("log")
        ax.set_xlabel("homogenization scale τ [s]")
    axes[0].set_ylabel("pull velocity V [m/s]")
    drawn.legend([stopped_handle], [stopped_label], loc="outside lower center", fontsize=8)


def plot_sweep_map(result, *, title: str | None = None, path: str | Path | None = None, axes=None) -> Figure:
    """The stick-slip map of a :class:`peeljax.SweepResult` over (τ, V) (cf. the paper's Figs. 2, 5–7).

    Three panels: how far each run got, the spread of v over the statistics window, std(v)/V
    (log scale: large where v sticks and slips, ≈ 0 where τ has smoothed v to V), and the
    stick-slip events in the window (or a note that there are none). Up to
    :data:`SWEEP_MAP_MAX_LINES` pull velocities: one series per V against τ (log axis), the
    first panel a row per V with ● completed and × stopped (its t_stop written by it), the
    value panels with × on their lower edge for a stopped run (no value). More V values on a
    full V × τ grid: images over (τ, V) with stopped cells hatched in every panel, the first
    one coloured by t_stop. The title gives the settings (dt, t_final, window) and the counts.

    Args:
        result: the sweep.
        title: a first title line (the settings follow).
        path: when given, the figure is saved there (format from the suffix, PNG if none).
        axes: three matplotlib Axes (a figure of the user's: stacked for few V, side by side
            for many); None: a new figure.
    """
    tau, V = np.asarray(result.tau, float), np.asarray(result.V, float)
    completed = np.asarray(result.completed, bool)
    t_stop = np.asarray(result.t_stop, float)
    spread = np.asarray(result.v_std, float) / V
    events = np.asarray(result.events)
    settings = result.settings or {}
    t_final = float(settings.get("t_final", np.nanmax(t_stop)))
    window = tuple(float(w) for w in settings.get("window", (0.5, 1.0)))
    n_V, n_tau = np.unique(V).size, np.unique(tau).size
    full_grid = n_V * n_tau == tau.size and np.unique(np.stack([tau, V]), axis=1).shape[1] == tau.size
    if n_V <= SWEEP_MAP_MAX_LINES:
        heights = (0.25 + 0.12 * n_V, 1.0, 1.0 if _events_title(events, completed)[1] else 0.4)
        drawn = panels(axes, 3, lambda fig: fig.subplots(3, 1, sharex=True, height_ratios=heights),
                       figsize=(10.0, 8.5), what="t_stop, spread and events against τ")  # fmt: skip
        _sweep_lines(drawn, tau, V, completed, t_stop, spread, events, t_final)
    else:
        drawn = panels(axes, 3, lambda fig: fig.subplots(1, 3, sharey=True), figsize=(14.0, 5.6),
                       what="t_stop, spread and events over (τ, V)")  # fmt: skip
        _sweep_images(drawn, tau, V, completed, t_stop, spread, events, t_final, grid=full_grid)
    heading = _sweep_heading(result, title, t_final, window, n_V, n_tau, full_grid)
    return drawn.finish(heading if drawn.own or title else None, path, fontsize=10)


def plot_fit(
    result, observations, *, model: PeelingModel | None = None, title: str | None = None,
    path: str | Path | None = None, axes=None,
) -> Figure:  # fmt: skip
    """A trajectory fit (:func:`peeljax.fit_adhesion`): each observed quantity (v, the tension F,
    the angle α: those the observations hold, one row each) against the start model's run
    (dashed) and the fitted model's (solid) at each V (one column each), the data drawn over
    both; and the fitted φ(v, V) against the start over the visited v range.

    Args:
        result: the fit's result (its ``adhesion``, ``start``, ``settings`` and ``v_range``).
        observations: the observations it was fitted to.
        model: the spool and tape of the fit (default: the paper's); φ is the start's and the fit's.
        title: the figure title (default: the loss before and after).
        path: when given, the figure is saved there (format from the suffix, PNG if none).
        axes: the Axes to draw into (a figure of the user's): one per observed quantity and
            observation, row by row (quantity by quantity, each over the observations), then
            one for φ; None: a new figure.
    """
    from ..fit.trajectory import QUANTITIES
    from ..simulate import simulate

    model = PeelingModel() if model is None else model
    settings = result.settings
    n = len(observations)
    quantities = [q for q in QUANTITIES if any(obs.series(q) is not None for obs in observations)]
    units = {"v": "v [m/s]", "F": "tension F [N]", "alpha": "angle α [rad]"}
    keys = [f"{q}{j}" for q in quantities for j in range(n)] + ["phi"]

    def mosaic(fig):
        grid = fig.subplot_mosaic([[f"{q}{j}" for j in range(n)] + ["phi"] for q in quantities])
        return [grid[key] for key in keys]

    drawn = panels(axes, len(keys), mosaic, figsize=(4.2 * (n + 1), 2.6 * len(quantities) + 0.8),
                   what=f"{len(quantities)} quantities × {n} observations, then φ")  # fmt: skip
    ax_of = dict(zip(keys, drawn.axes))

    def with_law(law):
        return PeelingModel(R=model.R, I=model.I, k=model.k, l=model.l, adhesion=law, geometry=model.geometry)

    runs = {"start": with_law(result.start), "fitted": with_law(result.adhesion)}
    engine = {"dt": settings["dt"]} if settings.get("dt") is not None else {"rtol": settings["rtol"], "atol": settings["atol"]}
    styles = {"start": {"ls": "--", "color": "C1", "lw": 1.1}, "fitted": {"ls": "-", "color": "C0", "lw": 1.3}}
    for j, obs in enumerate(observations):
        series = {}
        for name, law_model in runs.items():
            run = simulate(law_model, V=obs.V, tau=settings["tau"], t_final=settings["t_final"], **engine)
            series[name] = _host_series(run, law_model)
        for q in quantities:
            ax = ax_of[f"{q}{j}"]
            for name in ("start", "fitted"):
                ax.plot(series[name]["t"], series[name][q], label=f"{name} model {q}", zorder=2, **styles[name])
            data = obs.series(q)
            if data is not None:  # over the model lines: open dots, seen where the fit lies on them
                ax.plot(*data, "o", ms=3.2, mfc="none", mec="k", mew=0.7, alpha=0.8, zorder=3, label=f"data {q}")
            else:
                ax.text(0.5, 0.9, f"no {q} observed at this V", transform=ax.transAxes, ha="center", fontsize=7)
            ax.set_ylabel(units[q])
            if q == quantities[0]:
                ax.set_title(f"V = {obs.V:g} m/s")
            if q == quantities[-1]:
                ax.set_xlabel("t [s]")
            ax.legend(fontsize=7)
    ax = ax_of["phi"]
    lo, hi = result.v_range
    lo = max(lo, 1e-12)
    v = np.geomspace(lo, max(hi, lo * 10), 300)
    draw_phi(ax, v, [obs.V for obs in observations], result.adhesion, result.start)
    ax.set_xscale("log")
    ax.set_xlabel("v [m/s] (visited range)")
    ax.set_ylabel("φ(v, V) [N]")
    ax.set_title("adhesion law: fitted vs start")
    default = f"fit: loss {result.initial_loss:.3g} → {result.final_loss:.3g} in {result.steps} iterations"
    return drawn.finish(title, path, default_title=default)
