"""The bifurcation diagram of stick-slip orbits over V (:func:`peeljax.orbits.orbit_diagram`).

Three panels sharing V: the tension at the slips and at the re-sticks (one period's means),
the time between slips, and the slips per period — every branch, stable parts solid and
unstable parts dashed, each located bifurcation marked; and over them, as dots, what the
seed runs themselves showed (a brute-force map's statistics over their second half).
matplotlib only: nothing is computed here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._panels import panels

__all__ = ["plot_orbit_diagram"]

_MARKERS = {
    "fold of cycles": ("^", "C3"),
    "period doubling": ("s", "C4"),
    "torus": ("D", "C2"),
    "grazing: a slip appears": ("o", "C1"),
    "grazing: a slip vanishes": ("v", "C1"),
    "end of the branch": ("x", "k"),
}


def _runs(values: np.ndarray, stable: np.ndarray):
    """Index ranges of consecutive points with the same stability (each run shares its ends
    with its neighbours, so the line is unbroken)."""
    start = 0
    for i in range(1, len(values) + 1):
        if i == len(values) or stable[i] != stable[start]:
            yield slice(start, min(i + 1, len(values))), bool(stable[start])
            start = i


def plot_orbit_diagram(diagram, *, axes=None, title: str | None = None, path: str | Path | None = None):
    """Draw ``diagram`` (an :class:`~peeljax.orbits.OrbitDiagram`) in three panels (module
    docstring); ``axes``: three matplotlib Axes to draw into (forces, time between slips,
    slips per period). Returns the Figure."""
    p = panels(axes, 3, lambda fig: list(fig.subplots(3, 1, sharex=True, height_ratios=(3, 2, 1.5))),
               figsize=(8.0, 8.5), what="forces, time between slips, slips per period")  # fmt: skip
    ax_F, ax_T, ax_k = p.axes
    handles, labels = [], []

    def keep(handle, label):
        if label not in labels:
            handles.append(handle)
            labels.append(label)

    for branch in diagram.branches:
        order = np.arange(len(branch))  # the branch's own order (along its arclength)
        stats = branch.statistics
        for part, stable in _runs(branch.V[order], branch.stable[order]):
            style = "-" if stable else "--"
            V = branch.V[order][part]
            (h,) = ax_F.plot(V, stats["F_slip"][order][part], style, color="C3", lw=1.2)
            keep(h, "F at the slips, " + ("stable orbit" if stable else "unstable orbit"))
            ax_F.plot(V, stats["F_stick"][order][part], style, color="C0", lw=1.2)
            ax_T.plot(V, 1e3 * stats["period"][order][part], style, color="C7", lw=1.2)
            ax_k.plot(V, branch.slips[order][part], style, color="C7", lw=1.2, drawstyle="steps-mid")
        for b in branch.bifurcations:
            marker, color = _MARKERS.get(b.kind.value, ("*", "k"))
            i = int(np.argmin(np.abs(branch.V - b.V)))
            h = ax_F.plot(b.V, stats["F_slip"][i], marker, color=color, ms=6, mfc="none", mew=1.4)[0]
            ax_T.plot(b.V, 1e3 * stats["period"][i], marker, color=color, ms=6, mfc="none", mew=1.4)
            ax_k.plot(b.V, branch.slips[i], marker, color=color, ms=6, mfc="none", mew=1.4)
            keep(h, b.kind.value)
    seeds = [s for s in diagram.seeds if np.isfinite(s.F_slip)]
    if seeds:
        V = np.array([s.V for s in seeds])
        h = ax_F.plot(V, [s.F_slip for s in seeds], ".", color="C3", ms=4, alpha=0.6)[0]
        ax_F.plot(V, [s.F_stick for s in seeds], ".", color="C0", ms=4, alpha=0.6)
        ax_T.plot(V, [1e3 * s.interval for s in seeds], ".", color="k", ms=4, alpha=0.6)
        periodic = [s for s in seeds if s.slips > 0]
        ax_k.plot([s.V for s in periodic], [s.slips for s in periodic], ".", color="k", ms=4, alpha=0.6)
        keep(h, "runs (second half's means): F at slips, re-sticks")
    ax_F.set_ylabel("tension F [N]\nat slips (red), re-sticks (blue)")
    ax_T.set_ylabel("time between\nslips [ms]")
    ax_k.set_ylabel("slips per\nperiod")
    ax_k.set_xlabel("pull velocity V [m/s]")
    for ax in p.axes:
        ax.grid(alpha=0.3)
    p.legend(handles, labels, loc="outside lower center", ncols=2, fontsize=8)
    lo, hi = diagram.V_range
    return p.finish(title, path, default_title=f"Stick-slip orbits over V in [{lo:g}, {hi:g}] m/s")
