"""Pieces shared by the ``peeljax`` subcommands: option checks, file checks, JSON output."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from ..adhesion import AdhesionLaw

PROG = "peeljax"


def load_phi(path: str) -> AdhesionLaw:
    """The adhesion law from a JSON file; every failure becomes a ValueError naming --phi."""
    try:
        law = AdhesionLaw.from_json(path)
    except OSError as error:  # a directory, no permission, …: from_json handles only a missing file
        raise ValueError(f"--phi: cannot read {path!r} ({error.strerror or error})") from None
    except ValueError as error:
        message = str(error)
        raise ValueError(message if message.startswith("--phi") else f"--phi: {message}") from None
    return law


def check_output_path(option: str, path: str | None, suffixes: set[str] | None = None) -> None:
    """Fail now rather than after a long run: the folder must exist, the suffix be writable."""
    if path is None:
        return
    target = Path(path)
    if target.is_dir():
        raise ValueError(f"{option}: {path!r} is a directory, expected a file name")
    if not target.parent.is_dir():
        raise ValueError(f"{option}: the folder {str(target.parent)!r} does not exist")
    suffix = target.suffix.lstrip(".").lower()
    if suffixes is not None and suffix and suffix not in suffixes:
        raise ValueError(f"{option}: unknown image format {suffix!r}; use one of {', '.join(sorted(suffixes))}")


def plot_formats() -> set[str]:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    return set(FigureCanvasAgg(Figure()).get_supported_filetypes())


def checked(allowed: str, check, *args):
    """Run a library check; add the allowed range where its message lacks one (e.g. "must be finite")."""
    try:
        return check(*args)
    except ValueError as error:
        message = str(error)
        if "allowed range" in message or allowed in message:
            raise
        raise ValueError(f"{message} (allowed range: {allowed})") from None


def json_safe(value):
    """NaN/inf → null, so the output is strict JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {key: json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    return value


def fail(error: Exception) -> int:
    print(f"{PROG}: error: {error}", file=sys.stderr)
    return 2
