"""Deprecated: the fit's old data layer, now :mod:`peeljax.measurements` (removed in peeljax 0.3.0)."""
from .._deprecated import moved_module
__getattr__, __dir__ = moved_module(__name__, "peeljax.measurements")
