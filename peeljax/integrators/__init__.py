"""Time integrators for the homogenized ODE: the α-method and the diffrax reference."""

from .alpha import (
    AlphaMethod,
    AlphaState,
    StepInfo,
    alpha_advance,
    alpha_coefficients,
    alpha_start,
    amplification_matrix,
    integrate_alpha,
    to_physical,
)
from .reference import integrate_reference

__all__ = [
    "AlphaMethod",
    "AlphaState",
    "StepInfo",
    "alpha_advance",
    "alpha_coefficients",
    "alpha_start",
    "amplification_matrix",
    "integrate_alpha",
    "integrate_reference",
    "to_physical",
]
