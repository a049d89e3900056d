"""The installed package's version, set in one place (``pyproject.toml``) and read from its metadata."""

from __future__ import annotations

from importlib import metadata

try:
    __version__ = metadata.version("peeljax")
except metadata.PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "0+unknown"
