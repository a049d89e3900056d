"""Time integrators for the homogenized ODE: the α-method (uniform mesh, error control, and as a
diffrax solver) and the diffrax reference."""

from .adaptive import alpha_attempt, error_constant, integrate_alpha_adaptive
from .alpha import (
    AlphaMethod,
    AlphaState,
    LogTransformedODE,
    StepInfo,
    alpha_advance,
    alpha_coefficients,
    alpha_start,
    amplification_matrix,
    integrate_alpha,
    to_physical,
)
from .controller import PIController
from .dense import hermite
from .diffrax_solver import AlphaSolver
from .reference import integrate_reference

__all__ = [
    "AlphaMethod",
    "AlphaSolver",
    "AlphaState",
    "LogTransformedODE",
    "PIController",
    "StepInfo",
    "alpha_attempt",
    "error_constant",
    "hermite",
    "integrate_alpha_adaptive",
    "alpha_advance",
    "alpha_coefficients",
    "alpha_start",
    "amplification_matrix",
    "integrate_alpha",
    "integrate_reference",
    "to_physical",
]
