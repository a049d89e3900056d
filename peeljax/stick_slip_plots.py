"""Deprecated: the stick-slip map's figure is :func:`peeljax.plots.plot_stick_slip_map`
(module :mod:`peeljax.plots.stick_slip_map`). This name is kept for one release."""

import warnings

from .plots.stick_slip_map import plot_stick_slip_map

warnings.warn(
    "peeljax.stick_slip_plots is deprecated: import plot_stick_slip_map from peeljax.plots",
    DeprecationWarning,
    stacklevel=2,
)

__all__ = ["plot_stick_slip_map"]
