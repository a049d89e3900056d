"""An observed run: what every fit of φ is given, whatever file it came from.

:func:`~peeljax.measurements.read_force_record` and :func:`~peeljax.measurements.read_observations` make them of
a lab's files; :func:`~peeljax.fit.fit_adhesion` fits them point by point,
:func:`~peeljax.fit.fit_records` by their stick-slip statistics or point by point, and
:meth:`StickSlipTable.from_force_records <peeljax.measurements.StickSlipTable.from_force_records>` pools
them into a table.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["Observation"]


@dataclasses.dataclass(frozen=True)
class Observation:
    """One observed run at pull velocity ``V``: ``v`` (and optionally ``F``, ``alpha``) on times ``t``.

    Each quantity may have its own time grid: pass ``t_F``/``t_alpha`` (default: ``t``).
    NaN entries (e.g. after a stop in a ``peeljax simulate --out`` file) are ignored.
    """

    V: float
    t: np.ndarray
    v: np.ndarray
    F: np.ndarray | None = None
    alpha: np.ndarray | None = None
    t_F: np.ndarray | None = None
    t_alpha: np.ndarray | None = None

    def series(self, quantity: str) -> tuple[np.ndarray, np.ndarray] | None:
        values = getattr(self, quantity)
        if values is None:
            return None
        times = (
            self.t
            if quantity == "v"
            else (getattr(self, f"t_{quantity}") if getattr(self, f"t_{quantity}") is not None else self.t)
        )
        times, values = np.asarray(times, float), np.asarray(values, float)
        if times.shape != values.shape or times.ndim != 1:
            raise ValueError(
                f"observation at V = {self.V:g}: {quantity} and its times must be 1-D arrays of one length"
            )
        keep = np.isfinite(times) & np.isfinite(values)
        return times[keep], values[keep]
