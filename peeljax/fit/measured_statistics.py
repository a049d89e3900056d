"""Deprecated: the statistics of a measured force record live beside the model's, in :mod:`peeljax.fit.statistics`.

Importing this module warns (``DeprecationWarning``; it is removed in peeljax 0.3.0); it
re-exports its names unchanged.
"""

import warnings

from .statistics import MIN_DROP_NOISE, MIN_DROP_RANGE, record_cycles, record_statistics, sample_std, smoothed

__all__ = ["MIN_DROP_NOISE", "MIN_DROP_RANGE", "record_cycles", "record_statistics", "sample_std", "smoothed"]

warnings.warn(
    "peeljax.fit.measured_statistics is deprecated: import record_statistics, record_cycles and sample_std from "
    "peeljax.fit.statistics (record_statistics also from peeljax.fit; peeljax.fit.measured_statistics is removed "
    "in peeljax 0.3.0)",
    DeprecationWarning,
    stacklevel=2,
)
