"""Fitting the adhesion law φ(v, V) to what a peel test measures.

* :mod:`.trajectory` — point-wise fits of smooth runs v(t), F(t), α(t) (optax), and of
  steady peeling (φ's own branch).
"""

from .trajectory import (
    QUANTITIES,
    FitResult,
    LossInfo,
    Observation,
    fit_adhesion,
    fit_adhesion_steady,
    phi_relative_error,
    restart_on_ascent,
    trajectory_loss,
)

__all__ = [
    "QUANTITIES",
    "FitResult",
    "LossInfo",
    "Observation",
    "fit_adhesion",
    "fit_adhesion_steady",
    "phi_relative_error",
    "restart_on_ascent",
    "trajectory_loss",
]
