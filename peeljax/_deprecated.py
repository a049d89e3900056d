"""Old module paths kept for one release: a stub module names its new home, and its names are
looked up there on first use, with a ``DeprecationWarning`` (removed in peeljax 0.3.0 unless the
stub says otherwise)."""

from __future__ import annotations

import importlib
import warnings


def moved_module(old: str, new: str, removed_in: str = "0.3.0"):
    """A module's ``__getattr__`` and ``__dir__`` (PEP 562) that take every name from ``new``,
    imported on first use; each use warns, naming the name, ``old`` and ``new``."""

    def __getattr__(name: str):
        if name.startswith("__") and name != "__all__":  # probes such as __wrapped__, __path__
            raise AttributeError(f"module {old!r} has no attribute {name!r}")
        what = "" if name == "__all__" else f" {name}"  # __all__: a star import
        warnings.warn(f"{old} is deprecated: import{what} from {new} ({old} is removed in peeljax {removed_in})",
                      DeprecationWarning, stacklevel=2)  # fmt: skip
        return getattr(importlib.import_module(new), name)

    def __dir__():
        return sorted(vars(importlib.import_module(new)))

    return __getattr__, __dir__
