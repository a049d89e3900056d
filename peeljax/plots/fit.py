"""Plots of a fit of φ: a stick-slip table fit (:func:`peeljax.fit.fit_stick_slip`), a records fit
(:func:`peeljax.fit.fit_records`).

:func:`plot_table_fit` draws one panel per statistic of the table (the data with their error
bars against V, the start model's and the fitted model's statistics), a panel of the residuals
(model − data)/σ against V, and the fitted φ(v, V) with its 95 % confidence band over the v
the fitted runs visited, the start φ dashed and φ's folds marked.

:func:`peeljax.fit.synthetic.model_statistics` gives the model's statistics at the table's
pull velocities as the fit predicts them (the start's and the fitted φ's curves).

matplotlib only, with an Agg canvas attached to each figure (as :mod:`peeljax.plots`): saving
needs no GUI and importing this module never switches the pyplot backend.
"""

from __future__ import annotations

from pathlib import Path

import equinox as eqx
import numpy as np
from matplotlib.figure import Figure

from .._panels import draw_phi, panels
from ..measurements.records import left_limit_rows
from ..measurements.statistics import STATISTICS
from ..measurements.stick_slip_table import StickSlipTable
from ..fit.synthetic import model_statistics
from ..model import PeelingModel

__all__ = ["plot_records_fit", "plot_table_fit"]

_LABELS = {
    "F_mean": "mean tension F̄ [N]",
    "F_slip": "tension at slip F_slip [N]",
    "F_stick": "tension at stick F_stick [N]",
    "period": "period [s]",
    "slip_duration": "slip duration [s]",
}
_MARKERS = {"F_mean": "o", "F_slip": "^", "F_stick": "v", "period": "s", "slip_duration": "D"}


def _run_options(result) -> dict:
    s = result.settings
    keys = ("method", "tau", "transient", "window", "n_samples", "rtol", "atol", "taper")
    return {k: s[k] for k in keys if k in s}


_PHI_CURVES = 8  # the φ panel draws at most this many of the table's pull velocities
# Statistics that cannot be negative: their error bars stop at zero.
_POSITIVE = ("F_mean", "F_slip", "F_stick", "period", "slip_duration")


def _phi_V(table: StickSlipTable) -> np.ndarray:
    """The table's pull velocities for the φ panel: all of them, or :data:`_PHI_CURVES`
    spread over them (the first and the last among them)."""
    V = np.unique(np.asarray(table.V, float))
    if V.size <= _PHI_CURVES:
        return V
    return V[np.unique(np.round(np.linspace(0, V.size - 1, _PHI_CURVES)).astype(int))]


def _error_bars(values: np.ndarray, std, positive: bool):
    """(lower, upper) error bars of ±σ; for a quantity that cannot be negative the lower one
    stops at zero; and whether any was cut there."""
    if std is None:
        return None, False
    std = np.nan_to_num(np.asarray(std, float))
    lower = np.minimum(std, np.maximum(np.asarray(values, float), 0.0)) if positive else std
    return np.stack([lower, std]), bool(positive and np.any(lower < std))


def plot_table_fit(
    result, table: StickSlipTable, *, model: PeelingModel | None = None, title: str | None = None,
    path: str | Path | None = None, axes=None, what: str = "stick-slip table fit",
) -> Figure:  # fmt: skip
    """A stick-slip table fit: data vs start and fitted model per statistic, residuals, φ band.

    One panel per statistic against V: the data with ±σ error bars (cut at zero for the
    statistics that cannot be negative), the start model (orange, dashed) and the fitted model
    (blue, solid); the residuals (model − data)/σ; φ(v, V) of the fitted law (solid, with its
    95 % band) and the start (dashed) at the table's pull velocities, one colour each from a
    sequential map (no orange or blue there), φ's folds marked, the legend beside the panel.

    Args:
        result: :func:`~peeljax.fit.table.fit_stick_slip`'s :class:`~peeljax.fit.FitResult`.
        table: the table it was fitted to.
        model: the spool and tape of the fit (default the paper's); φ is replaced by the
            start's and the fitted law.
        title: the figure's title (default: ``what``, the fitted coefficients with their 95 %
            intervals, the loss and the stop reason).
        path: save the figure there (any format matplotlib's Agg canvas writes).
        axes: the Axes to draw into (a figure of the user's): one per fitted statistic, then the
            residuals', then φ's; None: a new figure.
    """
    from ..branches import phi_folds

    model = PeelingModel() if model is None else model
    stats = [s for s in result.settings.get("statistics", table.statistics) if s in table.statistics]
    n_panels = len(stats) + 2
    n_cols = min(n_panels, 3)
    n_rows = -(-n_panels // n_cols)

    def grid(fig):
        axes = fig.subplots(n_rows, n_cols, squeeze=False).ravel()
        for ax in axes[n_panels:]:
            ax.set_visible(False)
        return axes[:n_panels]

    drawn = panels(axes, n_panels, grid, figsize=(4.4 * n_cols + 1.2, 3.4 * n_rows),
                   what=f"{', '.join(stats)}, the residuals and φ")  # fmt: skip
    axes = drawn.axes
    options = _run_options(result)
    fitted, _ = model_statistics(result.adhesion, table, model=model, **options)
    started, _ = model_statistics(result.start, table, model=model, **options)
    V = np.asarray(table.V, float)

    for ax, s in zip(axes, stats):
        yerr, cut = _error_bars(table.values[s], table.std.get(s), s in _POSITIVE)
        ax.errorbar(V, table.values[s], yerr=yerr, fmt=_MARKERS[s], color="0.2", ms=4, capsize=3,
                    label="data ± σ" + (" (cut at 0)" if cut else ""), zorder=3)  # fmt: skip
        ax.plot(V, started[s], "--", marker=".", color="C1", alpha=0.8, label="start model")
        ax.plot(V, fitted[s], "-", marker=".", color="C0", label="fitted model")
        if cut:
            ax.set_ylim(bottom=0.0)
        ax.set_xlabel("pull velocity V [m/s]")
        ax.set_ylabel(_LABELS[s])
        ax.legend(fontsize=7)

    ax = axes[len(stats)]
    if result.residuals is not None:
        measured = [(i, s) for i in range(len(V)) for s in STATISTICS if s in stats and np.isfinite(table.values[s][i])]
        r = np.asarray(result.residuals, float)
        if len(measured) == r.size:
            for s in stats:
                idx = [n for n, (_, name) in enumerate(measured) if name == s]
                # grey markers: C0 and C1 mean the fitted and the start model beside this panel
                ax.plot([V[measured[n][0]] for n in idx], r[idx], _MARKERS[s], color="0.25", mfc="none", ms=6,
                        mew=1.1, label=s)  # fmt: skip
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set_xlabel("pull velocity V [m/s]")
    ax.set_ylabel("residual (model − data)/σ")
    ax.set_title(f"residuals (loss {result.final_loss:.3g})", fontsize=9)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)

    ax = axes[len(stats) + 1]
    lo, hi = result.v_range
    lo = max(float(lo), 1e-12)
    hi = max(float(hi), lo * 10)
    v = np.geomspace(lo, hi, 300)
    fitted_model = eqx.tree_at(lambda m: m.adhesion, model, result.adhesion)
    Vs = _phi_V(table)
    band = None if result.uncertainty is None else (lambda V_i: result.uncertainty.phi_band(result.adhesion, v, V_i))
    from matplotlib.lines import Line2D

    marks = [(Line2D([], [], marker="^", color="0.6", mec="k", ls="none"), "fold: φ max"),
             (Line2D([], [], marker="v", color="0.6", mec="k", ls="none"), "fold: φ min")]  # fmt: skip
    steady = [row for row in getattr(result, "rows", []) if row.get("kind") == "steady"]
    if steady:
        marks.append((Line2D([], [], marker="o", color="0.6", mec="k", ls="none"), "steady row: F_mean at v = V"))
    colors = draw_phi(ax, v, Vs, result.adhesion, result.start, band=band, extra=marks)
    for V_i, color in zip(Vs, colors):
        folds = phi_folds(fitted_model, V_i)
        for v_f, phi_f, mark in ((folds.v_max, folds.phi_max, "^"), (folds.v_min, folds.phi_min, "v")):
            v_f, phi_f = float(v_f), float(phi_f)
            if np.isfinite(v_f) and lo <= v_f <= hi:
                ax.plot([v_f], [phi_f], mark, color=color, mec="k", ms=7, zorder=4)
    if steady and "F_mean" in table.values:  # steady rows pin φ on its diagonal: F_mean = φ(V, V), at v = V
        curve = dict(zip(np.round(np.asarray(Vs, float), 12), colors))
        for row in steady:
            i, V_i = row["row"], row["V"]
            std = table.std.get("F_mean")
            ax.errorbar([V_i], [table.values["F_mean"][i]], yerr=None if std is None else [std[i]], fmt="o",
                        color=curve.get(round(V_i, 12), "0.2"), mec="k", ms=5, capsize=3, zorder=5)  # fmt: skip
    ax.set_xscale("log")
    ax.set_xlabel("v [m/s] (range visited by the fitted runs)")
    ax.set_ylabel("φ(v, V) [N]")
    ax.set_title("adhesion law: fitted" + (" (95 % band)" if band else "") + " vs start", fontsize=9)

    reason = result.stop_reason.split(":")[0] if result.stop_reason else ""
    default = (f"{what}: {fitted_values(result)}; loss {result.initial_loss:.3g} → {result.final_loss:.3g}"
               + (f", {reason}" if reason else ""))  # fmt: skip
    return drawn.finish(title, path, default_title=default)


def fitted_values(result) -> str:
    """'c1 = 402.3 [398.0, 406.6]': each free coefficient with its 95 % interval where known."""
    values = result.adhesion.coefficients()
    intervals = {} if result.uncertainty is None else result.uncertainty.intervals(0.95)
    parts = []
    for name in result.free:
        lo_hi = intervals.get(name)
        parts.append(f"{name} = {values[name]:.5g}" + (f" [{lo_hi[0]:.5g}, {lo_hi[1]:.5g}]" if lo_hi else ""))
    return ", ".join(parts) + (" (95 %)" if intervals else "")


# Most records drawn, and most points of a record's F(t) drawn (a longer one is thinned evenly).
RECORD_PANELS, RECORD_POINTS = 6, 4000


def plot_records_fit(
    result, records, *, model: PeelingModel | None = None, tau: float = 0.0, title: str | None = None,
    path: str | Path | None = None,
) -> Figure:  # fmt: skip
    """A fit of force records: each record's measured F(t) against the fitted model's and the
    start's (their runs from the paper's start at the record's V, on its times), and φ(v, V)
    fitted (with its 95 % band) against the start.

    From rest the model's stick-slip and the record's are not in phase after the first slips:
    compare their amplitude, period and mean (the fit compares statistics for such records).

    Args:
        result: :func:`~peeljax.fit.fit_records`'s result; records: the
            :class:`~peeljax.fit.Observation` s fitted (the first ``RECORD_PANELS`` drawn).
        model: spool and tape (default the paper's); tau: the model runs' τ (0: the DAE).
        title: the figure's title (default: the fitted coefficients with their 95 % intervals).
        path: save the figure there.
    """
    from ..simulate import simulate

    model = PeelingModel() if model is None else model
    drawn_records = [o for o in records if o.series("F") is not None][:RECORD_PANELS]
    count = len(drawn_records) + 1

    def grid(fig):
        return list(np.ravel(fig.subplots(count, 1, squeeze=False)))

    drawn = panels(None, count, grid, figsize=(9.0, 2.4 * count + 0.6))
    axes = drawn.axes
    for ax, record in zip(axes, drawn_records):
        t, F = record.series("F")
        keep = np.unique(np.linspace(0, len(t) - 1, min(len(t), RECORD_POINTS)).astype(int))
        t, F = t[keep], F[keep]
        ax.plot(t, F, color="0.35", lw=0.8, label="measured F(t)")
        for law, style, color, label in ((result.start, "--", "C1", "start model"), (result.adhesion, "-", "C0", "fitted model")):
            run = simulate(eqx.tree_at(lambda m: m.adhesion, model, law), V=record.V, tau=tau, t_final=float(t[-1]),
                           ts=t if t[0] == 0.0 else np.concatenate([[0.0], t]))  # fmt: skip
            times = np.asarray(run.ts)
            left = left_limit_rows(times, np.zeros(len(times), bool) if run.after_jump is None else run.after_jump)
            ax.plot(times[left], np.asarray(model.tension(run.ys[:, 2], run.ys[:, 0]))[left], style, color=color,
                    lw=1.0, alpha=0.85, label=label)  # fmt: skip
        ax.set_xlabel("t [s]")
        ax.set_ylabel("tension F [N]")
        ax.set_title(f"record at V = {record.V:g} m/s", fontsize=9)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    ax = axes[-1]
    lo, hi = result.v_range
    lo = max(float(lo), 1e-12)
    v = np.geomspace(lo, max(float(hi), lo * 10), 300)
    Vs = sorted({float(o.V) for o in records})
    band = None if result.uncertainty is None else (lambda V_i: result.uncertainty.phi_band(result.adhesion, v, V_i))
    draw_phi(ax, v, Vs, result.adhesion, result.start, band=band)
    ax.set_xscale("log")
    ax.set_xlabel("v [m/s] (range visited by the fitted runs)")
    ax.set_ylabel("φ(v, V) [N]")
    ax.set_title("adhesion law: fitted vs start", fontsize=9)
    return drawn.finish(title, path, default_title=f"force records fitted: {fitted_values(result)}")
