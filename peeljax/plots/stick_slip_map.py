"""The stick-slip map over V as a figure (:func:`plot_stick_slip_map`).

matplotlib only, and nothing computed beyond what is drawn: everything comes from a
:class:`peeljax.sweeps.StickSlipMap` (φ's folds included). The figure is a plain
:class:`matplotlib.figure.Figure` with an Agg canvas attached, as in :mod:`peeljax.plots`:
saving needs no GUI and importing this module never switches the pyplot backend.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FixedLocator, FormatStrFormatter, NullFormatter

from .._panels import panels
from ..cycles import MIN_EVENTS

__all__ = ["plot_stick_slip_map"]

# One colour per start and jump direction: the slips in reds, the re-sticks in blues, the
# paper's start dark and filled, the steady start light and open (drawn larger, so that both
# stay visible where they coincide).
_JUMP_COLORS = {
    ("paper", True): "#b2182b",
    ("paper", False): "#2166ac",
    ("steady", True): "#f4a582",
    ("steady", False): "#67a9cf",
}
_START_COLORS = {"paper": "#1b1b1b", "steady": "#e08214"}
_START_WORDS = {"paper": "paper's start (at rest)", "steady": "steady start (v = V)"}
_STICK_COLORS = {"paper": "#2166ac", "steady": "#92c5de"}
_SLIP_COLORS = {"paper": "#b2182b", "steady": "#f4a582"}
_NO_FOLD_COLOR = "0.88"


def _start_style(start: str, index: int, density: float = 1.0) -> dict:
    """Filled small markers for the first start, open larger ones for the next; ``density``
    (≤ 1) shrinks them on a fine grid of V."""
    if index == 0:
        return {"ms": 3.2 * max(density, 0.7), "mew": 0.0, "filled": True}
    return {"ms": 6.5 * density, "mew": 0.9 * max(density, 0.7), "filled": False}


def _spans(V: np.ndarray, mask: np.ndarray, lo: float, hi: float, edge=None) -> list[tuple[float, float]]:
    """Intervals of V where ``mask`` holds: edges halfway between neighbours, or ``edge(V_in,
    V_out)`` where it gives one (None: halfway), the axis limits ``lo`` and ``hi`` beyond the
    first and last V."""
    order = np.argsort(V)
    V, mask = V[order], mask[order]
    edges = np.concatenate([[lo], 0.5 * (V[1:] + V[:-1]), [hi]])
    if edge is not None:
        for i in np.flatnonzero(mask[1:] != mask[:-1]):
            inside, outside = (V[i], V[i + 1]) if mask[i] else (V[i + 1], V[i])
            found = edge(inside, outside)
            if found is not None:
                edges[i + 1] = found
    spans, begin = [], None
    for i, flag in enumerate(mask):
        if flag and begin is None:
            begin = edges[i]
        if begin is not None and (not flag or i == mask.size - 1):
            spans.append((float(begin), float(edges[i + 1] if flag else edges[i])))
            begin = None
    return spans


def _unique_forces(G: np.ndarray, up: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A lane's distinct jump forces (to 1e-9 relative) per direction: drawing one dot per value
    looks the same as drawing every jump and keeps the figure light."""
    G, up = G[:n], up[:n]
    out = []
    for direction in (True, False):
        values = G[up == direction]
        values = values[np.isfinite(values)]
        if values.size:
            scale = max(float(np.max(np.abs(values))), 1e-300)
            values = np.unique(np.round(values / scale, 9)) * scale
        out.append(values)
    return out[0], out[1]


def _map_model(smap):
    """The model the map ran, from its settings (None where they do not say: a callable φ)."""
    from ..adhesion import AdhesionLaw
    from ..model import PeelingModel

    model = ((smap.settings or {}).get("sweep") or {}).get("model")
    if not isinstance(model, dict) or not isinstance(model.get("phi"), dict):
        return None
    try:
        return PeelingModel(
            **{name: float(model[name]) for name in ("R", "I", "k", "l")},
            adhesion=AdhesionLaw.from_dict(model["phi"]) if model["phi"] else AdhesionLaw(),
            geometry=model.get("geometry", "paper"),
        )
    except (KeyError, TypeError, ValueError):
        return None


def _fold_edge(model):
    """Where φ loses (or gains) its fold between a V with one and a V without (a root solve:
    :func:`peeljax.analysis.fold_limit`); None when the model is unknown or the root is not
    between them (then the shading starts halfway, as the samples alone say)."""
    if model is None:
        return None
    from ..analysis import fold_limit

    def edge(V_none, V_fold):
        try:
            return fold_limit(model, V_fold, V_none)
        except ValueError:
            return None

    return edge


def _heading(smap, title: str | None) -> str:
    V = np.asarray(smap.V)
    tau = "τ = 0 (the DAE itself)" if smap.tau == 0 else f"τ = {smap.tau:g} s (homogenized ODE)"
    sweep = (smap.settings or {}).get("sweep", {})
    tolerances = f", rtol = {sweep['rtol']:g}, atol = {sweep['atol']:g}" if sweep.get("rtol") is not None else ""
    line = (
        f"{V.size} values of V in [{V.min():.3g}, {V.max():.3g}] m/s, {tau}, t ∈ [0, {smap.t_final:g}] s, "
        f"statistics over t ≥ {smap.transient:g} s{tolerances}"
    )
    return f"{title}\n{line}" if title else f"Stick-slip map over the pull velocity V\n{line}"


def plot_stick_slip_map(
    smap, *, title: str | None = None, path: str | Path | None = None, model=None, axes=None
) -> Figure:
    """The stick-slip map of a :class:`peeljax.sweeps.StickSlipMap` against V, three panels.

    (a) The forces at which the tape slips and re-sticks: the shear force G at every jump after
        the transient (one dot per distinct value and lane; reds: stick → slip, blues: slip →
        stick; filled: the first start, open: the second) over φ's fold forces φ(v̂, V) (where
        it slips) and φ(v̌, V) (where it re-sticks). The V range where φ(·, V) has no fold is
        shaded and labelled, from the V where the fold vanishes (a root solve on the model,
        :func:`peeljax.analysis.fold_limit`; halfway between the samples where the model is
        not known: a callable φ).
    (b) The repeat period T of the stick → slip events (markers) and the mean time between
        slips (lines), log time axis; below it, on its own axis, the number k of events per
        repeat; below that a strip with one row each for the stick-slip lanes without a repeat
        (○ fewer than 31 slips in the window: too few repeats to tell, as
        :func:`peeljax.cycles.repeat_outlook` has it; × no repeat in more: irregular or still
        settling, the map does not keep the times to tell) and the lanes that stopped before
        t_final (▾; their statistics cover what they ran, see ``StickSlipMap.window_start``).
    (c) The v amplitude: the range of v on the stick branch (blues) and on the slip branch
        (reds) seen at the jumps, one bar per V and start (the starts side by side), with
        v̂(V), v̌(V) and v = V. Lanes without jumps (steady peeling) show their v range over the
        window as a black dot/bar. v = 0 (the tape landed fully stuck) is drawn at the bottom
        edge.

    Args:
        smap: the map (:func:`peeljax.sweeps.stick_slip_map`).
        title: a first title line (the settings follow on the next).
        path: when given, the figure is saved there (format from the suffix, PNG if none).
        model: the model the map ran (default: the one its settings record).
        axes: five matplotlib Axes to draw into (a figure of the user's): the forces, the
            period, k per repeat, the status strip and the v amplitude; None: a new figure.

    Returns:
        The figure (the axes' when given).
    """
    V = np.asarray(smap.V, float)
    starts = tuple(smap.starts)
    has_folds = np.isfinite(np.asarray(smap.v_max, float)) & np.isfinite(np.asarray(smap.v_min, float))
    order = np.argsort(V)
    span = float(V.max() - V.min()) if V.size > 1 else max(float(V[0]), 1.0)
    # each V's room on the axis: the distance to its nearest neighbour, at most 4 % of the range
    gaps = np.diff(V[order]) if V.size > 1 else np.array([span])
    room = np.empty(V.size)
    room[order] = np.minimum(np.concatenate([[gaps[0]], gaps]), np.concatenate([gaps, [gaps[-1]]]))
    room = np.minimum(room, 0.04 * span)

    drawn = panels(
        axes, 5, lambda fig: fig.subplots(5, 1, sharex=True, height_ratios=(1.0, 0.8, 0.3, 0.22, 1.1)),
        figsize=(12.5, 12.0), what="the forces, the period, k per repeat, the status strip, the v amplitude",
    )  # fmt: skip
    ax_G, ax_T, ax_k, ax_S, ax_v = drawn.axes
    density = float(np.clip(60.0 / V.size, 0.45, 1.0))  # marker scale: smaller beyond 60 values of V
    margin = max(float(room.max()), 0.01 * span)
    x_lo = max(float(V.min()) - margin, 0.5 * float(V.min()))
    x_hi = float(V.max()) + margin
    shifts = [0.0] if len(starts) == 1 else np.linspace(-0.22, 0.22, len(starts))  # the starts side by side
    no_fold = _spans(V, ~has_folds, x_lo, x_hi, _fold_edge(_map_model(smap) if model is None else model))
    for ax in (ax_G, ax_T, ax_k, ax_S, ax_v):
        for a, b in no_fold:
            ax.axvspan(a, b, color=_NO_FOLD_COLOR, zorder=0, lw=0)
        ax.grid(True, alpha=0.3)
        ax.set_xlim(x_lo, x_hi)

    # (a) the forces at the jumps over the fold forces ---------------------------------------
    Vo = V[order]
    ax_G.plot(Vo, np.asarray(smap.phi_max, float)[order], color="#67001f", lw=1.4, zorder=2,
              label="φ(v̂, V): φ's maximum (the stick branch ends)")  # fmt: skip
    ax_G.plot(Vo, np.asarray(smap.phi_min, float)[order], color="#053061", lw=1.4, zorder=2,
              label="φ(v̌, V): φ's minimum (the slip branch ends)")  # fmt: skip
    for s, start in enumerate(starts):
        style = _start_style(start, s, density)
        for direction, word in ((True, "slips (stick → slip)"), (False, "re-sticks (slip → stick)")):
            xs, ys = [], []
            for i in range(V.size):
                values = _unique_forces(smap.jump_G[s, i], smap.jump_up[s, i], int(smap.jumps[s, i]))[
                    0 if direction else 1
                ]
                xs.append(np.full(values.size, V[i]))
                ys.append(values)
            xs, ys = np.concatenate(xs), np.concatenate(ys)
            color = _JUMP_COLORS.get((start, direction), "C2" if direction else "C4")
            ax_G.plot(
                xs, ys, "o", ls="none", ms=style["ms"], mew=style["mew"], mec=color,
                mfc=color if style["filled"] else "none", zorder=3 + (1 - s),
                label=f"G at the jumps, {_START_WORDS.get(start, start)}: {word}",
            )  # fmt: skip
    ax_G.set_ylabel("shear force G at the jumps [N]")
    ax_G.set_title("(a) the forces at which the tape slips and re-sticks (every jump after the transient)",
                   fontsize=10, loc="left")  # fmt: skip
    for a, b in no_fold:
        ax_G.text(0.5 * (a + b), 0.04, "φ(·, V) has no fold:\nno stick-slip", transform=ax_G.get_xaxis_transform(),
                  ha="center", va="bottom", fontsize=8.5, color="0.25")  # fmt: skip
    ax_G.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, framealpha=0.95, borderaxespad=0)

    # (b) the repeat period, the events per repeat and the time between slips ----------------
    period = np.asarray(smap.period, float)
    events = np.asarray(smap.events)
    interval = np.asarray(smap.slip_interval, float)
    no_repeat = np.asarray(smap.stick_slip) & (events == 0)
    # fewer slips in the window than peeljax.cycles needs to call a run irregular: too few to tell
    few = no_repeat & (np.asarray(smap.slips) < MIN_EVENTS)
    no_repeat &= ~few
    stopped = np.asarray(smap.status) != 0
    shown_any = {"interval": False, "period": False}
    for s, start in enumerate(starts):
        style = _start_style(start, s, density)
        color = _START_COLORS.get(start, f"C{s}")
        face = color if style["filled"] else "none"
        regular = events[s] > 0
        if np.isfinite(interval[s]).any():
            ax_T.plot(V[order], interval[s][order], color=color, lw=1.1, ls="-" if s == 0 else "--", marker=".",
                      ms=3)  # fmt: skip
            shown_any["interval"] = True
        if regular.any():
            ax_T.plot(V[regular], period[s][regular], "D", ls="none", ms=style["ms"] + 1.8, mec=color, mfc=face,
                      mew=1.0, zorder=4)  # fmt: skip
            ax_k.plot(V[regular] + shifts[s] * room[regular], events[s][regular], "D", ls="none",
                      ms=style["ms"] + 1.0, mec=color, mfc=face, mew=1.0)  # fmt: skip
            shown_any["period"] = True
        # the lanes without a repeat and the stopped ones on their own strip, one row each
        x = V + shifts[s] * room
        for row, mask, marker in ((2, few[s], "o"), (1, no_repeat[s], "x"), (0, stopped[s], "v")):
            if mask.any():
                ax_S.plot(x[mask], np.full(int(mask.sum()), row), marker, ls="none", ms=5, mec=color,
                          mfc=face if marker != "x" else color, mew=1.2, color=color)  # fmt: skip
    ax_T.set_yscale("log")
    finite = np.concatenate([period[np.isfinite(period)], interval[np.isfinite(interval)]])
    if finite.size:  # the data and a little room
        lo, hi = float(finite.min()), float(finite.max())
        ax_T.set_ylim(lo / 1.6, hi * 1.6)
    else:
        ax_T.text(0.5, 0.5, "no stick-slip after the transient", transform=ax_T.transAxes, ha="center", va="center")
    ax_T.set_ylabel("time [s]")
    ax_T.set_title("(b) the repeat of the stick → slip events (period T, k events per repeat) and the mean time "
                   "between slips", fontsize=10, loc="left")  # fmt: skip
    # k: its own axis (integers, log), limits from the data
    k_seen = events[events > 0]
    k_max = float(k_seen.max()) if k_seen.size else 1.0
    ax_k.set_yscale("log")
    ax_k.set_ylim(0.7, max(3.0, 1.6 * k_max))
    ax_k.yaxis.set_major_locator(FixedLocator([k for k in (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000)
                                               if k <= max(3.0, 1.6 * k_max)]))  # integers only  # fmt: skip
    ax_k.yaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax_k.yaxis.set_minor_formatter(NullFormatter())
    ax_k.set_ylabel("k per repeat")
    if not k_seen.size:
        ax_k.text(0.5, 0.5, "no repeat found", transform=ax_k.transAxes, ha="center", va="center", fontsize=8)
    # the status strip: rows, not values
    ax_S.set_ylim(-0.6, 2.6)
    ax_S.set_yticks([0, 1, 2], ["stopped", "no repeat", "too few"], fontsize=8)
    ax_S.grid(False, axis="y")
    grey = "0.35"
    entries = {
        "interval": Line2D([], [], color=grey, lw=1.1, label="mean time between slips"),
        "period": Line2D([], [], color=grey, marker="D", ls="none", ms=6, label="repeat period T; below: its k"),
    }
    handles = [entries[key] for key, shown_key in shown_any.items() if shown_key]
    handles += [
        Line2D([], [], color=grey, marker="o", ls="none", ms=5, mfc="none",
               label=f"too few repeats to tell: no repeat, < {MIN_EVENTS} slips in the window"),
        Line2D([], [], color=grey, marker="x", ls="none", ms=5, mew=1.2,
               label=f"no repeat found in ≥ {MIN_EVENTS} slips (irregular, or still settling)"),
        Line2D([], [], color=grey, marker="v", ls="none", ms=5, label="stopped before t_final (statistics up to t_stop)"),
    ]  # fmt: skip
    for s, start in enumerate(starts):
        style = _start_style(start, s, density)
        color = _START_COLORS.get(start, f"C{s}")
        handles.append(Line2D([], [], color=color, lw=1.1, ls="-" if s == 0 else "--", marker="D", ms=6,
                              mfc=color if style["filled"] else "none", label=_START_WORDS.get(start, start)))  # fmt: skip
    ax_T.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, framealpha=0.95,
                borderaxespad=0)  # fmt: skip

    # (c) the v amplitude on each branch -----------------------------------------------------
    ranges = [np.asarray(getattr(smap, name), float) for name in ("v_stick_min", "v_stick_max", "v_slip_min",
                                                                   "v_slip_max", "v_lo", "v_hi")]  # fmt: skip
    positive = np.concatenate(
        [r[np.isfinite(r) & (r > 0)] for r in ranges] + [V, np.asarray(smap.v_max, float)[has_folds]]
    )
    floor = max(float(positive.min()) / 3.0, 1e-8 * float(positive.max())) if positive.size else 1e-3
    shown = lambda values: np.where(values > 0, values, floor * 1.2)  # v = 0 at the bottom
    for s, start in enumerate(starts):
        x = V + shifts[s] * room
        for lo_name, hi_name, colors, word in (
            ("v_stick_min", "v_stick_max", _STICK_COLORS, "stick branch"),
            ("v_slip_min", "v_slip_max", _SLIP_COLORS, "slip branch"),
        ):
            lo_v = np.asarray(getattr(smap, lo_name), float)[s]
            hi_v = np.asarray(getattr(smap, hi_name), float)[s]
            ok = np.isfinite(lo_v) & np.isfinite(hi_v)
            if ok.any():
                ax_v.vlines(x[ok], shown(lo_v[ok]), shown(hi_v[ok]), colors=colors.get(start, "C2"),
                            lw=max(0.8, min(4.0, 200.0 / max(V.size, 1))),
                            label=f"v on the {word}, {_START_WORDS.get(start, start)}")  # fmt: skip
        steady = (np.asarray(smap.jumps)[s] == 0) & np.isfinite(ranges[4][s]) & np.isfinite(ranges[5][s])
        if steady.any():
            ax_v.vlines(x[steady], shown(ranges[4][s][steady]), shown(ranges[5][s][steady]), colors="k", lw=1.0)
            style = _start_style(start, s, density)
            ax_v.plot(x[steady], shown(np.asarray(smap.v_mean, float)[s][steady]), "o", ls="none", ms=style["ms"],
                      mec="k", mew=0.9, mfc="k" if style["filled"] else "none",
                      label=f"no jumps: v over the window, {_START_WORDS.get(start, start)}")  # fmt: skip
    ax_v.plot(Vo, np.asarray(smap.v_max, float)[order], color="#67001f", lw=1.1, ls="--", zorder=5,
              label="v̂(V): φ's maximum")  # fmt: skip
    ax_v.plot(Vo, np.asarray(smap.v_min, float)[order], color="#053061", lw=1.1, ls="--", zorder=5,
              label="v̌(V): φ's minimum")  # fmt: skip
    ax_v.plot([x_lo, x_hi], [x_lo, x_hi], color="k", lw=0.9, ls=":", zorder=5, label="v = V (steady peeling)")
    ax_v.set_yscale("log")
    ax_v.set_ylim(bottom=floor)
    if any(np.any(r == 0) for r in ranges[:1]):
        ax_v.text(0.005, 0.01, "v = 0 (landed fully stuck) drawn at the bottom edge", transform=ax_v.transAxes,
                  fontsize=7.5, color="0.3", va="bottom")  # fmt: skip
    ax_v.set_ylabel("peeling velocity v [m/s]")
    ax_v.set_xlabel("pull velocity V [m/s]")
    ax_v.set_title("(c) the v amplitude: v on the stick and slip branches, seen at the jumps", fontsize=10, loc="left")
    ax_v.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, framealpha=0.95, borderaxespad=0)
    limits = sorted({round(x, 6) for span in no_fold for x in span if x not in (x_lo, x_hi)})
    where = f"\n(its maximum and minimum merge at V = {', '.join(f'{x:.4g}' for x in limits)} m/s)" if limits else ""
    no_fold_patch = Line2D([], [], color=_NO_FOLD_COLOR, lw=8, label="φ(·, V) has no fold" + where)
    ax_G.add_artist(ax_G.legend(handles=[no_fold_patch], loc="lower left", bbox_to_anchor=(1.01, 0.0), fontsize=8,
                                borderaxespad=0, framealpha=0.95))  # fmt: skip
    ax_G.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, framealpha=0.95, borderaxespad=0)

    return drawn.finish(_heading(smap, title) if drawn.own or title else None, path, dpi=130, fontsize=11)
