"""Refuse, before anything compiles, a request whose output would not fit in memory.

One rule for :func:`peeljax.sweep` and :func:`peeljax.simulate` (and their commands): the
caller estimates the bytes its output takes, and :func:`check_output_memory` compares them
with the memory limit (default: half the machine's RAM) and words the refusal.
"""

from __future__ import annotations

import functools
import os

__all__ = ["check_output_memory", "memory_limit"]


@functools.cache
def memory_limit() -> float:
    """Half the machine's physical memory [bytes] (8 GB where it cannot be read)."""
    try:
        return 0.5 * os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 8e9


def check_output_memory(what: str, total: float, detail: str, remedy: str, limit: float | None = None) -> None:
    """A ValueError when ``total`` bytes exceed ``limit`` (None: :func:`memory_limit`).

    The message reads "<what> would take <total> GB (<detail>), more than the memory limit of
    <limit> GB: <remedy>".
    """
    limit = memory_limit() if limit is None else float(limit)
    if total > limit:
        raise ValueError(
            f"{what} would take {total / 1e9:.3g} GB ({detail}), more than the memory limit of "
            f"{limit / 1e9:.3g} GB: {remedy}"
        )
