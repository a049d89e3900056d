"""Time integrators for the homogenized ODE: the α-method and the diffrax reference."""

from .alpha import AlphaMethod, alpha_coefficients, amplification_matrix, integrate_alpha
from .reference import integrate_reference

__all__ = ["AlphaMethod", "alpha_coefficients", "amplification_matrix", "integrate_alpha", "integrate_reference"]
