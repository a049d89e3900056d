"""Deprecated: the plots of a fit live with the other plots, in :mod:`peeljax.plots.fit`.

Importing this module warns (``DeprecationWarning``; it is removed in peeljax 0.3.0); it
re-exports :func:`plot_table_fit`, :func:`plot_records_fit`, :func:`fitted_values` and
:func:`model_statistics` unchanged.
"""

import warnings

from ..plots.fit import fitted_values, model_statistics, plot_records_fit, plot_table_fit

__all__ = ["fitted_values", "model_statistics", "plot_records_fit", "plot_table_fit"]

warnings.warn(
    "peeljax.fit.plots is deprecated: import plot_table_fit, plot_records_fit and fitted_values from "
    "peeljax.plots.fit (peeljax.fit.plots is removed in peeljax 0.3.0)",
    DeprecationWarning,
    stacklevel=2,
)
