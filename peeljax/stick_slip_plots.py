"""Deprecated: the stick-slip map's figure is :func:`peeljax.plots.plot_stick_slip_map`
(module :mod:`peeljax.plots.stick_slip_map`). This name is removed in peeljax 0.3.0."""

import warnings

from .plots.stick_slip_map import plot_stick_slip_map

warnings.warn(
    "peeljax.stick_slip_plots is deprecated: import plot_stick_slip_map from peeljax.plots "
    "(peeljax.stick_slip_plots is removed in peeljax 0.3.0)",
    DeprecationWarning,
    stacklevel=2,
)

__all__ = ["plot_stick_slip_map"]
