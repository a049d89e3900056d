"""Drawing into a new figure or into the user's axes: one rule for every plotting function.

Every public plotting function takes ``ax=`` (one panel) or ``axes=`` (several, in the order
its docstring gives) and draws there, or makes its own :class:`~matplotlib.figure.Figure`
(with an Agg canvas attached, so that saving needs no GUI and pyplot's backend is never
touched). It returns the Figure either way: its own, or the one the given axes belong to.
Into the user's axes it draws only: it does not share or hide them, set the figure's layout,
or put a title or a legend on the figure unless asked (``title=``); legends go with a panel.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ._atomic import save_figure

__all__ = ["Panels", "V_COLORS", "panels", "draw_phi"]

# The pull velocities' colours in φ panels: a sequential map, none of the C0/C1 that mean
# "fitted model" and "start model" in the panels beside them.
V_COLORS = "viridis"


class Panels:
    """The figure and the axes a plotting function draws into.

    Attributes:
        figure: the root :class:`Figure` (the function's own, or the one of the given axes).
        axes: the axes, in the function's order.
        own: True when the function made the figure (it may then lay it out, title it, and
            put legends beside the panels).
    """

    def __init__(self, figure: Figure, axes: list, own: bool):
        self.figure, self.axes, self.own = figure, axes, own

    def legend(self, handles, labels, *, ax: Axes | None = None, **kwargs):
        """A legend below the panels on the function's own figure (``kwargs`` are its
        placement), else in ``ax`` (default the first panel) where it covers least."""
        if not labels:
            return None
        if self.own:
            return self.figure.legend(handles, labels, **kwargs)
        options = {key: kwargs[key] for key in ("fontsize", "ncols") if key in kwargs}
        return (ax or self.axes[0]).legend(handles, labels, loc="best", **options)

    def finish(self, title: str | None, path, *, dpi: int = 150, default_title: str | None = None, **title_options):
        """The title (the function's own figure: ``title`` or ``default_title``; the user's:
        ``title`` only) and the file, when asked for; returns the figure."""
        text = title if title or not self.own else default_title
        if text:
            self.figure.suptitle(text, **title_options)
        if path is not None:
            save_figure(self.figure, path, dpi=dpi)  # whole or not at all: a failed write keeps the old file
        return self.figure


def panels(
    axes: Axes | Sequence[Axes] | np.ndarray | None,
    count: int,
    make: Callable[[Figure], list],
    *,
    figsize: tuple[float, float],
    name: str = "axes",
    what: str = "",
) -> Panels:
    """The panels to draw into: the user's ``axes`` (checked: ``count`` matplotlib Axes), or
    ``make(figure)``'s on a new constrained-layout figure of ``figsize``.

    Raises:
        TypeError: ``axes`` is not Axes or holds something else.
        ValueError: ``axes`` holds another number of Axes than ``count`` (``what`` says which).
    """
    if axes is None:
        figure = Figure(figsize=figsize, layout="constrained")
        FigureCanvasAgg(figure)  # attaches itself: savefig works with no pyplot backend
        return Panels(figure, list(make(figure)), own=True)
    given = [axes] if isinstance(axes, Axes) else list(np.ravel(np.asarray(axes, dtype=object)))
    wrong = [type(a).__name__ for a in given if not isinstance(a, Axes)]
    if wrong:
        raise TypeError(f"{name} must be matplotlib Axes, got {', '.join(sorted(set(wrong)))}")
    if len(given) != count:
        plural = "" if count == 1 else "s"
        raise ValueError(f"{name} must hold {count} Axes{plural}{f' ({what})' if what else ''}, got {len(given)}")
    figure = given[0].get_figure(root=True)
    return Panels(figure, given, own=False)


def draw_phi(ax: Axes, v: np.ndarray, Vs: Sequence[float], fitted, start=None, band=None, extra=()) -> list:
    """φ(v, V) of the fitted law (solid) and the start (dashed) at each V, one colour per V
    (:data:`V_COLORS`), with a legend beside the panel (one entry per V, one per line style)
    so that it covers no curve. ``band(V)``: (φ, half width) of a confidence band, or None;
    ``extra``: (handle, label) pairs for the legend. Returns the colours, one per V."""
    import jax.numpy as jnp
    from matplotlib import colormaps
    from matplotlib.lines import Line2D

    cmap = colormaps[V_COLORS]
    colors = [cmap(x) for x in np.linspace(0.0, 0.85, len(Vs))] if len(Vs) > 1 else [cmap(0.3)]
    for V, color in zip(Vs, colors):
        if band is not None:
            phi, half = band(V)
            ax.fill_between(v, phi - half, phi + half, color=color, alpha=0.2, lw=0)
        else:
            phi = np.asarray(fitted(jnp.asarray(v), V))
        ax.plot(v, phi, "-", color=color, lw=1.4)
        if start is not None:
            ax.plot(v, np.asarray(start(jnp.asarray(v), V)), "--", color=color, lw=1.1, alpha=0.8)
    from matplotlib.patches import Patch

    # one V: its colour is the curves' (a key in another colour would not be true to them)
    key = colors[0] if len(colors) == 1 else "0.3"
    handles = [Line2D([], [], color=color, lw=3) for color in colors] if len(colors) > 1 else []
    labels = [f"V = {V:g} m/s" for V in Vs] if len(colors) > 1 else []
    fitted_label = "fitted" + (f" (V = {Vs[0]:g} m/s)" if len(colors) == 1 else "")
    handles.append(Line2D([], [], color=key, lw=1.4))
    labels.append(fitted_label)
    if band is not None:
        handles.append(Patch(color=key, alpha=0.2, lw=0))
        labels.append("its 95 % band")
    if start is not None:
        handles.append(Line2D([], [], color=key, lw=1.1, ls="--", alpha=0.8))
        labels.append("start")
    for handle, label in extra:  # more entries of the caller's (markers it drew)
        handles.append(handle)
        labels.append(label)
    ax.legend(handles, labels, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=7, borderaxespad=0)
    return colors
