"""Deprecated: now :mod:`peeljax.measurements.instrument` (removed in peeljax 0.3.0)."""
from .._deprecated import moved_module
__getattr__, __dir__ = moved_module(__name__, "peeljax.measurements.instrument")
