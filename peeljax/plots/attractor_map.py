"""The attractor map over V (:func:`peeljax.attractor_map`) as one figure of three panels."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import ScalarFormatter

__all__ = ["plot_attractor_map"]

# One colour per label (the order of peeljax.attractor_map.ATTRACTOR_KINDS).
_COLOURS = ("0.35", "tab:blue", "tab:green", "tab:red", "tab:orange", "tab:purple", "tab:brown")


def plot_attractor_map(amap, *, title: str | None = None, path: str | Path | None = None) -> Figure:
    """The attractors of an :class:`peeljax.AttractorMap` against V, three panels.

    (a) The mean time between slips of each attractor (T/k on a periodic orbit; at τ = 0 every
        slip starts at φ's maximum and every stick at its minimum, so the forces at the jumps
        are V's alone and the time between slips is what tells attractors apart; steady
        peeling: none, drawn at the bottom edge), log axis, coloured by its label, one marker
        per attractor and V; the located boundaries as vertical lines at their brackets'
        middles, named by their change where it is not a grazing, a loss of stability or a
        loss to another attractor (those: ``amap.summary()``).
    (b) The period T of periodic attractors (log axis), with k (slips per period) beside
        the first point of each branch of three V or more; |μ₁| of the orbit as the marker's
        fill (1: white).
    (c) The basin shares among the random starts (stacked, with binomial standard errors as
        bars on each share).

    Args:
        amap: the map.
        title: a first title line (the settings follow).
        path: when given, the figure is saved there (format from the suffix, PNG if none).
    """
    from ..attractor_map import ATTRACTOR_KINDS, PERIODIC, STEADY

    fig = Figure(figsize=(9.0, 9.0), layout="constrained")
    ax_force, ax_period, ax_basin = fig.subplots(3, 1, sharex=True, height_ratios=(3, 2, 2))
    V, kind = np.asarray(amap.V), np.asarray(amap.kind)
    orbit = (kind == PERIODIC) & (np.asarray(amap.slips) > 0)  # (k = 0: a limit cycle by its exponents alone)
    interval = 1e3 * np.where(orbit, np.asarray(amap.period) / np.maximum(np.asarray(amap.slips), 1),
                              np.asarray(amap.slip_interval, float))  # fmt: skip
    interval[kind == STEADY] = np.nan
    floor = np.nanmin(interval) * 0.8 if np.any(np.isfinite(interval)) else 1.0
    for code, name in enumerate(ATTRACTOR_KINDS):
        mask = kind == code
        if not mask.any():
            continue
        y = np.full(mask.sum(), floor) if code == STEADY else interval[mask]
        ax_force.scatter(V[mask], y, s=9, color=_COLOURS[code], label=f"{name} ({mask.sum()})", marker="_" if code == STEADY else "o")
    b = amap.boundaries
    for i in range(np.size(b["branch"])):
        where = 0.5 * (b["V_inside"][i] + b["V_outside"][i])
        for ax in (ax_force, ax_period, ax_basin):
            ax.axvline(where, color="0.6", lw=0.6, ls=":")
        if str(b["change"][i]).startswith(("lost", "grazing", "loses stability")):
            continue  # (many: named in amap.summary(), not on the figure)
        ax_force.annotate(str(b["change"][i]), (where, 1.0), xycoords=("data", "axes fraction"), rotation=90,
                          fontsize=6, va="top", ha="right", color="0.3")  # fmt: skip
    ax_force.set_yscale("log")
    ax_force.set_ylabel("mean time between slips [ms]")
    ax_force.legend(fontsize=7, loc="lower right")

    periodic = orbit
    if periodic.any():
        mu = np.clip(np.asarray(amap.multiplier, float)[periodic], 0.0, 1.0)
        ax_period.scatter(V[periodic], np.asarray(amap.period)[periodic], c=1.0 - mu, cmap="Blues", vmin=0, vmax=1,
                          edgecolors="tab:blue", s=14, linewidths=0.5)  # fmt: skip
        ax_period.set_yscale("log")
        ax_period.yaxis.set_major_formatter(ScalarFormatter())
        ax_period.yaxis.set_minor_formatter(ScalarFormatter())
        branch = np.asarray(amap.branch)[periodic]
        slips = np.asarray(amap.slips)[periodic]
        members = np.bincount(branch - branch.min())
        for i in np.unique(branch, return_index=True)[1]:
            if members[branch[i] - branch.min()] < 3:
                continue  # k written at branches of three V or more
            ax_period.annotate(f"k={slips[i]}", (V[periodic][i], np.asarray(amap.period)[periodic][i]), fontsize=6,
                               xytext=(2, 2), textcoords="offset points")  # fmt: skip
    ax_period.set_ylabel("period T [s] (fill: 1 − |μ₁|)")

    grid = np.asarray(amap.grid_V)
    if amap.random_starts:
        bottom = np.zeros(grid.size)
        index = np.asarray(amap.V_index)
        share, error = np.asarray(amap.basin, float), np.asarray(amap.basin_se, float)
        width = np.gradient(grid) if grid.size > 1 else np.full(1, 0.1)
        labelled = set()
        for i in sorted(np.flatnonzero(share > 0), key=lambda i: (kind[i], index[i])):
            j = index[i]
            name = ATTRACTOR_KINDS[kind[i]]
            ax_basin.bar(grid[j], share[i], bottom=bottom[j], width=width[j], color=_COLOURS[kind[i]],
                         edgecolor="w", linewidth=0.2, label=None if name in labelled else name)  # fmt: skip
            ax_basin.errorbar(grid[j], bottom[j] + share[i], yerr=error[i], fmt="none", ecolor="k", elinewidth=0.4)
            labelled.add(name)
            bottom[j] += share[i]
        ax_basin.set_ylim(0, 1)
        ax_basin.set_ylabel(f"basin share ({amap.random_starts} starts)")
        ax_basin.set_title("bars: each share's binomial standard error", fontsize=8, loc="left")
    ax_basin.set_xlabel("V [m/s]")
    settings = f"t_final = {amap.t_final:g} s, window from {amap.transient:g} s, {amap.random_starts} random starts per V"
    fig.suptitle(settings if title is None else f"{title}\n{settings}", fontsize=9)
    if path is not None:
        path = Path(path)
        fig.savefig(path if path.suffix else path.with_suffix(".png"), dpi=150)
    return fig
