"""Plots of a stick-slip table fit (:func:`peeljax.fit.table.fit_stick_slip`).

:func:`plot_table_fit` draws one panel per statistic of the table (the data with their error
bars against V, the start model's and the fitted model's statistics), a panel of the residuals
(model − data)/σ against V, and the fitted φ(v, V) with its 95 % confidence band over the v
the fitted runs visited, the start φ dashed and φ's folds marked.

:func:`model_statistics` runs the model at a table's pull velocities exactly as the fit does
(:class:`peeljax.fit.table.TableFit`) and returns its statistics.

matplotlib only, with an Agg canvas attached to each figure (as :mod:`peeljax.plots`): saving
needs no GUI and importing this module never switches the pyplot backend.
"""

from __future__ import annotations

from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..adhesion import AdhesionLaw
from ..model import PeelingModel
from .stick_slip_table import STATISTICS, StickSlipTable
from .table import TableFit, build_table_fit

__all__ = ["model_statistics", "plot_table_fit"]

_LABELS = {
    "F_mean": "mean tension F̄ [N]",
    "F_slip": "tension at slip F_slip [N]",
    "F_stick": "tension at stick F_stick [N]",
    "period": "period [s]",
    "slip_duration": "slip duration [s]",
}
_MARKERS = {"F_mean": "o", "F_slip": "^", "F_stick": "v", "period": "s", "slip_duration": "D"}


@eqx.filter_jit
def _statistics(fit: TableFit, theta):
    return fit.statistics(theta)


def model_statistics(
    law: AdhesionLaw,
    V,
    *,
    model: PeelingModel | None = None,
    tau: float = 0.0,
    transient: float = 0.5,
    window: float = 1.0,
    n_samples: int = 401,
    rtol: float = 1e-7,
    atol: float = 1e-10,
    max_jumps: int = 4096,
    max_steps: int = 400_000,
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The model's stick-slip statistics at the pull velocities ``V`` (a sequence, or a
    :class:`~peeljax.fit.StickSlipTable`), run as :func:`~peeljax.fit.table.fit_stick_slip`
    runs them, with φ = ``law``.

    Returns:
        ({statistic: (n,) values, NaN where the run did not produce it}, the (n, 2) range of v
        visited in each window).
    """
    V = np.asarray(V.V if isinstance(V, StickSlipTable) else V, float).reshape(-1)
    model = PeelingModel() if model is None else model
    shape = (V.size, len(STATISTICS))
    fit = build_table_fit(
        law, model, V, np.zeros(shape), np.ones(shape), np.ones(shape, bool), names=("c1",), tau=tau,
        transient=transient, window=window, n_samples=n_samples, rtol=rtol, atol=atol, max_jumps=max_jumps,
        max_steps=max_steps,
    )  # fmt: skip
    values, available, v_range = _statistics(fit, {"c1": jnp.zeros(())})
    values = np.where(np.asarray(available), np.asarray(values, float), np.nan)
    return {s: values[:, j] for j, s in enumerate(STATISTICS)}, np.asarray(v_range, float)


def synthetic_table(law: AdhesionLaw, V, *, noise: float = 0.01, seed: int = 0, **settings) -> StickSlipTable:
    """A stick-slip table made by the model with φ = ``law`` at the pull velocities ``V``: each
    statistic of :func:`model_statistics` (``settings`` are its options) times 1 + noise·N(0, 1)
    (``seed``), with standard deviations noise·|value| — for hidden-truth exercises."""
    stats, _ = model_statistics(law, V, **settings)
    rng = np.random.default_rng(seed)
    columns = {}
    for name in STATISTICS:
        exact = np.asarray(stats[name])
        columns[name] = exact * (1 + noise * rng.normal(size=exact.shape))
        columns[f"{name}_std"] = noise * np.abs(exact)
    return StickSlipTable.from_dict(V=np.asarray(V, float), **columns)


def _run_options(result) -> dict:
    s = result.settings
    keys = ("tau", "transient", "window", "n_samples", "rtol", "atol")
    return {k: s[k] for k in keys if k in s}


def _phi_V(table: StickSlipTable) -> np.ndarray:
    """2–3 of the table's pull velocities: first, middle, last."""
    V = np.asarray(table.V, float)
    return V[sorted({0, len(V) // 2, len(V) - 1})]


def plot_table_fit(
    result, table: StickSlipTable, *, model: PeelingModel | None = None, title: str | None = None,
    path: str | Path | None = None,
) -> Figure:  # fmt: skip
    """A stick-slip table fit: data vs start and fitted model per statistic, residuals, φ band.

    Args:
        result: :func:`~peeljax.fit.table.fit_stick_slip`'s :class:`~peeljax.fit.FitResult`.
        table: the table it was fitted to.
        model: the spool and tape of the fit (default the paper's); φ is replaced by the
            start's and the fitted law.
        title: the figure's title (default: the loss and the stop reason).
        path: save the figure there (any format matplotlib's Agg canvas writes).
    """
    from ..branches import phi_folds

    model = PeelingModel() if model is None else model
    options = _run_options(result)
    stats = [s for s in result.settings.get("statistics", table.statistics) if s in table.statistics]
    fitted, _ = model_statistics(result.adhesion, table, model=model, **options)
    started, _ = model_statistics(result.start, table, model=model, **options)
    V = np.asarray(table.V, float)

    n_panels = len(stats) + 2
    n_cols = min(n_panels, 3)
    n_rows = -(-n_panels // n_cols)
    fig = Figure(figsize=(4.4 * n_cols, 3.4 * n_rows), layout="constrained")
    FigureCanvasAgg(fig)  # attaches itself: savefig works with no pyplot backend
    axes = fig.subplots(n_rows, n_cols, squeeze=False).ravel()
    for ax in axes[n_panels:]:
        ax.set_visible(False)

    for ax, s in zip(axes, stats):
        std = table.std.get(s)
        ax.errorbar(
            V, table.values[s], yerr=None if std is None else np.nan_to_num(std), fmt=_MARKERS[s], color="0.2",
            ms=4, capsize=3, label="data",
        )  # fmt: skip
        ax.plot(V, started[s], "--", marker=".", color="C1", alpha=0.8, label="start model")
        ax.plot(V, fitted[s], "-", marker=".", color="C0", label="fitted model")
        ax.set_xlabel("pull velocity V [m/s]")
        ax.set_ylabel(_LABELS[s])
        ax.legend(fontsize=7)

    ax = axes[len(stats)]
    if result.residuals is not None:
        measured = [(i, s) for i in range(len(V)) for s in STATISTICS if s in stats and np.isfinite(table.values[s][i])]
        r = np.asarray(result.residuals, float)
        if len(measured) == r.size:
            for k, s in enumerate(stats):
                idx = [n for n, (_, name) in enumerate(measured) if name == s]
                ax.plot([V[measured[n][0]] for n in idx], r[idx], _MARKERS[s], color=f"C{k}", ms=5, label=s)
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
    for k, V_i in enumerate(_phi_V(table)):
        color = f"C{k}"
        if result.uncertainty is not None:
            phi, half = result.uncertainty.phi_band(result.adhesion, v, V_i)
            ax.fill_between(v, phi - half, phi + half, color=color, alpha=0.2, lw=0)
        else:
            phi = np.asarray(result.adhesion(jnp.asarray(v), V_i))
        ax.plot(v, phi, "-", color=color, label=f"fitted, V = {V_i:g}" + (" (95 % band)" if result.uncertainty else ""))
        ax.plot(
            v, np.asarray(result.start(jnp.asarray(v), V_i)), "--", color=color, alpha=0.7, label=f"start, V = {V_i:g}"
        )
        folds = phi_folds(fitted_model, V_i)
        for v_f, phi_f, mark in ((folds.v_max, folds.phi_max, "^"), (folds.v_min, folds.phi_min, "v")):
            v_f, phi_f = float(v_f), float(phi_f)
            if np.isfinite(v_f) and lo <= v_f <= hi:
                ax.plot([v_f], [phi_f], mark, color=color, mec="k", ms=7)
    ax.plot([], [], "^", color="0.6", mec="k", label="fold: φ max")
    ax.plot([], [], "v", color="0.6", mec="k", label="fold: φ min")
    ax.set_xscale("log")
    ax.set_xlabel("v [m/s] (range visited by the fitted runs)")
    ax.set_ylabel("φ(v, V) [N]")
    ax.set_title("adhesion law: fitted (95 % band) vs start", fontsize=9)
    ax.legend(fontsize=6)

    reason = result.stop_reason.split(":")[0] if result.stop_reason else ""
    fig.suptitle(
        title
        or f"stick-slip table fit ({', '.join(result.free)}): loss {result.initial_loss:.3g} → {result.final_loss:.3g}"
        + (f", {reason}" if reason else "")
    )
    if path is not None:
        fig.savefig(path, dpi=150)
    return fig
